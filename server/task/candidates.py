"""Candidate shooting points around an enemy: the abstract action space's targets.

The abstract action picks an enemy and one of ``k`` points to drive to. Following the
released build (``docs/reference.md``, "Candidate points"): sample ``n_samples``
points evenly on a circle of ``radius`` (2.5 m, the best shooting distance) around the
enemy; drop those outside ``x ∈ [0.2, 7.8], y ∈ [0.2, 4.0]``, inside an obstacle grown by
the robot's half-size (0.30 m), inside the ±0.6 m square around another robot, or without
line of sight to the enemy (tall obstacles only); cluster the rest into ``k`` groups with
k-means and keep, for each centre, the nearest surviving point.

The computation runs for every enemy of every robot at every decision, so it is one
``numba`` kernel of a few tens of microseconds, and :func:`all_candidate_points` does a
whole decision in one call, sharing the filter pass among the robots asking about the same
enemy. The k-means is a deterministic Lloyd
iteration written here rather than ``scipy.cluster.vq.kmeans2`` or scikit-learn: those
cost on the order of milliseconds per call (about 100× this whole budget) and seed their
centres randomly, which would make the observation depend on an RNG. Because the kept
points lie on arcs of one circle, initialising the centres evenly along the kept points in
angular order (starting after the widest angular gap, so no arc is cut in two) already
places them close to the optimum and Lloyd converges in a few iterations.

Output conventions (the environment and the bots rely on them):

* the ``k`` points are distinct surviving samples, ordered by their angle around the
  enemy, counter-clockwise from +x in ``[0, 2π)``;
* with fewer than ``k`` surviving samples, all of them in that order, the last repeated;
* with none, the "stay" sentinel: every row is the asking robot's own position (so the
  planner, driving there, stops) and ``valid`` is all ``False``. ``valid`` is ``True`` for
  every row otherwise (repeated rows are real, reachable points too).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from neuronsmae.server.sim.field import SPAWN_OBSTACLE_MARGIN
from neuronsmae.server.task.geometry import SIGHT_MIN_HEIGHT, point_in_grown_box, slab_clip

RADIUS = 2.5
"""Circle radius (m): the best shooting distance (hit factor 1 below 3 m)."""
N_SAMPLES = 180
K = 4
BOUNDS = (0.2, 7.8, 0.2, 4.0)
"""x_min, x_max, y_min, y_max of admissible points (released build; inclusive)."""
OBSTACLE_MARGIN = SPAWN_OBSTACLE_MARGIN
"""Obstacles are grown by the robot's half-size, 0.30 m."""
ROBOT_CLEARANCE = 0.6
"""A point is dropped when ``|dx| < 0.6`` and ``|dy| < 0.6`` from another robot."""
MAX_LLOYD_ITERATIONS = 50
FREE, DROPPED = -1, -2
"""Sample codes of :func:`_filter_samples` (codes >= 0 name the one robot in the way)."""


