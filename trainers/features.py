"""Optional input features computed from an agent's own observation (and the fixed map).

``raw`` feeds the observation as the environment gives it (the paper's setup). ``relative``
appends geometry that the released 37-value abstract 2 v 2 layout implies but a small
network needs thousands of episodes to discover from normalised absolute coordinates:
distances from the agent and its ally to each enemy and each candidate point, the bearing of
each enemy relative to the agent's heading (is it inside the ±0.52 rad firing cone?), and
for each candidate point the direction it lies in as seen from its enemy, relative to that
enemy's heading (which armour plate faces it: rear plates take 3× damage). Everything is a
fixed function of the observation, so the policy stays decentralised and observation-based;
it only spares the learner from re-deriving trigonometry, which is what lets it learn within
a laptop's half hour (see ``bench/bench_learning.py``).

Layout read (``docs/options.md``; every value in [-1, 1]): poses (x, y, yaw) of self, ally,
enemy 0, enemy 1 at [0:12]; 4 candidate points (x, y) per enemy at [12:28]; time [28]; HP
[29:33]; bullets [33:37].

``exposure`` adds, for every candidate point, what standing there offers the *other* enemy
(the one the action does not target): how far it is (the hit factor falls from 1.0 below
3 m to 0.5 and 0.2), which of my plates it would see once my chassis has turned toward my
target (side and rear plates take 2× and 3× damage), and whether the point lies in that
enemy's firing cone as it now faces. ``relative`` describes a point only against its own
enemy, so a point that is ideal against one robot but hands the other a rear plate looked
as good as any; games against the easy bot are lost as close races on HP at the time limit
(``python -m bench.outcomes``), which is where those plates count. Measured against the
easy bot it does not lift the 30-minute plateau (0.865 and 0.81 on two seeds against 0.845,
0.855 and 0.815 for ``relative``; docs/results.md, runs K, L and D, J, N), so it is not the default.

``sight`` adds what ``exposure`` leaves out: whether a tall wall stands between each robot
and each enemy, and between each candidate point and the other enemy (a hidden point makes
a duel of a crossfire). That needs the arena's walls besides the observation; they are
fixed knowledge of the task, read from the server's field constants (a data module) so the
map is described once. It tested at 0.86 against the easy bot (run X), no better either.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from neuronsmae.server.sim.field import CENTER, obstacle_array

HALF_X, HALF_Y = 4.04, 2.24
"""Half the field's interior size (m): the observation's position scale."""
SCALE = 8.0
"""Distances are divided by this (m), about the field's diagonal."""
LAYOUT_37 = 37
"""Length of the released abstract 2 v 2 observation, the layout ``relative`` understands."""
N_ENEMY, K = 2, 4


class UnknownFeaturesError(ValueError):
    """An unknown feature set, or one that does not fit the observation's layout."""


def _xy(obs: np.ndarray, i: int) -> np.ndarray:
    """Metres from the normalised (x, y) at columns ``i, i+1``: ``[..., 2]``."""
    return np.stack([obs[..., i] * HALF_X + HALF_X, obs[..., i + 1] * HALF_Y + HALF_Y], -1)


def _angle_feats(angle: np.ndarray) -> list[np.ndarray]:
    return [np.cos(angle), np.sin(angle)]


def relative(obs: np.ndarray) -> np.ndarray:
    """``obs [..., 37]`` → ``[..., 37 + 44]``: the observation, then the geometry above."""
    if obs.shape[-1] != LAYOUT_37:
        raise UnknownFeaturesError(
            f"'relative' features need the 37-value abstract 2 v 2 observation, got "
            f"{obs.shape[-1]} values; use features='raw'"
        )
    me, ally = _xy(obs, 0), _xy(obs, 3)
    my_yaw = obs[..., 2] * np.pi
    out = [obs]
    for j in range(N_ENEMY):
        enemy, enemy_yaw = _xy(obs, 6 + 3 * j), obs[..., 8 + 3 * j] * np.pi
        to_enemy = enemy - me
        out += [
            np.linalg.norm(to_enemy, axis=-1) / SCALE,
            np.linalg.norm(enemy - ally, axis=-1) / SCALE,
        ]
        out += _angle_feats(np.arctan2(to_enemy[..., 1], to_enemy[..., 0]) - my_yaw)
        from_enemy = me - enemy  # where I stand as seen from the enemy's heading
        out += _angle_feats(np.arctan2(from_enemy[..., 1], from_enemy[..., 0]) - enemy_yaw)
        for k in range(K):
            point = _xy(obs, 12 + 2 * (K * j + k))
            out += [
                np.linalg.norm(point - me, axis=-1) / SCALE,
                np.linalg.norm(point - ally, axis=-1) / SCALE,
            ]
            side = point - enemy
            out += [np.cos(np.arctan2(side[..., 1], side[..., 0]) - enemy_yaw)]
            out += [np.sin(np.arctan2(side[..., 1], side[..., 0]) - enemy_yaw)]
    cols = [c if c.ndim == obs.ndim else c[..., None] for c in out]
    return np.concatenate(cols, axis=-1).astype(np.float32)


