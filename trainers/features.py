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
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

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


RELATIVE_PER_ENEMY = 6 + 4 * K
"""``relative`` columns per enemy: its 6, then 4 for each of its candidate points."""
RELATIVE_DIM = LAYOUT_37 + N_ENEMY * RELATIVE_PER_ENEMY
"""Width of the ``relative`` features (81)."""


def action_feature_index(features: str, n_actions: int) -> np.ndarray:
    """Columns of the features that describe each abstract action: ``[8, 17]``.

    Action ``a`` drives to point ``a % 4`` of enemy ``a // 4``; its row lists that point's
    (x, y), the enemy's pose, HP and bullets, the enemy's 6 relative features and the
    point's 4. The ``points`` Q head scores every action from its row.
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
    return np.asarray(rows, np.int64)


def raw(obs: np.ndarray) -> np.ndarray:
    """The observation unchanged (as float32)."""
    return np.asarray(obs, np.float32)


FEATURES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "raw": raw,
    "relative": relative,
}
"""Feature sets by name."""
POINT_FEATURES = ("relative",)
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
