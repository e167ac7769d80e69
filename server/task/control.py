"""The controller: body-velocity commands for every robot from its intent, 10 times a second.

Each robot's command is recomputed at the first physics step of every decision and every
``CONTROL_EVERY`` steps after it within the decision, and held in between (so with
``decision_steps`` not a multiple of 5 the last update of a decision is held for fewer
steps; a new decision's intent takes effect at once):
a continuous action is its own command; a discrete move or a goal (abstract actions and bots,
followed along the planner's path) gives the translation, and the chassis auto-turns toward
the robot's target. The arena packs one decision's intents into :class:`Orders` once, and
each update is then one numba call for all robots instead of Python per robot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np

from neuronsmae.server.task.actions import KIND_CMD, KIND_GOAL, Intent

MAX_SPEED = 2.0
SLOW_RADIUS = 0.5
STOP_RADIUS = 0.15
LOOKAHEAD = 0.3
SLOW_GAIN = 2.0
"""The path follower's defaults (see :func:`follow`)."""
TURN_LIMIT = 2.0
"""Auto-turn rate limit (rad/s)."""


@numba.njit(cache=True)
def heading_rate(
    yaw: float, x: float, y: float, tx: float, ty: float, limit: float = TURN_LIMIT
) -> float:
    """Auto-turn: ω equals the heading error toward the target, clamped to ±limit rad/s."""
    err = math.atan2(ty - y, tx - x) - yaw
    err = math.atan2(math.sin(err), math.cos(err))
    return min(max(err, -limit), limit)


@numba.njit(cache=True)
def _follow_kernel(x, y, yaw, path, max_speed, slow_radius, stop_radius, lookahead, gain):
    n = path.shape[0]
    if n == 0:
        return 0.0, 0.0
    gx, gy = path[n - 1, 0], path[n - 1, 1]
    d_goal = math.hypot(gx - x, gy - y)
    if d_goal <= stop_radius:
        return 0.0, 0.0
    speed = max_speed if d_goal > slow_radius else min(max_speed, gain * d_goal)
    # Closest point on the polyline, then walk ``lookahead`` further along it.
    seg, best, px, py = 0, np.inf, path[0, 0], path[0, 1]
    for k in range(n - 1):
        ax, ay = path[k, 0], path[k, 1]
        bx, by = path[k + 1, 0] - ax, path[k + 1, 1] - ay
        l2 = bx * bx + by * by
        u = 0.0 if l2 == 0.0 else min(max(((x - ax) * bx + (y - ay) * by) / l2, 0.0), 1.0)
        d2 = (ax + u * bx - x) ** 2 + (ay + u * by - y) ** 2
        if d2 < best:
            seg, best, px, py = k, d2, ax + u * bx, ay + u * by
    tx, ty, remaining = gx, gy, lookahead
    for k in range(seg + 1, n):
        ex, ey = path[k, 0], path[k, 1]
        seg_len = math.hypot(ex - px, ey - py)
        if seg_len >= remaining:
            f = remaining / seg_len
            tx, ty = px + (ex - px) * f, py + (ey - py) * f
            break
        remaining -= seg_len
        px, py = ex, ey
    dx, dy = tx - x, ty - y
    norm = math.hypot(dx, dy)
    if norm < 1e-9:
        dx, dy, norm = gx - x, gy - y, d_goal
    vx, vy = speed * dx / norm, speed * dy / norm
    c, s = math.cos(yaw), math.sin(yaw)
    return c * vx + s * vy, -s * vx + c * vy


def follow(
    pose: tuple[float, float, float],
    path: np.ndarray | None,
    goal_xy: np.ndarray,
    max_speed: float = MAX_SPEED,
    slow_radius: float = SLOW_RADIUS,
    stop_radius: float = STOP_RADIUS,
    lookahead: float = LOOKAHEAD,
    slow_gain: float = SLOW_GAIN,
) -> tuple[float, float]:
    """Body-frame translational command ``(v_forward, v_left)`` to follow ``path``.

    Heads for the point ``lookahead`` metres along the path beyond the robot's closest point;
    speed is ``max_speed`` beyond ``slow_radius`` of the path's end, ``slow_gain``·d inside it,
    and 0 within ``stop_radius``. The path's end is the goal (it differs from ``goal_xy``
    only when the planner moved an impassable goal). An empty path (no path) gives (0, 0);
    ``path=None`` drives straight at ``goal_xy``. Turning is the caller's job.
    """
    if path is None:
        path = np.asarray(goal_xy, np.float64).reshape(1, 2)
    v = _follow_kernel(
        float(pose[0]), float(pose[1]), float(pose[2]),
        np.ascontiguousarray(path, dtype=np.float64), float(max_speed), float(slow_radius),
        float(stop_radius), float(lookahead), float(slow_gain),
    )  # fmt: skip
    return float(v[0]), float(v[1])


@numba.njit(cache=True)
def control_kernel(poses, alive, intent, pts, off, cmd) -> None:
    """Every robot's command (forward, left, ω) into ``cmd`` (N, 3); see :class:`Orders`."""
    for i in range(poses.shape[0]):
        kind = int(intent[i, 0])
        if not alive[i]:
            cmd[i, 0], cmd[i, 1], cmd[i, 2] = 0.0, 0.0, 0.0
            continue
        if kind == KIND_CMD:
            cmd[i, 0], cmd[i, 1], cmd[i, 2] = intent[i, 2], intent[i, 3], intent[i, 4]
            continue
        x, y, yaw = poses[i, 0], poses[i, 1], poses[i, 2]
        if kind == KIND_GOAL:
            path = pts[off[i] : off[i + 1]]
            vf, vl = _follow_kernel(
                x, y, yaw, path, MAX_SPEED, SLOW_RADIUS, STOP_RADIUS, LOOKAHEAD, SLOW_GAIN
            )
        else:
            vf, vl = intent[i, 2], intent[i, 3]
        t = int(intent[i, 1])
        cmd[i, 0], cmd[i, 1] = vf, vl
        cmd[i, 2] = heading_rate(yaw, x, y, poses[t, 0], poses[t, 1], TURN_LIMIT)


class Orders:
    """One decision's intents and planned paths, packed as arrays for :meth:`apply`."""

    def __init__(self, intents: Sequence[Intent], paths: Sequence[np.ndarray | None]) -> None:
        """``paths[i]`` is robot ``i``'s planned path for a goal intent (``None``: drive
        straight at the goal, as :func:`follow` does)."""
        rows, segs, off, total = [], [], [0], 0
        for it, path in zip(intents, paths, strict=True):
            rows.append((it.kind, it.target, *it.vel))
            if it.kind == KIND_GOAL:
                seg = np.asarray(it.goal, np.float64).reshape(1, 2) if path is None else path
                segs.append(seg)
                total += len(seg)
            off.append(total)
        self.intent = np.array(rows, dtype=np.float64)
        """(N, 5): kind, target, then the velocity (forward, left, ω) of ``Intent.vel``."""
        self.off = np.array(off, dtype=np.int64)
        """(N + 1,): robot ``i``'s path is ``pts[off[i]:off[i + 1]]``."""
        self.pts = np.concatenate(segs) if segs else np.zeros((0, 2))

    def apply(self, poses: np.ndarray, alive: np.ndarray, cmd: np.ndarray) -> None:
        """Write every robot's command for the current poses into ``cmd`` (N, 3), in place;
        destroyed robots get zero."""
        control_kernel(poses, alive, self.intent, self.pts, self.off, cmd)
