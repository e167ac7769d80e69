"""Planner and follower: paths respect the arena, robustness cases, velocity law."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from neuronsmae.server.sim import field
from neuronsmae.server.task.planner import (
    STATUS_GOAL_MOVED,
    STATUS_OK,
    STATUS_START_MOVED,
    Planner,
    follow,
)


@pytest.fixture(scope="module")
def planner() -> Planner:
    return Planner()


def _dense(path: np.ndarray, step: float = 0.01) -> np.ndarray:
    """Points every ``step`` metres along the polyline (and its vertices)."""
    pts = [path[:1]]
    for a, b in itertools.pairwise(path):
        k = max(2, math.ceil(np.linalg.norm(b - a) / step) + 1)
        pts.append(np.linspace(a, b, k)[1:])
    return np.concatenate(pts)


def _clearance(pts: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest raw obstacle (negative inside), from the
    field's own rectangles, independent of the planner's grid."""
    d = np.full(len(pts), np.inf)
    for cx, cy, hx, hy, yaw, _h in field.obstacle_array():
        c, s = math.cos(yaw), math.sin(yaw)
        lx = np.abs(c * (pts[:, 0] - cx) + s * (pts[:, 1] - cy)) - hx
        ly = np.abs(-s * (pts[:, 0] - cx) + c * (pts[:, 1] - cy)) - hy
        out = np.hypot(np.maximum(lx, 0), np.maximum(ly, 0))
        d = np.minimum(d, out + np.minimum(np.maximum(lx, ly), 0))
    return d


def _assert_legal(path: np.ndarray) -> None:
    pts = _dense(path)
    assert np.all(_clearance(pts) > 0.0), "path crosses a raw obstacle"
    assert np.all((pts > 0.0) & (pts < [field.FIELD_X, field.FIELD_Y])), "path leaves the field"


def test_open_space_path_is_straight(planner: Planner) -> None:
    path = planner.plan((2.4, 2.85), (5.6, 2.85), np.zeros((0, 2)))
    assert planner.last_status == STATUS_OK
    np.testing.assert_allclose(path, [[2.4, 2.85], [5.6, 2.85]])


def test_path_around_tall_obstacle_keeps_clear(planner: Planner) -> None:
    start, goal = (4.04, 0.4), (4.04, 1.7)  # B4 lies between
    path = planner.plan(start, goal, None)
    assert planner.last_status == STATUS_OK
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], goal)
    _assert_legal(path)
    # Free space allows the full 0.30 m margin; shortcuts never cut into it.
    assert _clearance(_dense(path)).min() > 0.27
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    assert length < 3.0  # around the near end of B4, not some long detour


def test_start_inside_grown_margin_still_plans(planner: Planner) -> None:
    start = (4.04, 0.86)  # 9 cm below B4, deep in its grown margin
    path = planner.plan(start, (6.0, 3.0), None)
    assert planner.last_status == STATUS_OK
    assert len(path) >= 2
    np.testing.assert_allclose(path[0], start)
    _assert_legal(path)


def test_start_inside_obstacle_leaves_it(planner: Planner) -> None:
    start = (4.04, 1.04)  # inside B4
    path = planner.plan(start, (4.04, 0.4), None)
    assert planner.last_status & STATUS_START_MOVED
    np.testing.assert_allclose(path[0], start)
    _assert_legal(path[1:])


def test_goal_inside_obstacle_goes_to_nearest_free_cell(planner: Planner) -> None:
    goal = np.array([4.04, 1.0])  # inside B4, 5.5 cm above its lower face
    path = planner.plan((4.04, 0.4), goal, None)
    assert planner.last_status == STATUS_GOAL_MOVED
    _assert_legal(path)
    assert np.linalg.norm(path[-1] - goal) < 0.15
    assert path[-1][1] < 0.9455  # the near (lower) side, not around the obstacle


