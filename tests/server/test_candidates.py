"""Candidate points: the spec's filters, k-means output conventions, sentinel, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from neuronsmae.server.sim import field as F
from neuronsmae.server.task.candidates import _kept_samples, candidate_points
from neuronsmae.server.task.geometry import (
    SIGHT_MIN_HEIGHT,
    point_in_grown_boxes,
    segment_blocked,
)

BOXES = F.obstacle_array()
NO_BOXES = np.zeros((0, 6))
X0, X1, Y0, Y1 = 0.2, 7.8, 0.2, 4.0
EPS = 1e-7


def _reference_ok(p: np.ndarray, enemy: np.ndarray, blockers: np.ndarray, tol: float) -> bool:
    """The spec's filters, straight from the geometry kernels; ``tol`` > 0 is stricter."""
    if not (X0 + tol <= p[0] <= X1 - tol and Y0 + tol <= p[1] <= Y1 - tol):
        return False
    if len(blockers) and np.any(np.all(np.abs(blockers - p) < 0.6 + tol, axis=1)):
        return False
    if point_in_grown_boxes(p[None], BOXES, 0.30 + tol)[0]:
        return False
    grown = BOXES.copy()
    grown[:, 2:4] += tol
    return not segment_blocked(p, enemy, grown, SIGHT_MIN_HEIGHT)