@numba.njit(cache=True)
def _filter_samples(
    ex: float,
    ey: float,
    others: np.ndarray,
    boxes: np.ndarray,
    radius: float,
    n_samples: int,
    x_min: float,
    x_max: float,
    y_min: float,
    y_max: float,
    margin: float,
    clearance: float,
    sight_min_height: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Sample the circle and run the filters for every possible asker at once.

    Returns ``(points (n_samples, 2), code (n_samples,))`` where ``code`` is ``FREE`` for a
    sample every filter keeps, the index in ``others`` of the one robot whose square holds
    it (kept only for that robot as the asker), or ``DROPPED``. One pass serves every robot
    asking about the same enemy (:func:`_select` picks its samples); the filters are plain
    conjunctions, so the kept set is the same as filtering for one asker directly.

    Filters run cheapest first (bounds, robot squares, grown obstacles, then sight), and
    only against the boxes that can matter for this circle: a box whose bounding circle
    misses the sampling circle cannot contain a sample, and a box wholly farther than
    ``radius`` from the enemy cannot cut a sight line. For the sight test the enemy is
    moved into each box's frame once, so a sample costs one rotation per box.
    """
    nb = boxes.shape[0]
    grown = np.empty(nb, dtype=np.int64)  # boxes that may contain a sample
    sight = np.empty(nb, dtype=np.int64)  # tall boxes that may cut a sight line
    n_grown = 0
    n_sight = 0
    # Per box: cos, sin, enemy's local x, y.
    frame = np.empty((nb, 4))
    for i in range(nb):
        c = math.cos(boxes[i, 4])
        s = math.sin(boxes[i, 4])
        ax = ex - boxes[i, 0]
        ay = ey - boxes[i, 1]
        frame[i, 0] = c
        frame[i, 1] = s
        frame[i, 2] = c * ax + s * ay
        frame[i, 3] = -s * ax + c * ay
        d = math.sqrt(ax * ax + ay * ay)
        r = boxes[i, 2] + boxes[i, 3]  # ≥ the box's circumradius
        rg = r + 2.0 * margin  # ≥ the grown box's circumradius
        if d - rg < radius < d + rg:
            grown[n_grown] = i
            n_grown += 1
        if boxes[i, 5] > sight_min_height and d - r < radius:
            sight[n_sight] = i
            n_sight += 1
    pts = np.empty((n_samples, 2))
    code = np.full(n_samples, DROPPED, dtype=np.int64)
    # Unit vectors by rotation recurrence: 2 trig calls instead of 2 per sample; the
    # accumulated error over 180 steps is ~1e-14 m.
    step = 2.0 * math.pi / n_samples
    cstep = math.cos(step)
    sstep = math.sin(step)
    ux = 1.0
    uy = 0.0
    for j in range(n_samples):
        if j > 0:
            ux, uy = ux * cstep - uy * sstep, ux * sstep + uy * cstep
        x = ex + radius * ux
        y = ey + radius * uy
        pts[j, 0] = x
        pts[j, 1] = y
        if x < x_min or x > x_max or y < y_min or y > y_max:
            continue
        holder = FREE
        for r in range(others.shape[0]):
            if abs(x - others[r, 0]) < clearance and abs(y - others[r, 1]) < clearance:
                if holder != FREE:  # two robots: no asker can have it
                    holder = DROPPED
                    break
                holder = r
        if holder == DROPPED:
            continue
        ok = True
        for q in range(n_grown):
            i = grown[q]
            if point_in_grown_box(x, y, boxes[i], frame[i, 0], frame[i, 1], margin):
                ok = False
                break
        if not ok:
            continue
        for q in range(n_sight):
            i = sight[q]
            c = frame[i, 0]
            s = frame[i, 1]
            # Sample → enemy in the box frame; the sample's local position is the enemy's
            # plus the rotated offset.
            ox = radius * ux
            oy = radius * uy
            lx = frame[i, 2] + c * ox + s * oy
            ly = frame[i, 3] - s * ox + c * oy
            t0, t1 = slab_clip(lx, frame[i, 2] - lx, boxes[i, 2], 0.0, 1.0)
            if t0 > t1:
                continue
            t0, t1 = slab_clip(ly, frame[i, 3] - ly, boxes[i, 3], t0, t1)
            if t0 <= t1:
                ok = False
                break
        if ok:
            code[j] = holder
    return pts, code


@numba.njit(cache=True)
def _select(
    all_pts: np.ndarray, code: np.ndarray, skip: int, pts: np.ndarray, idx: np.ndarray
) -> int:
    """The samples kept for the asker ``skip`` (-1: none) into ``pts``/``idx``; the count."""
    n = 0
    for j in range(code.shape[0]):
        if code[j] == FREE or (code[j] >= 0 and code[j] == skip):
            pts[n, 0] = all_pts[j, 0]
            pts[n, 1] = all_pts[j, 1]
            idx[n] = j
            n += 1
    return n


@numba.njit(cache=True)
def _kept_samples(
    ex: float, ey: float, others: np.ndarray, skip: int, boxes: np.ndarray, radius: float,
    n_samples: int, x_min: float, x_max: float, y_min: float, y_max: float, margin: float,
    clearance: float, sight_min_height: float,
) -> tuple[np.ndarray, np.ndarray, int]:  # fmt: skip
    """Sample the circle and filter it for one asker (``skip``, -1 for none: every robot's
    square forbids points); returns (points, sample indices, count kept)."""
    all_pts, code = _filter_samples(
        ex, ey, others, boxes, radius, n_samples, x_min, x_max, y_min, y_max, margin,
        clearance, sight_min_height,
    )  # fmt: skip
    pts = np.empty((n_samples, 2))
    idx = np.empty(n_samples, dtype=np.int64)
    return pts, idx, _select(all_pts, code, skip, pts, idx)


@numba.njit(cache=True)
def _lloyd(
    pts: np.ndarray, idx: np.ndarray, n: int, k: int, n_samples: int, max_iter: int
) -> np.ndarray:
    """Deterministic k-means (``n > k``) on the first ``n`` points; returns ``(k, 2)`` centres.

    Centres start at evenly spaced points along the kept samples in angular order, rotated
    to begin after the widest angular gap so an arc crossing angle 0 stays in one piece.
    An emptied cluster keeps its previous centre.
    """
    # Start after the widest cyclic gap between consecutive kept sample indices.
    start = 0
    widest = idx[0] + n_samples - idx[n - 1]
    for i in range(n - 1):
        g = idx[i + 1] - idx[i]
        if g > widest:
            widest = g
            start = i + 1
    centres = np.empty((k, 2))
    for c in range(k):
        p = (start + int((c + 0.5) * n / k)) % n
        centres[c, 0] = pts[p, 0]
        centres[c, 1] = pts[p, 1]
    label = np.full(n, -1, dtype=np.int64)
    sums = np.empty((k, 2))
    counts = np.empty(k, dtype=np.int64)
    for _ in range(max_iter):
        changed = False
        for p in range(n):
            best = 0
            best_d = np.inf
            for c in range(k):
                dx = pts[p, 0] - centres[c, 0]
                dy = pts[p, 1] - centres[c, 1]
                d = dx * dx + dy * dy
                if d < best_d:
                    best_d = d
                    best = c
            if label[p] != best:
                label[p] = best
                changed = True
        if not changed:
            break
        sums[:] = 0.0
        counts[:] = 0
        for p in range(n):
            sums[label[p], 0] += pts[p, 0]
            sums[label[p], 1] += pts[p, 1]
            counts[label[p]] += 1
        for c in range(k):
            if counts[c] > 0:
                centres[c, 0] = sums[c, 0] / counts[c]
                centres[c, 1] = sums[c, 1] / counts[c]
    return centres


@numba.njit(cache=True)
def _candidates_kernel(
    ex: float, ey: float, others: np.ndarray, skip: int, boxes: np.ndarray, k: int,
    radius: float, n_samples: int, x_min: float, x_max: float, y_min: float, y_max: float,
    margin: float, clearance: float, sight_min_height: float, stay_x: float, stay_y: float,
    max_iter: int,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The whole candidate-point computation for one enemy (see the module docstring)."""
    pts, idx, n = _kept_samples(
        ex, ey, others, skip, boxes, radius, n_samples, x_min, x_max, y_min, y_max, margin,
        clearance, sight_min_height,
    )  # fmt: skip
    out = np.empty((k, 2))
    valid = np.empty(k, dtype=np.bool_)
    _choose(pts, idx, n, n_samples, stay_x, stay_y, max_iter, out, valid)
    return out, valid


@numba.njit(cache=True)
def _choose(
    pts: np.ndarray, idx: np.ndarray, n: int, n_samples: int, stay_x: float, stay_y: float,
    max_iter: int, out: np.ndarray, valid: np.ndarray,
) -> None:  # fmt: skip
    """The ``k = len(out)`` points from the ``n`` kept samples, into ``out`` and ``valid``."""
    k = out.shape[0]
    valid[:] = True
    if n == 0:
        for c in range(k):
            out[c, 0] = stay_x
            out[c, 1] = stay_y
            valid[c] = False
        return
    if n <= k:
        for c in range(k):
            p = min(c, n - 1)
            out[c, 0] = pts[p, 0]
            out[c, 1] = pts[p, 1]
        return
    centres = _lloyd(pts, idx, n, k, n_samples, max_iter)
    # Nearest not-yet-taken kept point per centre, so the k outputs are distinct.
    taken = np.zeros(n, dtype=np.bool_)
    chosen = np.empty(k, dtype=np.int64)
    for c in range(k):
        best = -1
        best_d = np.inf
        for p in range(n):
            if taken[p]:
                continue
            dx = pts[p, 0] - centres[c, 0]
            dy = pts[p, 1] - centres[c, 1]
            d = dx * dx + dy * dy
            if d < best_d:
                best_d = d
                best = p
        taken[best] = True
        chosen[c] = best
    # Kept points are stored in increasing sample index = increasing angle from +x.
    chosen.sort()
    for c in range(k):
        out[c, 0] = pts[chosen[c], 0]
        out[c, 1] = pts[chosen[c], 1]


def _rows(a: np.ndarray, cols: int) -> np.ndarray:
    """``a`` as a C-contiguous float64 ``(n, cols)`` array, copying only when it must.

    The fast path matters: this wrapper runs 8 times per decision.
    """
    if (
        type(a) is np.ndarray
        and a.dtype == np.float64
        and a.ndim == 2
        and a.shape[1] == cols
        and a.flags.c_contiguous
    ):
        return a
    return np.ascontiguousarray(a, dtype=np.float64).reshape(-1, cols)


def candidate_points(
    enemy_xy: np.ndarray,
    others_xy: np.ndarray,
    boxes: np.ndarray,
    k: int = K,
    radius: float = RADIUS,
    n_samples: int = N_SAMPLES,
    *,
    asker: int | None = None,
    asker_blocks: bool = False,
    margin: float = OBSTACLE_MARGIN,
    clearance: float = ROBOT_CLEARANCE,
    bounds: tuple[float, float, float, float] = BOUNDS,
    sight_min_height: float = SIGHT_MIN_HEIGHT,
) -> tuple[np.ndarray, np.ndarray]:
    """``k`` candidate shooting points around one enemy and which of them are real.

    Args:
        enemy_xy: the enemy's position ``(2,)``.
        others_xy: ``(M, 2)`` positions of every robot except this enemy (allies, the other
            enemy, destroyed robots, the asking robot); each forbids the ±``clearance``
            square around it.
        boxes: ``(n, 6)`` obstacle rows (``field.obstacle_array()``). All of them, grown by
            ``margin``, forbid points; those taller than ``sight_min_height`` also block
            the line of sight from a point to the enemy. Robots are not sight blockers here.
        k, radius, n_samples: number of outputs, circle radius (m), samples on the circle.
        asker: index in ``others_xy`` of the robot asking. Its position is the "stay"
            sentinel returned when no point survives; without it the sentinel rows are NaN.
        asker_blocks: whether the asker's own square forbids points too. Off by default: a
            robot already standing at a good point should be offered it.
        margin, clearance, bounds, sight_min_height: the filters' parameters (defaults are
            the released build's).

    Returns:
        ``(points (k, 2), valid (k,) bool)`` following the conventions in the module
        docstring: distinct points ordered counter-clockwise from +x, the last repeated when
        fewer than ``k`` survive, the sentinel with ``valid`` all ``False`` when none do.
    """
    if k < 1 or n_samples < 1:
        raise ValueError(f"k and n_samples must be positive, got k={k}, n_samples={n_samples}")
    others = _rows(others_xy, 2)
    box_arr = _rows(boxes, 6)
    if asker is None:
        skip, stay_x, stay_y = -1, math.nan, math.nan
    else:
        skip = -1 if asker_blocks else int(asker)
        stay_x, stay_y = float(others[asker, 0]), float(others[asker, 1])
    x_min, x_max, y_min, y_max = bounds
    return _candidates_kernel(
        float(enemy_xy[0]),
        float(enemy_xy[1]),
        others,
        skip,
        box_arr,
        int(k),
        float(radius),
        int(n_samples),
        float(x_min),
        float(x_max),
        float(y_min),
        float(y_max),
        float(margin),
        float(clearance),
        float(sight_min_height),
        stay_x,
        stay_y,
        MAX_LLOYD_ITERATIONS,
    )


@numba.njit(cache=True)
def _batch_kernel(
    xy, alive, enemies, wanted, boxes, radius, n_samples, x_min, x_max, y_min, y_max,
    margin, clearance, sight_min_height, max_iter, cands, valid,
) -> None:  # fmt: skip
    """Candidate points of every wanted live robot around each of its live enemies.

    Works enemy by enemy: one filter pass serves every robot asking about that enemy, and
    the k-means runs again only when an asker's kept samples differ from the previous
    asker's (they differ only by samples in the askers' own squares). ``enemies`` (N, E)
    lists each robot's enemies (-1 padding); rows of ``cands``/``valid`` nobody computes
    keep the caller's "stay" sentinel.
    """
    n = xy.shape[0]
    others = np.empty((n - 1, 2))
    pts = np.empty((n_samples, 2))
    idx = np.empty(n_samples, dtype=np.int64)
    prev_idx = np.empty(n_samples, dtype=np.int64)
    for e in range(n):
        if not alive[e]:
            continue
        for r in range(n - 1):
            q = r if r < e else r + 1
            others[r, 0] = xy[q, 0]
            others[r, 1] = xy[q, 1]
        code = np.empty(0, dtype=np.int64)
        all_pts = np.empty((0, 2))
        filtered = False
        prev_n, prev_i, prev_j = -1, -1, -1
        for i in range(n):
            if not (wanted[i] and alive[i]):
                continue
            for j in range(enemies.shape[1]):
                if enemies[i, j] != e:
                    continue
                if not filtered:  # only for enemies someone asks about
                    filtered = True
                    all_pts, code = _filter_samples(
                        xy[e, 0], xy[e, 1], others, boxes, radius, n_samples, x_min, x_max,
                        y_min, y_max, margin, clearance, sight_min_height,
                    )  # fmt: skip
                m = _select(all_pts, code, i if i < e else i - 1, pts, idx)
                same = m == prev_n and m > 0
                for p in range(m if same else 0):
                    if idx[p] != prev_idx[p]:
                        same = False
                        break
                if same:
                    cands[i, j] = cands[prev_i, prev_j]
                    valid[i, j] = valid[prev_i, prev_j]
                else:
                    _choose(
                        pts, idx, m, n_samples, xy[i, 0], xy[i, 1], max_iter, cands[i, j],
                        valid[i, j],
                    )  # fmt: skip
                    prev_idx[:m] = idx[:m]
                    prev_n, prev_i, prev_j = m, i, j


def all_candidate_points(
    xy: np.ndarray,
    alive: np.ndarray,
    enemies: np.ndarray,
    wanted: np.ndarray,
    boxes: np.ndarray,
    k: int = K,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`candidate_points` for every wanted live robot around each of its live enemies.

    ``xy`` (N, 2) positions, or (N, 3) poses whose first two columns are used, ``enemies``
    (N, E) each robot's enemies (-1 padding), ``alive`` and ``wanted`` (N,) bool. Each robot
    asks as itself (``asker``: its own square does not forbid points). Returns
    ``(cands (N, E, k, 2), valid (N, E, k))``; rows not computed (robot or enemy destroyed,
    robot not wanted) hold the robot's own position, not valid. One numba call for the whole
    decision, identical to calling :func:`candidate_points` per pair.
    """
    if not (
        type(xy) is np.ndarray
        and xy.dtype == np.float64
        and xy.ndim == 2
        and xy.shape[1] in (2, 3)
        and xy.flags.c_contiguous
    ):  # the kernel reads columns 0 and 1 of any C-contiguous (N, 2) or (N, 3) array
        xy = _rows(xy, 2)
    n, n_enemy = enemies.shape
    cands = np.empty((n, n_enemy, k, 2))
    cands[...] = xy[:, None, None, :2]
    valid = np.zeros((n, n_enemy, k), dtype=bool)
    x_min, x_max, y_min, y_max = BOUNDS
    _batch_kernel(
        xy, alive, enemies, wanted, _rows(boxes, 6), RADIUS, N_SAMPLES, x_min, x_max, y_min,
        y_max, OBSTACLE_MARGIN, ROBOT_CLEARANCE, SIGHT_MIN_HEIGHT, MAX_LLOYD_ITERATIONS,
        cands, valid,
    )  # fmt: skip
    return cands, valid
