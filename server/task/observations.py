"""Observation vectors, the global state and their normalisation.

The layout of one observation is written once, in the protocol
(:class:`neuronsmae.protocol.env_info.ObsLayout`, which clients and trainers read too;
docs/options.md has the table): :func:`obs_size` is that layout's size, and the kernels
below fill its blocks in its order. For 2 v 2 with abstract actions and k = 4 it is the
released 37-value layout; without candidate points the released 21-value one. Under
partial observability an enemy outside the camera's view or sight has its pose and
candidate points replaced by ``unseen_value``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from neuronsmae.protocol.env_info import ObsLayout
from neuronsmae.server.sim import field as F

LIDAR_OFFSET = 61
HALF_X, HALF_Y = F.FIELD_X / 2.0, F.FIELD_Y / 2.0


def obs_size(n_team: int, n_enemy: int, k: int, candidates: bool, vector: bool, lidar: bool) -> int:
    """Length of one observation: the protocol's :class:`ObsLayout` of these blocks."""
    beams = F.LIDAR_BEAMS if lidar else 0
    return ObsLayout(n_team, n_enemy, k if candidates else 0, vector, beams).size


def state_size(n_robots: int) -> int:
    """Global state: pose, HP and bullets of every robot, then the time."""
    return 5 * n_robots + 1


def norm_xy(xy: np.ndarray) -> np.ndarray:
    """Positions to [-1, 1] along each axis of the field."""
    out = np.empty_like(xy, dtype=np.float64)
    out[..., 0] = (xy[..., 0] - HALF_X) / HALF_X
    out[..., 1] = (xy[..., 1] - HALF_Y) / HALF_Y
    return out


def norm_yaw(yaw: np.ndarray) -> np.ndarray:
    """Yaw wrapped to [-π, π) and divided by π."""
    return (np.mod(yaw + np.pi, 2 * np.pi) - np.pi) / np.pi


def norm_pose(poses: np.ndarray) -> np.ndarray:
    """(N, 3) poses → normalised (N, 3)."""
    out = np.empty_like(poses)
    out[:, :2] = norm_xy(poses[:, :2])
    out[:, 2] = norm_yaw(poses[:, 2])
    return out


def norm_time(t: int, limit: int) -> float:
    """Elapsed physics steps → [-1, 1]."""
    return 2.0 * t / limit - 1.0


def norm_hp(hp: np.ndarray, max_hp: np.ndarray) -> np.ndarray:
    """HP over the robot's own starting HP (600 by default), to [-1, 1]."""
    return 2.0 * hp / max_hp - 1.0


def norm_bullets(bullets: np.ndarray, max_bullets: np.ndarray) -> np.ndarray:
    """Bullets over the most the robot can hold in the episode (the 370 at the start; with
    zones, plus 100 per ammunition refresh the episode lasts into), to [-1, 1]."""
    return 2.0 * bullets / max_bullets - 1.0


def vector_obs_batch(
    order: np.ndarray,
    n_team: int,
    poses_n: np.ndarray,
    cands_n: np.ndarray | None,
    t_n: float,
    hp_n: np.ndarray,
    bul_n: np.ndarray,
    seen: np.ndarray,
    unseen: float,
) -> np.ndarray:
    """The vectors of A robots sharing one layout, one row each: (A, size).

    ``order`` (A, n) lists each robot's robot indices as self, allies, enemies;
    ``poses_n``, ``hp_n``, ``bul_n`` are normalised per robot; ``cands_n``
    (A, n_enemy, k, 2) normalised or None (filled with ``unseen`` in place where unseen, so
    pass a fresh array); ``seen`` (A, n_enemy) says which enemies each robot sees. All
    robots at once in a few array operations, because this runs every decision.
    """
    a = order.shape[0]
    poses = poses_n[order]
    poses[:, n_team:][~seen] = unseen
    parts = [poses.reshape(a, -1)]
    if cands_n is not None:
        cands_n[~seen] = unseen  # the caller's fresh array
        parts.append(cands_n.reshape(a, -1))
    parts += [np.full((a, 1), t_n), hp_n[order], bul_n[order]]
    return np.concatenate(parts, axis=1)