EXPOSURE_PER_POINT = 5
"""``exposure`` columns per candidate point: distance to the other enemy, the other enemy's
bearing from the point relative to the heading toward the target (cos, sin), and the point's
bearing from the other enemy relative to its heading (cos, sin)."""
RELATIVE_PER_ENEMY = 6 + 4 * K
"""``relative`` columns per enemy: its 6, then 4 for each of its candidate points."""
RELATIVE_DIM = LAYOUT_37 + N_ENEMY * RELATIVE_PER_ENEMY
"""Width of the ``relative`` features (81)."""


def exposure(obs: np.ndarray) -> np.ndarray:
    """``obs [..., 37]`` → ``[..., 81 + 40]``: ``relative``, then 5 columns per point.

    Point ``k`` of enemy ``j`` (action ``4j + k``) fills columns ``81 + 5(4j + k)`` onward.
    """
    out = [relative(obs)]
    for j in range(N_ENEMY):
        target = _xy(obs, 6 + 3 * j)
        other, other_yaw = _xy(obs, 6 + 3 * (1 - j)), obs[..., 8 + 3 * (1 - j)] * np.pi
        for k in range(K):
            point = _xy(obs, 12 + 2 * (K * j + k))
            to_target, to_other = target - point, other - point
            heading = np.arctan2(to_target[..., 1], to_target[..., 0])
            out += [np.linalg.norm(to_other, axis=-1)[..., None] / SCALE]
            seen = np.arctan2(to_other[..., 1], to_other[..., 0]) - heading
            cone = np.arctan2(-to_other[..., 1], -to_other[..., 0]) - other_yaw
            out += [np.stack([*_angle_feats(seen), *_angle_feats(cone)], -1)]
    return np.concatenate(out, axis=-1).astype(np.float32)


EXPOSURE_DIM = RELATIVE_DIM + N_ENEMY * K * EXPOSURE_PER_POINT
"""Width of the ``exposure`` features (121)."""
SIGHT_PER_ENEMY = 2 + K
"""``sight`` columns per enemy: can I see it, can my ally, and, for each of its candidate
points, could the *other* enemy see a robot standing there."""


def _sight_boxes() -> np.ndarray:
    """The tall obstacles as ``(m, 4)`` axis-aligned boxes ``x_lo, y_lo, x_hi, y_hi`` (m).

    The released layout is centrally symmetric to within 2 cm; each box here is averaged
    with its partner's half-turned image so that the map is symmetric exactly, which keeps
    the features unchanged under the ``field`` symmetry of :mod:`neuronsmae.trainers.symmetry`.
    The tall ones are all axis-aligned; the low ones block neither shots nor sight.
    """
    boxes = obstacle_array(tall_only=True)
    assert np.all(boxes[:, 4] == 0.0), "tall obstacles are axis-aligned"
    centre = np.asarray(CENTER)
    xy, half = boxes[:, :2], boxes[:, 2:4]
    mirrored = 2.0 * centre - xy
    partner = np.argmin(np.linalg.norm(xy[:, None] - mirrored[None], axis=-1), axis=1)
    xy = (xy + mirrored[partner]) / 2.0
    half = (half + half[partner]) / 2.0
    return np.concatenate([xy - half, xy + half], axis=1)


SIGHT_BOXES = _sight_boxes()
"""The map ``sight`` tests lines against (see :func:`_sight_boxes`)."""


