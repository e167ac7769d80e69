"""Grid A* path planner and path follower behind the abstract action space.

The released planner (``docs/reference.md``, "Planner") is a 4 cm grid, obstacles grown by
0.30 m, other robots blocked ±0.6 m, 4-connected A*. Taken literally it fails whenever a
robot stands inside a grown margin, which happens all the time, so here the margins (walls
included) and the robot squares are *soft*: passable at a high, depth-graded extra cost.
Only cells touching a raw obstacle, and the outside, are impassable; an impassable start or
goal is moved to the nearest passable cell. So a command exists whenever a real path does.

Speed (four robots replan every decision, >400 decisions/s): the static grid and its ALT
landmark tables are built once and shared; per-query bookkeeping is generation-stamped, so
nothing is cleared; robot costs are computed on the fly. Manhattan A* floods the map
whenever it must detour or the goal is in a soft region, so the heuristic is the max of two
consistent bounds: ALT on the static grid, and Manhattan plus the penalty still to pay in
the goal's soft region. Paths are (near-)optimal for the soft costs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np
from scipy import ndimage

from ..sim import field
from .control import follow  # noqa: F401  (re-exported: the follower lived here)

SOFT_BASE = 8.0
"""Extra cost (in cell steps) of entering a grown-margin cell at its outer edge."""
SOFT_SLOPE = 32.0
"""Further extra cost growing linearly to the raw obstacle; steers escapes outward."""
ROBOT_BASE = 8.0
"""Extra cost of entering another robot's square at its edge."""
ROBOT_SLOPE = 56.0
"""Further extra cost growing linearly towards the other robot's centre."""
N_LANDMARKS = 4
"""ALT landmarks; more tighten the heuristic but cost a lookup each per push."""
TIE_BREAK = 1.0 + 1e-3
"""Heuristic weight just above 1: among equal-f nodes prefer the one nearer the goal."""

STATUS_OK = 0
STATUS_START_MOVED = 1
"""The start was in an impassable cell; the path begins by leaving it."""
STATUS_GOAL_MOVED = 2
"""The goal was impassable or outside the field; the path ends at the nearest free cell."""
STATUS_NO_PATH = 4
"""No path exists; :meth:`Planner.plan` returned an empty path (``follow`` then stops)."""

# Columns of the per-planner scratch arrays (cells × fields, generation-stamped, never
# cleared).
_G, _PD = 0, 1  # float: cost-to-come, goal penalty
_GST, _PAR, _CST, _PST = 0, 1, 2, 3  # int32: stamp of g, parent, closed stamp, stamp of pd
_DX, _DY = (1, -1, 0, 0), (0, 0, 1, -1)


@dataclass(frozen=True)
class StaticGrid:
    """Per-cell costs of the fixed arena, flat row-major (index ``iy * nx + ix``)."""

    res: float
    nx: int
    ny: int
    pen: np.ndarray
    """Extra cost of entering each cell: 0 free, >0 grown margin, ``inf`` impassable."""
    snap: np.ndarray
    """Nearest passable cell of each cell (itself when passable)."""
    land: np.ndarray
    """(cells, landmarks) static cost from each landmark, for the ALT heuristic."""