@numba.njit(cache=True)
def _norm_yaw1(yaw: float) -> float:
    """:func:`norm_yaw` of one value (numba's ``np.mod`` is NumPy's floored remainder)."""
    return (np.mod(yaw + np.pi, 2 * np.pi) - np.pi) / np.pi


@numba.njit(cache=True)
def vector_obs_kernel(order, n_team, poses, agents, cands, t_n, hp, max_hp, bullets,
                      max_bullets, seen, unseen, out) -> None:  # fmt: skip
    """:func:`vector_obs_batch` from raw values in one pass, into ``out`` (A, size).

    ``poses`` (N, 3), ``hp``, ``max_hp``, ``bullets``, ``max_bullets`` (N,) are the
    referee's raw values and are normalised here with the same operations as
    :func:`norm_pose`, :func:`norm_hp` and :func:`norm_bullets`, so the result is
    bit-identical to the array version; ``cands``
    (N, E, k, 2) are every robot's raw candidate points (agent ``a`` reads robot
    ``agents[a]``'s), or an empty array for a layout without them; ``t_n`` is
    :func:`norm_time`. ``out`` may be float32: values are rounded once, as by ``astype``.
    """
    n = order.shape[1]
    with_cands = cands.shape[0] > 0
    k = cands.shape[2]
    for a in range(order.shape[0]):
        c = 0
        for j in range(n):
            r = order[a, j]
            if j >= n_team and not seen[a, j - n_team]:
                out[a, c], out[a, c + 1], out[a, c + 2] = unseen, unseen, unseen
            else:
                out[a, c] = (poses[r, 0] - HALF_X) / HALF_X
                out[a, c + 1] = (poses[r, 1] - HALF_Y) / HALF_Y
                out[a, c + 2] = _norm_yaw1(poses[r, 2])
            c += 3
        if with_cands:
            i = agents[a]
            for e in range(n - n_team):
                for q in range(k):
                    if seen[a, e]:
                        out[a, c] = (cands[i, e, q, 0] - HALF_X) / HALF_X
                        out[a, c + 1] = (cands[i, e, q, 1] - HALF_Y) / HALF_Y
                    else:
                        out[a, c], out[a, c + 1] = unseen, unseen
                    c += 2
        out[a, c] = t_n
        c += 1
        for j in range(n):
            r = order[a, j]
            out[a, c + j] = 2.0 * hp[r] / max_hp[r] - 1.0
            out[a, c + n + j] = 2.0 * bullets[r] / max_bullets[r] - 1.0


def global_state(
    poses_n: np.ndarray, hp_n: np.ndarray, bul_n: np.ndarray, t_n: float
) -> np.ndarray:
    """The true state from the blue-first view: per robot (x, y, yaw, HP, bullets), time."""
    per_robot = np.concatenate([poses_n, hp_n[:, None], bul_n[:, None]], axis=1)
    return np.concatenate([per_robot.reshape(-1), [t_n]]).astype(np.float32)


def camera_sees(
    pose: np.ndarray, target_xy: np.ndarray, other_xy: np.ndarray, hfov: float, blocked: bool
) -> bool:
    """Is ``other_xy`` inside the camera's horizontal view? The gimbal points at the robot's
    current target within ±90° of the chassis; ``blocked`` is the line-of-sight verdict."""
    if blocked:
        return False
    aim = math.atan2(target_xy[1] - pose[1], target_xy[0] - pose[0]) - pose[2]
    aim = math.atan2(math.sin(aim), math.cos(aim))
    aim = min(max(aim, -F.GIMBAL_YAW_LIMIT), F.GIMBAL_YAW_LIMIT) + pose[2]
    bearing = math.atan2(other_xy[1] - pose[1], other_xy[0] - pose[0]) - aim
    bearing = math.atan2(math.sin(bearing), math.cos(bearing))
    return abs(bearing) <= hfov / 2.0
