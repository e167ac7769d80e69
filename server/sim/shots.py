"""Shot selection as a numba kernel: which armour plate, if any, each robot hits this step.

The referee calls :func:`select_shots` once per physics step for all robots, so it is one
compiled function over arrays rather than Python per robot per plate. Occlusion is a ray
test in 3-D against the field's boxes: the ray runs from the muzzle (0.374 m high) down to
the plate (0.195 m), so tall obstacles and robots block it while the low ones (≤ 0.145 m)
cannot, exactly as heights dictate; anything within 8 cm of the plate is ignored (the
target's own body around its plate).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from neuronsmae.server.sim import field as F

MIN_RANGE = 0.3
MAX_RANGE = 9.0
BEARING_LIMIT = 0.52
MIN_INCIDENCE = math.radians(35.0)
OCCLUSION_MARGIN = 0.08
BANDS = np.array([3.0, 6.0], dtype=np.float64)
FACTORS = np.array([1.0, 0.5, 0.2], dtype=np.float64)
FL_HP, FL_BULLETS, FL_SCALE, FL_DIST, FL_DEALT, FL_TAKEN = range(6)
"""Rows of the referee's packed float array: HP, bullets, damage scale, shot distance (scratch),
damage dealt and taken."""
IT_TEAM, IT_KILLS, IT_PLATE = range(3)
"""Rows of the referee's packed int array: team, kills, plate hit this step (-1 for none)."""
SKIP_MARGIN = 1e-6
"""Quick rejections (a box far from a ray, a plate far outside the bearing limit) decide
only cases this far (m, or cosine) from the edge, where rounding cannot change the exact
test's answer; closer cases take the exact test. They save time, never change a shot."""
COS_BEARING = math.cos(BEARING_LIMIT)


@nb.njit(cache=True)
def hit_factor(d: float) -> float:
    """Expected hit fraction by distance: 1.0 below 3 m, 0.5 to 6 m, 0.2 beyond."""
    if d < 3.0:
        return 1.0
    if d < 6.0:
        return 0.5
    return 0.2


@nb.njit(cache=True)
def segment_box_blocked(ax, ay, az, bx, by, bz, box) -> bool:
    """Does the 3-D segment A→B pass through the vertical box (cx, cy, hx, hy, yaw, h)?

    A row may carry cos(yaw), sin(yaw) in columns 6 and 7 (:func:`with_trig`), so the
    per-step ray tests do not recompute them for every shooter and plate.
    """
    # A box whose bounding circle (radius below hx + hy) lies clear of the segment's
    # bounding box by more than rounding could ever matter cannot be crossed: the slab test
    # below would say so too, so skipping it changes no answer.
    r = box[2] + box[3] + SKIP_MARGIN
    if (
        min(ax, bx) > box[0] + r
        or max(ax, bx) < box[0] - r
        or min(ay, by) > box[1] + r
        or max(ay, by) < box[1] - r
    ):
        return False
    if box.shape[0] >= 8:
        c, s = box[6], box[7]
    else:
        c, s = math.cos(box[4]), math.sin(box[4])
    # Into the box frame.
    px, py = ax - box[0], ay - box[1]
    lx0, ly0 = c * px + s * py, -s * px + c * py
    qx, qy = bx - box[0], by - box[1]
    lx1, ly1 = c * qx + s * qy, -s * qx + c * qy
    t0, t1 = 0.0, 1.0
    for d0, d1, half in ((lx0, lx1, box[2]), (ly0, ly1, box[3])):
        dd = d1 - d0
        if abs(dd) < 1e-12:
            if abs(d0) > half:
                return False
            continue
        ta, tb = (-half - d0) / dd, (half - d0) / dd
        if ta > tb:
            ta, tb = tb, ta
        t0, t1 = max(t0, ta), min(t1, tb)
        if t0 > t1:
            return False
    z_low = min(az + (bz - az) * t0, az + (bz - az) * t1)
    return z_low < box[5]