def clear_sight(p0: np.ndarray, p1: np.ndarray, boxes: np.ndarray = SIGHT_BOXES) -> np.ndarray:
    """Whether the segments ``p0 → p1`` (``[..., 2]`` metres) miss every box: ``[...]`` bool.

    A vectorised slab test. Robots do not occlude here (they move; the obstacles are the
    arena's fixed knowledge), so this is the sight the layout allows, not the referee's.
    """
    d = (p1 - p0)[..., None, :]  # [..., 1, 2]
    start = p0[..., None, :]
    lo, hi = boxes[:, :2], boxes[:, 2:]  # [m, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - start) / d, (hi - start) / d
    inside = (start >= lo) & (start <= hi)
    flat = d == 0.0  # parallel to a slab: inside it for every t, or for none
    near = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    far = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    enter = np.maximum(near.max(-1), 0.0)
    leave = np.minimum(far.min(-1), 1.0)
    return ~(enter <= leave).any(-1)


def sight(obs: np.ndarray) -> np.ndarray:
    """``obs [..., 37]`` → ``[..., 121 + 12]``: ``exposure``, then what the walls hide.

    Per enemy ``j`` (columns ``121 + 6j`` onward, 1 = clear, 0 = blocked by a tall
    obstacle): whether I see it, whether my ally does, and for each of its 4 candidate
    points whether the other enemy sees that point. ``exposure`` tells how a point faces
    the other enemy but not whether a wall stands between them; a point hidden from it is
    a duel instead of a crossfire, which is how close races on HP are lost.
    """
    me, ally = _xy(obs, 0), _xy(obs, 3)
    starts, ends = [], []  # per enemy: me, ally, then its 4 points; all tested in one call
    for j in range(N_ENEMY):
        enemy, other = _xy(obs, 6 + 3 * j), _xy(obs, 6 + 3 * (1 - j))
        starts += [me, ally, *(_xy(obs, 12 + 2 * (K * j + k)) for k in range(K))]
        ends += [enemy, enemy, *([other] * K)]
    clear = clear_sight(np.stack(starts, -2), np.stack(ends, -2))  # [..., 2 · (2 + K)]
    return np.concatenate([exposure(obs), clear.astype(np.float32)], axis=-1)


def action_feature_index(features: str, n_actions: int) -> np.ndarray:
    """Columns of the features that describe each abstract action: ``[8, 17]`` or ``[8, 22]``.

    Action ``a`` drives to point ``a % 4`` of enemy ``a // 4``; its row lists that point's
    (x, y), the enemy's pose, HP and bullets, the enemy's 6 relative features and the
    point's 4, then with ``exposure`` the point's 5 exposure columns. The ``points`` Q head
    scores every action from its row.
    """
    if features not in POINT_FEATURES or n_actions != N_ENEMY * K:
        raise UnknownFeaturesError(
            f"the 'points' head needs features in {POINT_FEATURES} and {N_ENEMY * K} abstract "
            f"actions, got features={features!r}, n_actions={n_actions}"
        )
    rows = []
    for a in range(n_actions):
        j, k = divmod(a, K)
        base = LAYOUT_37 + RELATIVE_PER_ENEMY * j
        rows.append(
            [
                12 + 2 * (K * j + k),
                13 + 2 * (K * j + k),
                6 + 3 * j,
                7 + 3 * j,
                8 + 3 * j,
                31 + j,
                35 + j,
                *range(base, base + 6),
                *range(base + 6 + 4 * k, base + 10 + 4 * k),
            ]
        )
        if features in ("exposure", "sight"):
            start = RELATIVE_DIM + EXPOSURE_PER_POINT * a
            rows[-1] += range(start, start + EXPOSURE_PER_POINT)
        if features == "sight":
            start = EXPOSURE_DIM + SIGHT_PER_ENEMY * j
            rows[-1] += [start, start + 1, start + 2 + k]
    return np.asarray(rows, np.int64)


def raw(obs: np.ndarray) -> np.ndarray:
    """The observation unchanged (as float32)."""
    return np.asarray(obs, np.float32)


FEATURES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "raw": raw,
    "relative": relative,
    "exposure": exposure,
    "sight": sight,
}
"""Feature sets by name."""
POINT_FEATURES = ("relative", "exposure", "sight")
"""Feature sets that describe each abstract action, as the ``points`` head needs."""


def get_features(name: str) -> Callable[[np.ndarray], np.ndarray]:
    """The feature function called ``name``; raise listing the valid names."""
    try:
        return FEATURES[name]
    except KeyError:
        raise UnknownFeaturesError(
            f"unknown features {name!r}; valid: {', '.join(sorted(FEATURES))}"
        ) from None


def feature_dim(name: str, obs_dim: int) -> int:
    """Input width after the feature set ``name`` for observations of ``obs_dim`` values."""
    return int(get_features(name)(np.zeros((1, obs_dim), np.float32)).shape[-1])