def _obstacle_distance(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Euclidean distance from points to the nearest raw obstacle (negative inside)."""
    d = np.full(x.shape, np.inf)
    for cx, cy, hx, hy, yaw, _h in field.obstacle_array():
        c, s = math.cos(yaw), math.sin(yaw)
        lx = np.abs(c * (x - cx) + s * (y - cy)) - hx
        ly = np.abs(-s * (x - cx) + c * (y - cy)) - hy
        outside = np.hypot(np.maximum(lx, 0.0), np.maximum(ly, 0.0))
        d = np.minimum(d, outside + np.minimum(np.maximum(lx, ly), 0.0))
    return d


@numba.njit(cache=True, inline="always")
def _push(keys, nodes, size, key, node):
    i = size
    while i > 0 and keys[(i - 1) >> 1] > key:
        keys[i], nodes[i] = keys[(i - 1) >> 1], nodes[(i - 1) >> 1]
        i = (i - 1) >> 1
    keys[i], nodes[i] = key, node
    return size + 1


@numba.njit(cache=True, inline="always")
def _pop(keys, nodes, size):
    """Remove the minimum; returns (its key, its node, new size)."""
    key0, node0 = keys[0], nodes[0]
    size -= 1
    key, node, i = keys[size], nodes[size], 0
    while 2 * i + 1 < size:
        c = 2 * i + 1
        if c + 1 < size and keys[c + 1] < keys[c]:
            c += 1
        if keys[c] >= key:
            break
        keys[i], nodes[i] = keys[c], nodes[c]
        i = c
    keys[i], nodes[i] = key, node
    return key0, node0, size


@numba.njit(cache=True)
def _dijkstra(pen, nx, ny, src):
    """Static cost from ``src`` to every cell, paying ``1 + pen`` per cell entered."""
    dist = np.full(nx * ny, np.inf)
    keys, nodes = np.empty(4 * nx * ny), np.empty(4 * nx * ny, np.int64)
    dist[src] = 0.0
    size = _push(keys, nodes, 0, 0.0, src)
    while size > 0:
        d, u, size = _pop(keys, nodes, size)
        if d > dist[u]:
            continue
        for k in range(4):
            vx, vy = u % nx + _DX[k], u // nx + _DY[k]
            v = vy * nx + vx
            if 0 <= vx < nx and 0 <= vy < ny and d + 1.0 + pen[v] < dist[v]:
                dist[v] = d + 1.0 + pen[v]
                size = _push(keys, nodes, size, dist[v], v)
    return dist


def _landmarks(pen: np.ndarray, nx: int, ny: int, k: int) -> np.ndarray:
    """Static cost-to-come from ``k`` free landmarks, spread by farthest-point selection.

    ALT: d(n, t) >= d(L, t) - d(L, n); and since a reversed path costs the same up to
    ``pen[end] - pen[start]``, also d(n, t) >= (d(L, n) - pen[n]) - (d(L, t) - pen[t]).
    Robot squares only add cost, so both bounds stay admissible and consistent.
    """
    free = np.flatnonzero(pen == 0.0)
    nearest = _dijkstra(pen, nx, ny, (ny // 2) * nx + nx // 2)
    cols = []
    for _ in range(k):
        cols.append(_dijkstra(pen, nx, ny, free[np.argmax(nearest[free])]))
        nearest = np.minimum(nearest, cols[-1]) if len(cols) > 1 else cols[-1]
    return np.ascontiguousarray(np.stack(cols, axis=1), dtype=np.float32)


@lru_cache(maxsize=4)
def static_grid(res: float = 0.04, inflate: float = 0.30) -> StaticGrid:
    """Build (once per parameter pair and process, ~0.4 s) the cost grid; planners share it."""
    nx, ny = round(field.FIELD_X / res), round(field.FIELD_Y / res)
    x, y = np.meshgrid((np.arange(nx) + 0.5) * res, (np.arange(ny) + 0.5) * res)
    d_obs = _obstacle_distance(x, y)
    d_wall = np.minimum.reduce([x, field.FIELD_X - x, y, field.FIELD_Y - y])
    # A cell is impassable when any part of it touches a raw obstacle, so a segment that
    # only crosses passable cells can never clip an obstacle.
    hard = (d_obs < res * math.sqrt(0.5)) | (d_wall <= 0.0)
    depth = np.clip((inflate - np.minimum(d_obs, d_wall)) / inflate, 0.0, 1.0)
    pen = np.where(depth > 0.0, SOFT_BASE + SOFT_SLOPE * depth, 0.0)
    pen[hard] = np.inf
    _, (iy, ix) = ndimage.distance_transform_edt(hard, return_indices=True)
    pen = np.ascontiguousarray(pen.ravel())
    snap = (iy * nx + ix).ravel().astype(np.int64)
    return StaticGrid(res, nx, ny, pen, snap, _landmarks(pen, nx, ny, N_LANDMARKS))


@numba.njit(cache=True, inline="always")
def _cost(x, y, pen, rob, rb, nx, ny):
    """Extra cost of entering cell (x, y): static margin plus the worst robot square.

    Infinite outside the grid. Robot squares are evaluated on the fly (``rob`` in cell
    units, half-size ``rb`` cells): for three robots cheaper than stamping ~3000 cells.
    """
    if x < 0 or x >= nx or y < 0 or y >= ny:
        return np.inf
    worst = 0.0
    for r in range(rob.shape[0]):
        cheb = max(abs(x - rob[r, 0]), abs(y - rob[r, 1]))
        if cheb < rb:
            worst = max(worst, ROBOT_BASE + ROBOT_SLOPE * (1.0 - cheb / rb))
    return pen[y * nx + x] + worst


@numba.njit(cache=True)
def _line_clear(x0, y0, x1, y1, limit, pen, rob, rb, nx, ny):
    """Every cell the segment touches (cell units) is passable and costs at most ``limit``.

    Amanatides–Woo traversal; at an exact corner crossing both side cells are checked.
    """
    ix, iy, ex, ey = math.floor(x0), math.floor(y0), math.floor(x1), math.floor(y1)
    dx, dy = x1 - x0, y1 - y0
    sx, sy = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
    tdx = abs(1.0 / dx) if dx != 0.0 else np.inf
    tdy = abs(1.0 / dy) if dy != 0.0 else np.inf
    tmx = ((ix + 1 - x0) if dx > 0 else (x0 - ix)) * tdx if dx != 0.0 else np.inf
    tmy = ((iy + 1 - y0) if dy > 0 else (y0 - iy)) * tdy if dy != 0.0 else np.inf
    for _ in range(abs(ex - ix) + abs(ey - iy) + 3):
        if _cost(ix, iy, pen, rob, rb, nx, ny) > limit:
            return False
        if ix == ex and iy == ey:
            return True
        if abs(tmx - tmy) < 1e-9:  # through a corner: both side cells are touched too
            side_x = _cost(ix + sx, iy, pen, rob, rb, nx, ny)
            if max(side_x, _cost(ix, iy + sy, pen, rob, rb, nx, ny)) > limit:
                return False
            ix, iy, tmx, tmy = ix + sx, iy + sy, tmx + tdx, tmy + tdy
        elif tmx < tmy:
            ix, tmx = ix + sx, tmx + tdx
        else:
            iy, tmy = iy + sy, tmy + tdy
    return True


@numba.njit(cache=True)
def _goal_penalty(t, pen, rob, rb, nx, ny, fw, iw, gen, hk, hn):
    """Least penalty P(n) still to pay from n into goal t, capped at the value of free cells.

    A reversed Dijkstra from t by P, stopped at the first fully free cell, gives P exactly
    for every cell below the cap (marked ``_PST == gen``) and returns the cap; the capped P
    is consistent, and plus Manhattan it bounds the cost-to-go.
    """
    fw[t, _PD], iw[t, _PST] = 0.0, -gen
    size = _push(hk, hn, 0, 0.0, t)
    while size > 0:
        d, u, size = _pop(hk, hn, size)
        if iw[u, _PST] == gen:
            continue
        iw[u, _PST] = gen
        ux, uy = u % nx, u // nx
        cu = _cost(ux, uy, pen, rob, rb, nx, ny)
        if cu == 0.0:
            return d
        for k in range(4):
            vx, vy = ux + _DX[k], uy + _DY[k]
            v = vy * nx + vx
            if not (0 <= vx < nx and 0 <= vy < ny) or pen[v] == np.inf or iw[v, _PST] == gen:
                continue
            if iw[v, _PST] != -gen or d + cu < fw[v, _PD]:
                fw[v, _PD], iw[v, _PST] = d + cu, -gen
                size = _push(hk, hn, size, d + cu, v)
    return np.inf


@numba.njit(cache=True)
def _astar(s, t, pen, land, rob, rb, nx, ny, fw, iw, gen, hk, hn):
    """A* from s to t with lazy deletion; True if t was reached (parents in ``_PAR``)."""
    tx, ty = t % nx, t // nx
    cap = _goal_penalty(t, pen, rob, rb, nx, ny, fw, iw, gen, hk, hn)
    land_t = land[t].copy()
    back_t = land_t - pen[t]
    fw[s, _G], iw[s, _GST], iw[s, _PAR] = 0.0, gen, -1
    size = _push(hk, hn, 0, 0.0, s)
    while size > 0:
        _, u, size = _pop(hk, hn, size)
        if iw[u, _CST] == gen:
            continue
        iw[u, _CST] = gen
        if u == t:
            return True
        ux, uy = u % nx, u // nx
        for k in range(4):
            vx, vy = ux + _DX[k], uy + _DY[k]
            v = vy * nx + vx
            if not (0 <= vx < nx and 0 <= vy < ny) or pen[v] == np.inf or iw[v, _CST] == gen:
                continue
            gv = fw[u, _G] + 1.0 + _cost(vx, vy, pen, rob, rb, nx, ny)
            if iw[v, _GST] == gen and gv >= fw[v, _G]:
                continue
            fw[v, _G], iw[v, _GST], iw[v, _PAR] = gv, gen, u
            h = abs(vx - tx) + abs(vy - ty) + (fw[v, _PD] if iw[v, _PST] == gen else cap)
            for q in range(land.shape[1]):
                lv = land[v, q]
                h = max(h, land_t[q] - lv, lv - pen[v] - back_t[q])
            size = _push(hk, hn, size, gv + TIE_BREAK * h, v)
    return False


@numba.njit(cache=True)
def _shortcut(pts, cost, n, i, pen, rob, rb, nx, ny):
    """Farthest j > i reachable straight from point i without any cell costing more than
    the grid path it replaces (gallop, then bisect; visibility is nearly monotone)."""
    best, hi, step = i + 1, n, 2
    while (hi - best > 1) if hi < n else (best < n - 1):
        j = min(i + step, n - 1) if hi == n else (best + hi) // 2
        ok = _line_clear(pts[i, 0], pts[i, 1], pts[j, 0], pts[j, 1], cost[i : j + 1].max(),
                         pen, rob, rb, nx, ny)  # fmt: skip
        if ok:
            best, step = j, 2 * step
        else:
            hi = j
    return best


@numba.njit(cache=True)
def _plan_kernel(grid, start, goal, others, block, gen, fw, iw, hk, hn, pts, cost, out):
    """Snap ends, A*, shortcut; writes world waypoints into ``out``.

    ``grid`` is (pen, snap, land, nx, res). Returns (number of waypoints, status bits).
    """
    pen, snap, land, nx, res = grid
    ny = pen.shape[0] // nx
    rob, rb = others / res - 0.5, block / res  # robot centres in cell-index units
    status, ends = 0, np.empty(2, np.int64)
    for e in range(2):
        p = start if e == 0 else goal
        ix, iy = math.floor(p[0] / res), math.floor(p[1] / res)
        c = min(max(iy, 0), ny - 1) * nx + min(max(ix, 0), nx - 1)
        if not (0 <= ix < nx and 0 <= iy < ny) or pen[c] == np.inf:
            status |= STATUS_START_MOVED if e == 0 else STATUS_GOAL_MOVED
        ends[e] = snap[c]
    s, t = ends[0], ends[1]
    if not _astar(s, t, pen, land, rob, rb, nx, ny, fw, iw, gen, hk, hn):
        return 0, status | STATUS_NO_PATH
    n, u = 0, t  # grid path into pts (cell units, centres at +0.5), start first
    while u != -1:
        n, u = n + 1, iw[u, _PAR]
    u = t
    for k in range(n - 1, -1, -1):
        ux, uy = u % nx, u // nx
        pts[k, 0], pts[k, 1], cost[k] = ux + 0.5, uy + 0.5, _cost(ux, uy, pen, rob, rb, nx, ny)
        u = iw[u, _PAR]
    if not status & STATUS_START_MOVED:
        pts[0, 0], pts[0, 1] = start[0] / res, start[1] / res
    if not status & STATUS_GOAL_MOVED:
        pts[n - 1, 0], pts[n - 1, 1] = goal[0] / res, goal[1] / res
    m, i = 0, 0
    if status & STATUS_START_MOVED:
        out[0, 0], out[0, 1], m = start[0], start[1], 1
    out[m, 0], out[m, 1], m = pts[0, 0] * res, pts[0, 1] * res, m + 1
    while i < n - 1:
        i = _shortcut(pts, cost, n, i, pen, rob, rb, nx, ny)
        out[m, 0], out[m, 1], m = pts[i, 0] * res, pts[i, 1] * res, m + 1
    if n == 1:  # start and goal in the same cell
        out[m, 0], out[m, 1], m = pts[0, 0] * res, pts[0, 1] * res, m + 1
    return m, status


class Planner:
    """A* on the soft-inflated arena grid; one instance per thread (it owns scratch buffers)."""

    def __init__(
        self, resolution: float = 0.04, inflate: float = 0.30, robot_block: float = 0.6
    ) -> None:
        self.grid = static_grid(float(resolution), float(inflate))
        self.robot_block = float(robot_block)
        gr, n = self.grid, self.grid.nx * self.grid.ny
        self._kgrid = (gr.pen, gr.snap, gr.land, gr.nx, gr.res)
        self._gen = 0
        self._fw = np.zeros((n, 2))
        self._iw = np.zeros((n, 4), np.int32)  # a cell's entries share a cache line
        self._hk, self._hn = np.zeros(4 * n + 4), np.zeros(4 * n + 4, np.int32)
        self._pts, self._cost, self._out = np.zeros((n, 2)), np.zeros(n), np.zeros((n + 2, 2))
        self.last_status = STATUS_OK
        """Status bits of the latest :meth:`plan` (``STATUS_*``)."""
        self.no_path_count = 0
        """How many plans found no path (should stay 0 in this arena)."""

    def plan(
        self, start_xy: np.ndarray, goal_xy: np.ndarray, others_xy: np.ndarray | None = None
    ) -> np.ndarray:
        """World waypoints ``(P, 2)`` from ``start_xy`` to ``goal_xy`` avoiding ``others_xy``.

        The first point is the start itself; the last is the goal, or the nearest passable
        cell centre if the goal is impassable. Only the corners of a line-of-sight-shortcut
        grid path are kept. An empty ``(0, 2)`` array means no path (see ``last_status``).
        """
        others = np.zeros((0, 2)) if others_xy is None else others_xy
        others = np.ascontiguousarray(others, dtype=np.float64).reshape(-1, 2)
        start = np.ascontiguousarray(start_xy, dtype=np.float64)
        goal = np.ascontiguousarray(goal_xy, dtype=np.float64)
        if self._gen >= 2**31 - 2:  # int32 stamps: start over before they wrap
            self._gen = 0
            self._iw[:] = 0
        self._gen += 1
        m, status = _plan_kernel(
            self._kgrid, start, goal, others, self.robot_block, self._gen, self._fw,
            self._iw, self._hk, self._hn, self._pts, self._cost, self._out,
        )  # fmt: skip
        self.last_status = status
        self.no_path_count += bool(status & STATUS_NO_PATH)
        return self._out[:m].copy()
