"""What each robot perceives at a decision: candidate points, sight of enemies, LiDAR.

These are derived from the poses once per decision and shared by the observation builder,
the action decoder (abstract actions index the candidate points the agent was shown) and
the bots.
"""

from __future__ import annotations

import numpy as np

from neuronsmae.server.sim import field as F
from neuronsmae.server.task.candidates import all_candidate_points
from neuronsmae.server.task.geometry import (
    SIGHT_MIN_HEIGHT,
    lidar_scan,
    robot_boxes,
    segment_blocked,
)
from neuronsmae.server.task.observations import camera_sees

ALL_BOXES = F.obstacle_array()
TALL_BOXES = F.obstacle_array(tall_only=True)


def _without(n: int, *skip: int) -> np.ndarray:
    """Indices 0..n-1 except ``skip`` (cheaper than ``np.delete`` on this hot path)."""
    return np.array([j for j in range(n) if j not in skip], dtype=np.int64)


def all_candidates(
    poses: np.ndarray,
    alive: np.ndarray,
    enemies_of: list[np.ndarray],
    k: int,
    wanted: np.ndarray,
    table: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate points for every robot around each of its enemies.

    Returns ``(cands (N, n_enemy, k, 2), valid (N, n_enemy, k))``. Only robots flagged in
    ``wanted`` (those whose observation or bot needs them) are computed; a destroyed robot,
    or a destroyed enemy, gets the "stay" sentinel (its own position, not valid). ``table``
    is ``enemy_table(enemies_of)`` when the caller keeps it.
    """
    table = enemy_table(enemies_of) if table is None else table
    return all_candidate_points(poses, alive, table, wanted, ALL_BOXES, k)


def enemy_table(enemies_of: list[np.ndarray]) -> np.ndarray:
    """(N, n_enemy) int: each robot's enemies in observation order, -1 padded."""
    table = np.full((len(enemies_of), max(len(e) for e in enemies_of)), -1, dtype=np.int64)
    for i, e in enumerate(enemies_of):
        table[i, : len(e)] = e
    return table


def sight(
    poses: np.ndarray,
    alive: np.ndarray,
    targets: np.ndarray,
    enemies_of: list[np.ndarray],
    hfov: float,
    partial: bool,
) -> np.ndarray:
    """(N, n_enemy) bool: which enemies each robot sees.

    Under full observability everything is seen. Under partial observability an enemy is
    seen when inside the gimbal camera's horizontal view (the gimbal follows the robot's
    target) and no tall obstacle or other robot stands in the line of sight. A destroyed
    robot sees nothing.
    """
    n = poses.shape[0]
    n_enemy = max(len(e) for e in enemies_of)
    if not partial:
        return np.ones((n, n_enemy), dtype=bool)
    seen = np.zeros((n, n_enemy), dtype=bool)
    rboxes = robot_boxes(poses)
    for i in np.flatnonzero(alive):
        tgt = targets[i] if targets[i] >= 0 else enemies_of[i][0]
        for j, e in enumerate(enemies_of[i]):
            blockers = np.concatenate([TALL_BOXES, rboxes[_without(n, i, e)]])
            blocked = segment_blocked(poses[i, :2], poses[e, :2], blockers, SIGHT_MIN_HEIGHT)
            seen[i, j] = camera_sees(poses[i], poses[tgt, :2], poses[e, :2], hfov, blocked)
    return seen


def lidar(poses: np.ndarray, i: int, max_range: float) -> np.ndarray:
    """Robot ``i``'s scan, normalised to [-1, 1] (−1 at contact, +1 at ``max_range``)."""
    boxes = np.concatenate([ALL_BOXES, robot_boxes(poses)[_without(poses.shape[0], i)]])
    d = lidar_scan(poses[i], boxes, max_range)
    return 2.0 * d / max_range - 1.0
