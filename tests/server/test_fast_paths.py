"""The arena's fast paths give exactly what the plain code they replace gives.

A decision's physics runs in :meth:`Stepper.run` (one kernel call per physics step), the
observation vector in one kernel, and shot selection decides clear cases without the exact
trigonometry; each is checked bit for bit against the straightforward version.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from neuronsmae.server import Arena
from neuronsmae.server.sim import field as F
from neuronsmae.server.sim import shots
from neuronsmae.server.task import observations as O
from neuronsmae.server.task import perception as P


def _per_step_run(arena: Arena):
    """``Stepper.run`` as the arena's per-step path (the one the zones option uses)."""

    def run(poses, cmd, targets, orders, t, limit, period, every, tally):
        ref = arena.referee
        for k in range(period):
            if k % every == 0:
                orders.apply(poses, ref.alive, cmd)
            if arena.stepper.step(poses, cmd, targets, tally):
                for i in np.flatnonzero(~ref.alive):
                    arena.chassis.stop(int(i))
                    cmd[i] = 0.0
            t += 1
            if ref.check_end(t, limit):
                break
        return t

    return run


def _bits(x: object) -> bytes:
    if isinstance(x, np.ndarray):
        return x.dtype.str.encode() + repr(x.shape).encode() + x.tobytes()
    if isinstance(x, dict):
        return b"{" + b",".join(_bits(k) + b":" + _bits(v) for k, v in x.items()) + b"}"
    if isinstance(x, (list, tuple)):
        return b"[" + b",".join(_bits(v) for v in x) + b"]"
    if isinstance(x, float):
        return x.hex().encode()
    return repr(x).encode()


@pytest.mark.parametrize(
    "options",
    [
        {"action_space": "continuous"},
        {"action_space": "abstract", "n_blue": 3, "n_red": 2, "hit_mode": "sampled"},
        {"action_space": "discrete", "mode": "competitive", "n_blue": 3, "n_red": 3},
    ],
)
def test_fused_decision_loop_matches_the_per_step_path(options: dict) -> None:
    arenas = [Arena(seed=5, **options), Arena(seed=5, **options)]
    arenas[1].stepper.run = _per_step_run(arenas[1])  # type: ignore[method-assign]
    rng = np.random.default_rng(3)
    trace: list[list[bytes]] = [[], []]
    for episode in range(2):
        for a, out in zip(arenas, trace, strict=True):
            out.append(_bits(a.reset({"level": "hard" if episode else "easy"})))
        for _ in range(60):
            masks = arenas[0].get_avail_actions()
            if options["action_space"] == "continuous":
                acts = [
                    np.array([*rng.uniform(-2, 2, 2), rng.uniform(-1.75, 1.75), np.argmax(m)])
                    for m in masks
                ]
            else:
                acts = [int(rng.choice(np.flatnonzero(m))) for m in masks]
            done = False
            for a, out in zip(arenas, trace, strict=True):
                obs, rew, done, info = a.step(acts)
                out.append(_bits([obs, rew, done, info, a.poses, a.chassis.state.rows]))
            if done:
                break
    for a in arenas:
        a.close()
    assert trace[0] == trace[1]


@pytest.mark.parametrize("partial", [False, True])
@pytest.mark.parametrize("with_cands", [False, True])
def test_observation_kernel_matches_the_array_version(partial: bool, with_cands: bool) -> None:
    rng = np.random.default_rng(11)
    a = Arena(seed=2, action_space="abstract", n_blue=2, n_red=3)
    a.reset()
    for _ in range(30):
        poses = np.column_stack(
            [rng.uniform(0, 8, 5), rng.uniform(0, 4.4, 5), rng.uniform(-4 * np.pi, 4 * np.pi, 5)]
        )
        hp, bullets = rng.uniform(0, 600, 5), rng.integers(0, 371, 5).astype(float)
        max_hp = np.array([600.0, 600.0, 300.0, 300.0, 300.0])
        max_bullets = np.array([370.0, 370.0, 470.0, 470.0, 670.0])
        cands, _ = P.all_candidates(poses, np.ones(5, bool), a.enemies_of, 4, np.ones(5, bool))
        seen = rng.random((2, 3)) < 0.5 if partial else np.ones((2, 3), bool)
        order = a._agent_order
        expected = O.vector_obs_batch(
            order,
            2,
            O.norm_pose(poses),
            O.norm_xy(cands[a.agents, :3]) if with_cands else None,
            O.norm_time(17, 1000),
            O.norm_hp(hp, max_hp),
            O.norm_bullets(bullets, max_bullets),
            seen,
            -0.5,
        ).astype(np.float32)
        got = np.empty_like(expected)
        O.vector_obs_kernel(
            order,
            2,
            poses,
            a.agents,
            cands if with_cands else np.zeros((0, 1, 1, 2)),
            O.norm_time(17, 1000),
            hp,
            max_hp,
            bullets,
            max_bullets,
            seen,
            -0.5,
            got,
        )
        assert got.tobytes() == expected.tobytes()
    a.close()