@nb.njit(cache=True)
def select_shots(poses, alive, bullets, targets, boxes, n_static, plates, out_plate, out_dist):
    """For each robot, the plate of its target it hits this step (-1 for none).

    poses (N, 3); alive (N,) bool; bullets (N,) float; targets (N,) int robot index or -1;
    boxes (S + N, 6) as (cx, cy, hx, hy, yaw, height): the S = ``n_static`` tall obstacles,
    then one row per robot; plates (4, 4) along, across, normal angle, multiplier. Writes
    out_plate (N,) int and out_dist (N,) float (muzzle-to-plate distance of the chosen plate).
    """
    n = poses.shape[0]
    cos_inc = math.cos(math.pi / 2 - MIN_INCIDENCE)
    for s in range(n):
        out_plate[s] = -1
        out_dist[s] = 0.0
        t = targets[s]
        if not alive[s] or bullets[s] <= 0 or t < 0 or t == s or not alive[t]:
            continue
        sx, sy, syaw = poses[s, 0], poses[s, 1], poses[s, 2]
        tx, ty, tyaw = poses[t, 0], poses[t, 1], poses[t, 2]
        # The gimbal turns toward the target (within ±90° of the chassis); the muzzle sits
        # 0.18 m ahead of its axis.
        aim = math.atan2(ty - sy, tx - sx) - syaw
        aim = math.atan2(math.sin(aim), math.cos(aim))
        aim = min(max(aim, -F.GIMBAL_YAW_LIMIT), F.GIMBAL_YAW_LIMIT) + syaw
        mx = sx + F.SHOOTER_OFFSET * math.cos(aim)
        my = sy + F.SHOOTER_OFFSET * math.sin(aim)
        ct, st = math.cos(tyaw), math.sin(tyaw)
        hx, hy = math.cos(syaw), math.sin(syaw)
        best = 1e9
        for p in range(4):
            px = tx + ct * plates[p, 0] - st * plates[p, 1]
            py = ty + st * plates[p, 0] + ct * plates[p, 1]
            dx, dy = px - mx, py - my
            d = math.sqrt(dx * dx + dy * dy)
            if d <= MIN_RANGE or d >= MAX_RANGE or d >= best:
                continue
            # Bearing from the chassis within ±BEARING_LIMIT: the cosine to the heading
            # decides all but the edge cases, which take the exact angle (the plate is
            # more than 0.1 m from the robot's centre here, as the muzzle is 0.18 m ahead).
            ux, uy = px - sx, py - sy
            cos_b = (ux * hx + uy * hy) / math.sqrt(ux * ux + uy * uy)
            if cos_b < COS_BEARING - SKIP_MARGIN:
                continue
            if cos_b <= COS_BEARING + SKIP_MARGIN:
                bearing = math.atan2(py - sy, px - sx) - syaw
                bearing = math.atan2(math.sin(bearing), math.cos(bearing))
                if abs(bearing) > BEARING_LIMIT:
                    continue
            nang = tyaw + plates[p, 2]
            # The shot must meet the plate surface at more than 35°: the angle between the
            # reversed shot and the plate's outward normal must be below 55°.
            if -(dx * math.cos(nang) + dy * math.sin(nang)) / d <= cos_inc:
                continue
            # Stop the ray 8 cm short of the plate; the 3-D segment descends to the plate.
            f = (d - OCCLUSION_MARGIN) / d
            ex, ey = mx + dx * f, my + dy * f
            ez = F.SHOOTER_HEIGHT + (F.ARMOR_HEIGHT - F.SHOOTER_HEIGHT) * f
            blocked = False
            for b in range(n_static):
                if segment_box_blocked(mx, my, F.SHOOTER_HEIGHT, ex, ey, ez, boxes[b]):
                    blocked = True
                    break
            if not blocked:
                for r in range(n):
                    if (
                        r != s
                        and r != t
                        and segment_box_blocked(
                            mx, my, F.SHOOTER_HEIGHT, ex, ey, ez, boxes[n_static + r]
                        )
                    ):
                        blocked = True
                        break
            if not blocked:
                best = d
                out_plate[s] = p
                out_dist[s] = d


