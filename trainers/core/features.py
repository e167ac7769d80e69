"""Optional input features computed from an agent's own observation.

``raw`` feeds the observation as the environment gives it (the paper's setup). ``relative``
appends geometry that the observation implies but a small network needs thousands of
episodes to discover from normalised absolute coordinates: distances from the agent and
each team-mate to each enemy and each candidate point, the bearing of each enemy relative
to the agent's heading (is it inside the ±0.52 rad firing cone?), where the agent stands as
seen from each enemy's heading, and for each candidate point the direction it lies in as
seen from its enemy, relative to that enemy's heading (which armour plate faces it: rear
plates take 3× damage). Everything is a fixed function of the observation, so the policy
stays decentralised and observation-based; it only spares the learner from re-deriving
trigonometry, which is what lets it learn within a laptop's half hour (measured with
``bench/bench_learning.py``, against ``--set features=raw --set head=flat``).

Columns are read from the observation's layout (:class:`~neuronsmae.protocol.EnvInfo`), so
``relative`` fits any team sizes and ``k`` as long as the observation holds the poses and
the candidate points; it refuses other layouts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from neuronsmae.protocol.env_info import FIELD_HALF, EnvInfo

SCALE = 8.0
"""Distances are divided by this (m), about the field's diagonal."""
FEATURES = ("raw", "relative")
"""Feature sets by name."""
POINT_FEATURES = ("relative",)
"""Feature sets that describe each abstract action, as the ``points`` head needs."""
HEADS = ("flat", "points")
"""The agent network's Q heads by name (``AgentSpec.head``): one linear output per action,
or that plus a per-action scorer of the ``POINT_FEATURES``."""

Featurizer = Callable[[np.ndarray], np.ndarray]
"""``obs [..., obs_shape]`` → ``[..., width]`` float32."""


class UnknownFeaturesError(ValueError):
    """An unknown feature set, or one that does not fit the observation's layout."""


def raw(obs: np.ndarray) -> np.ndarray:
    """The observation unchanged (as float32)."""
    return np.asarray(obs, np.float32)


def _angle(angle: np.ndarray) -> np.ndarray:
    """``(cos, sin)`` of ``angle``, stacked first: ``[2, ...]``."""
    return np.stack([np.cos(angle), np.sin(angle)])


@dataclass(frozen=True)
class Relative:
    """The ``relative`` features of one observation layout; call it on observations.

    Output columns: the observation, then per enemy ``j`` a block of ``per_enemy`` columns
    (:meth:`enemy_block`): its distance from me and from each team-mate, its bearing from my
    heading (cos, sin), my bearing from its heading (cos, sin), then per candidate point
    ``q`` its distance from me and from each team-mate and its bearing from the enemy's
    heading (cos, sin) (:meth:`point_columns`).
    """

    info: EnvInfo
    """The environment whose observations this describes."""

    def __post_init__(self) -> None:
        layout = self.info.obs
        if not layout.vector or layout.k == 0:
            raise UnknownFeaturesError(
                "'relative' features need the poses and candidate points in the observation "
                f"(vector_obs and candidate_obs), got {layout}; use features='raw'"
            )

    @property
    def per_point(self) -> int:
        """Columns per candidate point."""
        return 2 + self.info.obs.team_size

    @property
    def per_enemy(self) -> int:
        """Columns per enemy, its points included."""
        return 4 + self.info.obs.team_size + self.info.obs.k * self.per_point

    @property
    def width(self) -> int:
        """Columns of the output."""
        return self.info.obs_shape + self.info.n_enemies * self.per_enemy

    def enemy_block(self, j: int) -> slice:
        """Output columns describing enemy ``j`` and its points."""
        start = self.info.obs_shape + self.per_enemy * j
        return slice(start, start + self.per_enemy)

    def enemy_columns(self, j: int) -> range:
        """Output columns describing enemy ``j`` itself (not its points)."""
        start = self.enemy_block(j).start
        return range(start, start + 4 + self.info.obs.team_size)

    def point_columns(self, j: int, q: int) -> range:
        """Output columns describing candidate point ``q`` of enemy ``j``."""
        start = self.enemy_columns(j).stop + self.per_point * q
        return range(start, start + self.per_point)

    @cached_property
    def _columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Observation columns of the team's (x, y) ``[T, 2]``, the enemies' (x, y, yaw)
        ``[E, 3]`` and their candidate points' (x, y) ``[E, k, 2]``."""
        layout = self.info.obs
        team = [layout.pose(r)[:2] for r in range(layout.team_size)]
        enemies = [layout.pose(layout.enemy(j)) for j in range(layout.n_enemies)]
        points = [[layout.point(j, q) for q in range(layout.k)] for j in range(layout.n_enemies)]
        return np.array(team), np.array(enemies), np.array(points).reshape(len(enemies), -1, 2)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """``obs [..., obs_shape]`` → ``[..., width]``, every enemy and point at once."""
        layout = self.info.obs
        if obs.shape[-1] != layout.size:
            raise UnknownFeaturesError(
                f"'relative' features expect {layout.size} values, got {obs.shape[-1]}"
            )
        team_cols, enemy_cols, point_cols = self._columns
        team = _xy(obs, team_cols)  # [..., T, 2]
        me, my_yaw = team[..., :1, :], obs[..., None, layout.pose(0)[2]] * np.pi  # [..., 1(, 2)]
        enemy = _xy(obs, enemy_cols[:, :2])  # [..., E, 2]
        enemy_yaw = obs[..., enemy_cols[:, 2]] * np.pi  # [..., E]
        points = _xy(obs, point_cols)  # [..., E, k, 2]
        to_enemy, from_enemy = enemy - me, me - enemy
        side = points - enemy[..., None, :]
        blocks = [
            _distance(enemy[..., None, :], team[..., None, :, :]),  # [..., E, T]
            *_angle(_bearing(to_enemy) - my_yaw)[..., :, None],  # 2 × [..., E, 1]
            *_angle(_bearing(from_enemy) - enemy_yaw)[..., :, None],
        ]
        per_point = [
            _distance(points[..., None, :], team[..., None, None, :, :]),  # [..., E, k, T]
            *_angle(_bearing(side) - enemy_yaw[..., None])[..., None],  # 2 × [..., E, k, 1]
        ]
        shape = (*obs.shape[:-1], layout.n_enemies, -1)
        blocks.append(np.concatenate(per_point, axis=-1).reshape(shape))
        enemies = np.concatenate(blocks, axis=-1).reshape(*obs.shape[:-1], -1)
        return np.concatenate([obs, enemies], axis=-1).astype(np.float32)