def test_goal_outside_field_is_clamped(planner: Planner) -> None:
    path = planner.plan((1.0, 2.0), (-1.0, 2.0), None)
    assert planner.last_status == STATUS_GOAL_MOVED
    _assert_legal(path)
    assert path[-1][0] < 0.05


def test_other_robot_square_is_avoided_when_possible(planner: Planner) -> None:
    other = np.array([[4.0, 2.9]])  # squarely on the straight line
    path = planner.plan((2.4, 2.9), (5.6, 2.9), other)
    assert planner.last_status == STATUS_OK
    _assert_legal(path)
    cheb = np.max(np.abs(_dense(path) - other[0]), axis=1)
    assert cheb.min() >= 0.6 - 1e-9


def test_start_inside_other_robot_square_still_plans(planner: Planner) -> None:
    path = planner.plan((2.4, 2.9), (5.6, 2.9), np.array([[2.8, 2.9]]))
    assert planner.last_status == STATUS_OK
    assert len(path) >= 2
    _assert_legal(path)


def test_random_queries_are_legal_and_deterministic(planner: Planner) -> None:
    rng = np.random.default_rng(7)
    other = Planner()
    pts = rng.uniform([0.3, 0.3], [7.8, 4.2], size=(300, 2))
    pts = pts[_clearance(pts) > 0.05][:120]
    for k in range(0, len(pts) - 4, 4):
        start, goal, others = pts[k], pts[k + 1], pts[k + 2 : k + 5]
        a = planner.plan(start, goal, others)
        assert planner.last_status in (STATUS_OK, STATUS_GOAL_MOVED)
        assert len(a) >= 2
        _assert_legal(a)
        np.testing.assert_array_equal(a, other.plan(start, goal, others))
        np.testing.assert_array_equal(a, planner.plan(start, goal, others))


LINE = np.array([[0.0, 0.0], [3.0, 0.0]])


@pytest.mark.parametrize(
    ("x", "expected"),
    [(0.0, 2.0), (1.5, 2.0), (2.6, 0.8), (2.7, 0.6), (2.86, 0.0), (3.0, 0.0)],
)
def test_follow_speed_profile(x: float, expected: float) -> None:
    vf, vl = follow((x, 0.0, 0.0), LINE, (3.0, 0.0))
    assert vf == pytest.approx(expected)
    assert vl == pytest.approx(0.0)


def test_follow_rotates_into_body_frame() -> None:
    # Goal straight ahead in world +x while the robot faces +y: it must go to its right.
    vf, vl = follow((0.0, 0.0, math.pi / 2), LINE, (3.0, 0.0))
    assert vf == pytest.approx(0.0, abs=1e-12)
    assert vl == pytest.approx(-2.0)
    vf, vl = follow((0.0, 0.0, math.pi), LINE, (3.0, 0.0))  # facing -x: backwards
    assert (vf, vl) == (pytest.approx(-2.0), pytest.approx(0.0, abs=1e-12))


def test_follow_heads_for_lookahead_point() -> None:
    # 0.4 m off the path: aim at the point 0.3 m further along, not straight at the goal.
    vf, vl = follow((1.0, 0.4, 0.0), LINE, (3.0, 0.0))
    assert math.hypot(vf, vl) == pytest.approx(2.0)
    assert math.atan2(vl, vf) == pytest.approx(math.atan2(-0.4, 0.3))


def test_follow_no_path_stops_and_none_drives_straight() -> None:
    assert follow((0.0, 0.0, 0.0), np.zeros((0, 2)), (3.0, 0.0)) == (0.0, 0.0)
    vf, vl = follow((0.0, 0.0, 0.0), None, (0.0, 1.0))
    assert (vf, vl) == (pytest.approx(0.0, abs=1e-12), pytest.approx(2.0))


def test_follow_uses_moved_goal(planner: Planner) -> None:
    goal = np.array([4.04, 1.0])  # inside B4: the path ends short of it
    path = planner.plan((4.04, 0.4), goal, None)
    end = path[-1]
    assert follow((end[0], end[1] - 0.1, 0.0), path, goal) == (0.0, 0.0)