def _exact_select(poses, alive, bullets, targets, boxes, n_static, plates):
    """Shot selection with the exact bearing test and every box tested (the plain rules)."""
    n = poses.shape[0]
    plate_out, dist_out = np.full(n, -1), np.zeros(n)
    cos_inc = math.cos(math.pi / 2 - shots.MIN_INCIDENCE)
    for s in range(n):
        t = targets[s]
        if not alive[s] or bullets[s] <= 0 or t < 0 or t == s or not alive[t]:
            continue
        sx, sy, syaw = poses[s]
        tx, ty, tyaw = poses[t]
        aim = math.atan2(ty - sy, tx - sx) - syaw
        aim = math.atan2(math.sin(aim), math.cos(aim))
        aim = min(max(aim, -F.GIMBAL_YAW_LIMIT), F.GIMBAL_YAW_LIMIT) + syaw
        mx, my = sx + F.SHOOTER_OFFSET * math.cos(aim), sy + F.SHOOTER_OFFSET * math.sin(aim)
        ct, st = math.cos(tyaw), math.sin(tyaw)
        best = 1e9
        for p in range(4):
            px = tx + ct * plates[p, 0] - st * plates[p, 1]
            py = ty + st * plates[p, 0] + ct * plates[p, 1]
            dx, dy = px - mx, py - my
            d = math.sqrt(dx * dx + dy * dy)
            if d <= shots.MIN_RANGE or d >= shots.MAX_RANGE or d >= best:
                continue
            bearing = math.atan2(py - sy, px - sx) - syaw
            bearing = math.atan2(math.sin(bearing), math.cos(bearing))
            if abs(bearing) > shots.BEARING_LIMIT:
                continue
            nang = tyaw + plates[p, 2]
            if -(dx * math.cos(nang) + dy * math.sin(nang)) / d <= cos_inc:
                continue
            f = (d - shots.OCCLUSION_MARGIN) / d
            ex, ey = mx + dx * f, my + dy * f
            ez = F.SHOOTER_HEIGHT + (F.ARMOR_HEIGHT - F.SHOOTER_HEIGHT) * f
            rows = [boxes[b] for b in range(n_static)]
            rows += [boxes[n_static + r] for r in range(n) if r not in (s, t)]
            if not any(_exact_blocked(mx, my, F.SHOOTER_HEIGHT, ex, ey, ez, b) for b in rows):
                best, plate_out[s], dist_out[s] = d, p, d
    return plate_out, dist_out


def _exact_blocked(ax, ay, az, bx, by, bz, box) -> bool:
    c, s = box[6], box[7]
    px, py, qx, qy = ax - box[0], ay - box[1], bx - box[0], by - box[1]
    lx0, ly0, lx1, ly1 = c * px + s * py, -s * px + c * py, c * qx + s * qy, -s * qx + c * qy
    t0, t1 = 0.0, 1.0
    for d0, d1, half in ((lx0, lx1, box[2]), (ly0, ly1, box[3])):
        dd = d1 - d0
        if abs(dd) < 1e-12:
            if abs(d0) > half:
                return False
            continue
        ta, tb = sorted(((-half - d0) / dd, (half - d0) / dd))
        t0, t1 = max(t0, ta), min(t1, tb)
        if t0 > t1:
            return False
    return min(az + (bz - az) * t0, az + (bz - az) * t1) < box[5]


def test_shot_selection_quick_rejections_change_no_shot() -> None:
    rng = np.random.default_rng(4)
    static = F.obstacle_array(tall_only=True)
    n_static = len(static)
    for k in range(3000):
        n = int(rng.integers(2, 7))
        poses = np.column_stack(
            [rng.uniform(0, 8.08, n), rng.uniform(0, 4.48, n), rng.uniform(-np.pi, np.pi, n)]
        )
        if k % 2 == 0:  # robot 1's plate right at the edge of robot 0's bearing limit
            edge = shots.BEARING_LIMIT + rng.choice([0.0, 1e-12, -1e-12, 1e-7, -1e-7, 2e-6])
            ang = poses[0, 2] + rng.choice([-1, 1]) * edge
            p = int(rng.integers(4))
            c, s = math.cos(poses[1, 2]), math.sin(poses[1, 2])
            plate = F.ARMOR_TABLE[p]
            offset = np.array([c * plate[0] - s * plate[1], s * plate[0] + c * plate[1]])
            at = poses[0, :2] + rng.uniform(0.5, 4.0) * np.array([math.cos(ang), math.sin(ang)])
            poses[1, :2] = at - offset
        alive = rng.random(n) < 0.9
        targets = rng.integers(-1, n, n)
        if k % 2 == 0:
            alive[:2], targets[0] = True, 1
        bullets = np.full(n, 10.0)
        boxes = shots.with_trig(np.concatenate([static, np.zeros((n, 6))]))
        shots.fill_robot_boxes(poses, boxes[n_static:])
        plate_out, dist_out = np.zeros(n, np.int64), np.zeros(n)
        shots.select_shots(
            poses, alive, bullets, targets, boxes, n_static, F.ARMOR_TABLE, plate_out, dist_out
        )
        want_plate, want_dist = _exact_select(
            poses, alive, bullets, targets, boxes, n_static, F.ARMOR_TABLE
        )
        assert plate_out.tolist() == want_plate.tolist()
        assert dist_out.tobytes() == want_dist.tobytes()