def _xy(obs: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Metres from the normalised ``(x, y)`` at columns ``cols [..., 2]``: the observation's
    leading axes, then ``cols``'s."""
    hx, hy = FIELD_HALF
    return np.stack([obs[..., cols[..., 0]] * hx + hx, obs[..., cols[..., 1]] * hy + hy], -1)


def _distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance over the last axis (of size 2), divided by :data:`SCALE`."""
    return np.linalg.norm(a - b, axis=-1) / SCALE


def _bearing(v: np.ndarray) -> np.ndarray:
    """The direction of ``v [..., 2]``, in radians."""
    return np.arctan2(v[..., 1], v[..., 0])


def get_features(name: str, info: EnvInfo) -> Featurizer:
    """The feature function ``name`` for observations of ``info``; raise listing the valid
    names, or if the layout does not suit it."""
    if name not in FEATURES:
        raise UnknownFeaturesError(f"unknown features {name!r}; valid: {', '.join(FEATURES)}")
    return raw if name == "raw" else Relative(info)


def feature_dim(name: str, info: EnvInfo) -> int:
    """Input width after the feature set ``name`` for observations of ``info``."""
    features = get_features(name, info)
    return features.width if isinstance(features, Relative) else info.obs_shape


def action_feature_index(features: str, info: EnvInfo) -> np.ndarray:
    """Columns of the features that describe each abstract action: ``[n_actions, F]``.

    Action ``a`` drives to point ``q`` of enemy ``j`` (``info.split(a)``); its row lists that
    point's (x, y), the enemy's pose, HP and bullets, the enemy's relative columns and the
    point's. The ``points`` Q head scores every action from its row (17 columns for 2 v 2).
    """
    if features not in POINT_FEATURES or info.action_space != "abstract":
        raise UnknownFeaturesError(
            f"the 'points' head needs features in {POINT_FEATURES} and abstract actions, got "
            f"features={features!r}, action_space={info.action_space!r}"
        )
    relative, layout = Relative(info), info.obs
    rows = []
    for a in range(info.n_actions):
        j, q = info.split(a)
        enemy = layout.enemy(j)
        rows.append(
            [
                *layout.point(j, q),
                *layout.pose(enemy),
                layout.hp_of(enemy),
                layout.bullets_of(enemy),
                *relative.enemy_columns(j),
                *relative.point_columns(j, q),
            ]
        )
    return np.asarray(rows, np.int64)
