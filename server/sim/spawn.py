"""Where robots start: the released build's random placement or the RMUA corner birth areas."""

from __future__ import annotations

import numpy as np

from neuronsmae.server.sim import field as F

_GROWN = None


def _grown_obstacles() -> np.ndarray:
    """Obstacle footprints grown by the spawn margin, as (n, 4) x0, y0, x1, y1 bounds.

    The turned B8 is taken by its axis-aligned bounding square, a slightly larger keep-out,
    which only ever rejects a few more lattice points.
    """
    global _GROWN
    if _GROWN is None:
        rows = []
        for o in F.OBSTACLES:
            c, s = abs(np.cos(o.yaw)), abs(np.sin(o.yaw))
            hx = (o.sx * c + o.sy * s) / 2 + F.SPAWN_OBSTACLE_MARGIN
            hy = (o.sx * s + o.sy * c) / 2 + F.SPAWN_OBSTACLE_MARGIN
            rows.append((o.cx - hx, o.cy - hy, o.cx + hx, o.cy + hy))
        _GROWN = np.array(rows)
    return _GROWN


def random_poses(n: int, rng: np.random.Generator, max_tries: int = 10_000) -> np.ndarray:
    """The released rule: 1 cm lattice in x ∈ [0.40, 7.80), y ∈ [0.40, 4.00); reject points in
    an obstacle grown by 0.30 m or within 0.80 m of a robot already placed; yaw uniform."""
    grown = _grown_obstacles()
    poses = np.zeros((n, 3))
    nx = round((F.SPAWN_X[1] - F.SPAWN_X[0]) * 100)
    ny = round((F.SPAWN_Y[1] - F.SPAWN_Y[0]) * 100)
    placed = 0
    for _ in range(max_tries):
        x = F.SPAWN_X[0] + rng.integers(nx) / 100.0
        y = F.SPAWN_Y[0] + rng.integers(ny) / 100.0
        inside = (grown[:, 0] < x) & (x < grown[:, 2]) & (grown[:, 1] < y) & (y < grown[:, 3])
        if inside.any():
            continue
        if placed and np.hypot(poses[:placed, 0] - x, poses[:placed, 1] - y).min() < (
            F.SPAWN_MIN_SEPARATION
        ):
            continue
        poses[placed] = (x, y, rng.uniform(-np.pi, np.pi))
        placed += 1
        if placed == n:
            return poses
    raise RuntimeError(f"could not place {n} robots in {max_tries} tries")  # pragma: no cover


BIRTH_JITTER = 0.15
"""A robot in a birth area starts with its centre uniform within this many metres (in x and
in y) of the area's centre: its footprint (0.60 × 0.46 m, facing along x) stays inside the
1 × 1 m area, at least 5 cm from its edges, and episodes of different seeds start apart."""


def corner_poses(n_blue: int, n_red: int, rng: np.random.Generator) -> np.ndarray:
    """RMUA birth areas: blue in the two left corners, red in the two right ones, facing the
    other side, each placed at random within :data:`BIRTH_JITTER` of its area's centre. A
    third robot of a team starts at random in its own half."""
    blue_corners, red_corners = F.BIRTH_AREAS[:2], F.BIRTH_AREAS[2:]
    poses = []
    for count, corners, yaw in ((n_blue, blue_corners, 0.0), (n_red, red_corners, np.pi)):
        for i in range(count):
            if i < len(corners):
                dx, dy = rng.uniform(-BIRTH_JITTER, BIRTH_JITTER, 2)
                poses.append((corners[i][0] + dx, corners[i][1] + dy, yaw))
            else:
                poses.append(_random_in_half(rng, left=(yaw == 0.0), placed=poses, yaw=yaw))
    return np.array(poses)


def _random_in_half(rng: np.random.Generator, left: bool, placed: list, yaw: float) -> tuple:
    for _ in range(10_000):
        cand = random_poses(1, rng)[0]
        if (cand[0] < F.CENTER[0]) == left and all(
            np.hypot(cand[0] - p[0], cand[1] - p[1]) >= F.SPAWN_MIN_SEPARATION for p in placed
        ):
            return (cand[0], cand[1], yaw)
    raise RuntimeError("could not place a robot in its half")  # pragma: no cover