@nb.njit(cache=True)
def fill_robot_boxes(poses, out):
    """Robot footprints as boxes (cx, cy, hx, hy, yaw, height) for ray tests."""
    for i in range(poses.shape[0]):
        out[i, 0] = poses[i, 0]
        out[i, 1] = poses[i, 1]
        out[i, 2] = F.ROBOT_LENGTH / 2
        out[i, 3] = F.ROBOT_WIDTH / 2
        out[i, 4] = poses[i, 2]
        out[i, 5] = F.ROBOT_HEIGHT
        if out.shape[1] >= 8:
            out[i, 6] = math.cos(poses[i, 2])
            out[i, 7] = math.sin(poses[i, 2])


@nb.njit(cache=True)
def with_trig(boxes: np.ndarray) -> np.ndarray:
    """Box rows (n, 6) → (n, 8) with cos(yaw), sin(yaw) appended (numba's math, the same
    values :func:`segment_box_blocked` would compute)."""
    out = np.empty((boxes.shape[0], 8))
    for i in range(boxes.shape[0]):
        out[i, :6] = boxes[i, :6]
        out[i, 6] = math.cos(boxes[i, 4])
        out[i, 7] = math.sin(boxes[i, 4])
    return out


@nb.njit(cache=True)
def fire(poses, alive, fl, it, targets, boxes, n_static, draws, tally_damage, tally_kills) -> int:
    """One physics step of shooting: select shots, spend bullets, apply damage, count kills.

    Shots are simultaneous: all are chosen from the same poses before any damage lands.
    ``fl`` (6, N) and ``it`` (3, N) are the referee's packed per-robot rows (``FL_*`` and
    ``IT_*``; few arguments keep numba's per-call dispatch cheap on this per-step path);
    ``boxes`` (S + N, 8) the tall obstacles then scratch rows for the robots, with trig
    columns (:func:`with_trig`). ``draws`` (N,)
    holds uniform numbers for sampled hits, or is empty for expected damage. A victim's
    actual HP loss is shared among its shooters in proportion to what each fired; the kill
    goes to the shooter that dealt the most (lowest index on ties). Returns the number of
    robots destroyed this step.
    """
    hp, bullets, scale, dist_out = fl[FL_HP], fl[FL_BULLETS], fl[FL_SCALE], fl[FL_DIST]
    dealt_total, taken_total = fl[FL_DEALT], fl[FL_TAKEN]
    team, kills, plate_out = it[IT_TEAM], it[IT_KILLS], it[IT_PLATE]
    plates = F.ARMOR_TABLE
    n = poses.shape[0]
    fill_robot_boxes(poses, boxes[n_static:])
    select_shots(poses, alive, bullets, targets, boxes, n_static, plates, plate_out, dist_out)
    raw = np.zeros(n)
    incoming = np.zeros(n)
    for s in range(n):
        p = plate_out[s]
        if p < 0:
            continue
        bullets[s] -= 1.0
        f = hit_factor(dist_out[s])
        if draws.shape[0] > 0:
            f = 1.0 if draws[s] < f else 0.0
        raw[s] = f * plates[p, 3] * scale[s]
        incoming[targets[s]] += raw[s]
    destroyed = 0
    for v in range(n):
        if incoming[v] <= 0.0:
            continue
        lost = min(incoming[v], hp[v])
        share = lost / incoming[v]
        hp[v] -= lost
        taken_total[v] += lost
        killer, best = -1, -1.0
        for s in range(n):
            if plate_out[s] >= 0 and targets[s] == v:
                d = raw[s] * share
                dealt_total[s] += d
                tally_damage[team[s]] += d
                if d > best:
                    killer, best = s, d
        if hp[v] <= 1e-9 and alive[v]:
            hp[v] = 0.0
            alive[v] = False
            kills[killer] += 1
            tally_kills[team[killer]] += 1
            destroyed += 1
    return destroyed