def _check(
    enemy: np.ndarray, others: np.ndarray, asker: int | None, k: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Run candidate_points and assert every invariant the spec and the docstring give."""
    pts, valid = candidate_points(enemy, others, BOXES, k=k, asker=asker)
    again = candidate_points(enemy, others.copy(), BOXES.copy(), k=k, asker=asker)
    np.testing.assert_array_equal(pts, again[0])  # deterministic
    np.testing.assert_array_equal(valid, again[1])
    assert pts.shape == (k, 2) and valid.shape == (k,) and valid.dtype == bool
    blockers = others if asker is None else np.delete(others, asker, axis=0)

    # The filtered sample set, bracketed by the reference filters run stricter and looser.
    kp, kidx, n = _kept_samples(
        enemy[0], enemy[1], others, -1 if asker is None else asker, BOXES,
        2.5, 180, X0, X1, Y0, Y1, 0.30, 0.6, SIGHT_MIN_HEIGHT,
    )  # fmt: skip
    kept = set(kidx[:n].tolist())
    for j in range(180):
        a = 2 * math.pi * j / 180
        p = enemy + 2.5 * np.array([math.cos(a), math.sin(a)])
        if _reference_ok(p, enemy, blockers, EPS):
            assert j in kept, f"sample {j} should survive"
        if not _reference_ok(p, enemy, blockers, -EPS):
            assert j not in kept, f"sample {j} should be dropped"

    if n == 0:
        assert not valid.any()
        expected = np.full((k, 2), np.nan) if asker is None else np.tile(others[asker], (k, 1))
        np.testing.assert_array_equal(pts, expected)
        return pts, valid
    assert valid.all()
    kept_pts = kp[:n]
    # Every output is a surviving sample, at 2.5 m, outputs distinct and in angular order.
    rows = [int(np.flatnonzero(np.all(np.abs(kept_pts - q) < 1e-12, axis=1))[0]) for q in pts]
    assert rows == sorted(rows)
    np.testing.assert_allclose(np.hypot(*(pts - enemy).T), 2.5, atol=1e-9)
    if n >= k:
        assert len(set(rows)) == k
    else:
        assert rows == [*range(n), *[n - 1] * (k - n)]
    for q in pts:
        assert _reference_ok(q, enemy, blockers, -EPS)
    return pts, valid


def test_centre_enemy_four_points_around_it() -> None:
    others = np.array([[1.0, 1.0], [7.0, 3.5]])
    pts, valid = _check(np.array([4.04, 2.24]), others, asker=0)
    assert valid.all()
    angles = np.arctan2(*(pts - [4.04, 2.24]).T[::-1]) % (2 * math.pi)
    assert np.all(np.diff(angles) > 0)


def test_enemy_behind_tall_obstacle_gets_no_point_through_it() -> None:
    enemy = np.array([4.04, 4.1])  # just above B5
    pts, _ = _check(enemy, np.array([[1.0, 1.0]]), asker=0)
    for q in pts:
        assert not segment_blocked(q, enemy, BOXES, SIGHT_MIN_HEIGHT)
    # Sample 135, (4.04, 1.6), is in bounds and clear of grown obstacles; B5 hides it.
    _, idx, n = _kept_samples(
        enemy[0], enemy[1], np.zeros((0, 2)), -1, BOXES, 2.5, 180,
        X0, X1, Y0, Y1, 0.30, 0.6, SIGHT_MIN_HEIGHT,
    )  # fmt: skip
    assert 135 not in idx[:n].tolist()
    assert 134 not in idx[:n].tolist() and 136 not in idx[:n].tolist()
    assert not point_in_grown_boxes(np.array([[4.04, 1.6]]), BOXES, 0.30)[0]


def test_low_obstacle_does_not_hide() -> None:
    # Enemy above B7; the sample straight below it, (6.18, 0.5), sees it across B7 only.
    enemy = np.array([6.18, 3.0])
    _, idx, n = _kept_samples(
        enemy[0], enemy[1], np.zeros((0, 2)), -1, BOXES, 2.5, 180,
        X0, X1, Y0, Y1, 0.30, 0.6, SIGHT_MIN_HEIGHT,
    )  # fmt: skip
    assert 135 in idx[:n].tolist()  # 270°


def test_robot_squares_and_asker_flag() -> None:
    enemy = np.array([4.04, 2.24])
    spot = enemy + 2.5 * np.array([math.cos(math.radians(20)), math.sin(math.radians(20))])
    others = np.array([spot, [1.0, 1.0]])
    open_pts, _ = _check(enemy, others, asker=0)  # asker's own square does not block
    blocked_pts, valid = candidate_points(enemy, others, BOXES, asker=0, asker_blocks=True)
    assert valid.all()
    assert not np.any(np.all(np.abs(blocked_pts - spot) < 0.6, axis=1))
    near_open = np.all(np.abs(open_pts - spot) < 0.6, axis=1)
    assert near_open.any()
    # asker=None: everyone in others blocks.
    none_pts, _ = _check(enemy, others, asker=None)
    np.testing.assert_array_equal(none_pts, blocked_pts)


def test_fewer_than_k_repeat_the_last() -> None:
    # Only sample 0 (x = 3.5 exactly) fits in x ∈ [3.5, 3.6]; then only samples 0 and 1.
    pts, valid = candidate_points(
        np.array([1.0, 2.24]), np.zeros((0, 2)), NO_BOXES, bounds=(3.5, 3.6, 0.2, 4.0)
    )
    assert valid.all()
    np.testing.assert_allclose(pts, np.tile([3.5, 2.24], (4, 1)))
    pts, valid = candidate_points(
        np.array([1.0, 2.24]), np.zeros((0, 2)), NO_BOXES, bounds=(3.495, 3.6, 2.24, 4.0)
    )
    a = 2 * math.pi / 180
    np.testing.assert_allclose(pts[0], [3.5, 2.24])
    second = [1 + 2.5 * math.cos(a), 2.24 + 2.5 * math.sin(a)]
    np.testing.assert_allclose(pts[1:], np.tile(second, (3, 1)))


def test_none_left_stays_put() -> None:
    others = np.array([[1.0, 1.0], [7.0, 3.5]])
    pts, valid = candidate_points(np.array([4.04, 2.24]), others, BOXES, radius=10.0, asker=1)
    assert not valid.any()
    np.testing.assert_array_equal(pts, np.tile([7.0, 3.5], (4, 1)))
    pts, valid = candidate_points(np.array([4.04, 2.24]), others, BOXES, radius=10.0)
    assert not valid.any() and np.isnan(pts).all()


def test_full_circle_is_split_evenly() -> None:
    """No filter active: the four points should sit roughly a quarter turn apart."""
    enemy = np.array([4.0, 2.0])
    pts, valid = candidate_points(enemy, np.zeros((0, 2)), NO_BOXES, bounds=(-9, 20, -9, 20))
    assert valid.all()
    ang = np.sort(np.arctan2(pts[:, 1] - 2.0, pts[:, 0] - 4.0) % (2 * math.pi))
    gaps = np.diff(np.append(ang, ang[0] + 2 * math.pi))
    np.testing.assert_allclose(gaps, math.pi / 2, atol=math.radians(6))


@pytest.mark.parametrize("k", [1, 2, 6])
def test_other_k(k: int) -> None:
    _check(np.array([2.0, 3.0]), np.array([[3.0, 1.0]]), asker=0, k=k)


def test_input_validation() -> None:
    with pytest.raises(ValueError, match="k and n_samples must be positive"):
        candidate_points(np.array([4.0, 2.0]), np.zeros((0, 2)), BOXES, k=0)


xs = st.floats(0.4, 7.8)
ys = st.floats(0.4, 4.0)


def _free(p: np.ndarray) -> bool:
    return not point_in_grown_boxes(p[None], BOXES, 0.30)[0]


@settings(max_examples=200, deadline=None)
@given(
    st.tuples(xs, ys),
    st.lists(st.tuples(xs, ys), min_size=0, max_size=3),
    st.one_of(st.none(), st.integers(0, 2)),
)
def test_random_scenes_keep_invariants(
    enemy: tuple[float, float], robots: list, asker: int | None
) -> None:
    e = np.array(enemy)
    others = np.array(robots).reshape(-1, 2)
    assume(_free(e) and all(_free(o) for o in others))
    if asker is not None and asker >= len(others):
        asker = None
    _check(e, others, asker)
