"""Geometry kernels against hand-computed scenes in the real arena and a brute-force check."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neuronsmae.server.sim import field as F
from neuronsmae.server.task.geometry import (
    LIDAR_MIN_HEIGHT,
    SIGHT_MIN_HEIGHT,
    lidar_scan,
    point_in_grown_boxes,
    ray_box_distance,
    robot_boxes,
    segment_blocked,
)

BOXES = F.obstacle_array()
TALL = F.obstacle_array(tall_only=True)
FRONT = F.LIDAR_BEAMS // 2
B8_DIAG = 0.245 / 2 * math.sqrt(2)  # centre-to-corner of the turned B8


def _p(x: float, y: float) -> np.ndarray:
    return np.array([x, y])


# --- LiDAR ------------------------------------------------------------------------------


def test_scan_has_61_beams_and_front_beam_reads_the_wall() -> None:
    d = lidar_scan(np.array([1.0, 2.24, math.pi]), BOXES, 10.0)
    assert d.shape == (61,)
    assert d[FRONT] == pytest.approx(1.0)
    # ±90° beams look along ±y at x = 1, just past B2's end (x ≤ 0.9925): walls 2.24 away.
    assert d[FRONT + 20] == pytest.approx(2.24)  # +90° from −x is −y
    assert d[FRONT - 20] == pytest.approx(2.24)


def test_beam_angles_span_270_degrees() -> None:
    pose = np.array([3.0, 2.5, 0.4])
    d = lidar_scan(pose, BOXES, 10.0)
    for j in (0, 7, FRONT, 44, 60):
        angle = pose[2] + math.radians(-135.0 + 4.5 * j)
        assert d[j] == pytest.approx(ray_box_distance(pose[:2], angle, BOXES, 10.0))


def test_low_obstacle_reflects_but_not_with_sight_threshold() -> None:
    pose = np.array([4.04, 1.6, math.pi / 2])  # facing +y, B8 ahead, B5 behind it
    d = lidar_scan(pose, BOXES, 10.0)
    assert d[FRONT] == pytest.approx(2.24 - (B8_DIAG - 0.001) - 1.6)
    d_tall = lidar_scan(pose, BOXES, 10.0, min_height=SIGHT_MIN_HEIGHT)
    assert d_tall[FRONT] == pytest.approx(3.445 - 0.183 / 2 - 1.6)


def test_tall_obstacle_face() -> None:
    d = lidar_scan(np.array([4.04, 1.6, -math.pi / 2]), BOXES, 10.0)
    assert d[FRONT] == pytest.approx(1.6 - (1.037 + 0.183 / 2))


def test_robots_reflect_and_range_caps() -> None:
    other = robot_boxes(np.array([[3.5, 1.5, 0.0], [3.5, 0.4, math.pi / 2]]))
    boxes = np.vstack([BOXES, other])
    pose = np.array([2.5, 1.5, 0.0])
    assert lidar_scan(pose, boxes, 10.0)[FRONT] == pytest.approx(0.7)  # rear face at 3.2
    assert lidar_scan(pose, boxes, 0.5)[FRONT] == 0.5
    # A robot turned 90° shows its 0.46 m side: face at 3.5 − 0.23 along y = 0.4.
    d = ray_box_distance(_p(2.5, 0.4), 0.0, boxes, 10.0)
    assert d == pytest.approx(0.77)


def test_ray_without_walls_can_miss() -> None:
    assert ray_box_distance(_p(1.0, 2.24), math.pi, BOXES, 10.0, walls=False) == 10.0
    assert ray_box_distance(_p(1.0, 2.24), math.pi, BOXES, 10.0) == pytest.approx(1.0)


def test_ray_from_inside_a_box_is_zero() -> None:
    assert ray_box_distance(_p(4.04, 3.445), 0.3, BOXES, 10.0) == 0.0


# --- line of sight ----------------------------------------------------------------------


def test_tall_obstacle_occludes() -> None:
    assert segment_blocked(_p(4.04, 2.9), _p(4.04, 4.2), BOXES, SIGHT_MIN_HEIGHT)
    assert segment_blocked(_p(4.04, 2.9), _p(4.04, 4.2), TALL, SIGHT_MIN_HEIGHT)
    # 1 cm past B5's end the line is clear.
    x = 4.04 + 0.985 / 2 + 0.01
    assert not segment_blocked(_p(x, 2.9), _p(x, 4.2), BOXES, SIGHT_MIN_HEIGHT)


@pytest.mark.parametrize("x", [1.9, 6.18, 4.04])
def test_low_obstacles_do_not_occlude_but_block_driving(x: float) -> None:
    p0, p1 = _p(x, 1.5), _p(x, 3.0)  # crosses B6 / B7 / B8 only
    assert not segment_blocked(p0, p1, BOXES, SIGHT_MIN_HEIGHT)
    assert segment_blocked(p0, p1, BOXES, LIDAR_MIN_HEIGHT)


def test_robot_occludes() -> None:
    rob = robot_boxes(np.array([[3.0, 2.7, 0.3]]))
    boxes = np.vstack([TALL, rob])
    assert segment_blocked(_p(2.0, 2.7), _p(4.0, 2.7), boxes, SIGHT_MIN_HEIGHT)
    assert not segment_blocked(_p(2.0, 3.1), _p(4.0, 3.1), boxes, SIGHT_MIN_HEIGHT)


def test_robot_boxes_rows() -> None:
    rows = robot_boxes(np.array([[1.0, 2.0, 0.5]]))
    np.testing.assert_allclose(rows, [[1.0, 2.0, 0.30, 0.23, 0.5, 0.44]])
    assert robot_boxes(np.zeros((0, 3))).shape == (0, 6)


def _inside(points: np.ndarray, boxes: np.ndarray, grow: float) -> np.ndarray:
    """Numpy reference for grown-box membership (any box), vectorised over points."""
    hit = np.zeros(len(points), dtype=bool)
    for cx, cy, hx, hy, yaw, _ in boxes:
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = points[:, 0] - cx, points[:, 1] - cy
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        hit |= (np.abs(lx) < hx + grow) & (np.abs(ly) < hy + grow)
    return hit


coords = st.tuples(st.floats(0.0, F.FIELD_X), st.floats(0.0, F.FIELD_Y))


@settings(max_examples=300, deadline=None)
@given(coords, coords)
def test_segment_matches_dense_sampling(a: tuple[float, float], b: tuple[float, float]) -> None:
    """Dense samples inside a box (shrunk 1 cm) force a block; none near it forbid one."""
    p0, p1 = np.array(a), np.array(b)
    t = np.linspace(0.0, 1.0, 2000)[:, None]
    pts = p0 + t * (p1 - p0)  # ≤ 4.6 mm apart
    blocked = segment_blocked(p0, p1, BOXES, LIDAR_MIN_HEIGHT)
    if _inside(pts, BOXES, -0.01).any():
        assert blocked
    if not _inside(pts, BOXES, 0.01).any():
        assert not blocked


def test_point_in_grown_boxes() -> None:
    pts = np.array(
        [
            [4.041 + 0.25, 2.24],  # beside the turned B8: outside as is, inside grown 0.1
            [4.04, 3.445 - 0.0915 - 0.29],  # 0.29 below B5
            [4.04, 3.445 - 0.0915 - 0.31],  # 0.31 below B5
        ]
    )
    np.testing.assert_array_equal(point_in_grown_boxes(pts, BOXES, 0.0), [False, False, False])
    np.testing.assert_array_equal(point_in_grown_boxes(pts, BOXES, 0.1), [True, False, False])
    np.testing.assert_array_equal(point_in_grown_boxes(pts, BOXES, 0.3), [True, True, False])


@settings(max_examples=100, deadline=None)
@given(st.lists(coords, min_size=1, max_size=50), st.floats(0.0, 0.5))
def test_point_in_grown_boxes_matches_numpy(pts: list, margin: float) -> None:
    arr = np.array(pts)
    np.testing.assert_array_equal(
        point_in_grown_boxes(arr, BOXES, margin), _inside(arr, BOXES, margin)
    )
