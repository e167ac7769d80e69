"""Symmetries of the cooperative task, for replaying episodes in an equivalent form.

Three relabellings leave the cooperative task unchanged, so a stored episode stays a
valid episode after any of them:

* ``enemies`` swaps the two enemy slots. The bots choose by position (nearest robot,
  nearest point), not by index, so the enemy called 0 could as well have been called 1
  (up to ties); the action ``(enemy j, choice c)`` becomes ``(enemy 1 − j, choice c)``.
* ``field`` turns the whole scene half a turn about the field's centre. The layout is
  centrally symmetric (``docs/reference.md``, "Arena"; the obstacles to within 2 cm, the
  spawn ranges to within 12 cm), and so are the physics and the bots: every position
  ``(x, y)`` becomes ``(−x, −y)`` in the normalised frame and every yaw gains π. The
  ``relative`` features are built from differences of positions and of angles, so they do
  not change. Each enemy's candidate points are then listed again in the environment's
  order (by angle from +x, which the half turn shifts by π), with the abstract actions that
  name them (:mod:`~neuronsmae.trainers.core.point_order`); so abstract actions need the points
  in the observation.
* ``allies`` swaps the two learning agents. Observations are egocentric (self first), so
  each agent keeps its own observation; only their order, and the blue rows of the global
  state, change.

Replaying each sampled episode under a random element of the group they generate shows
the network every scene in all its equivalent forms (``augment`` in the trainer's config),
the way image models see flipped images: the Q-values of a relabelled scene must be the
relabelled Q-values, and the learner no longer has to discover that from data.

Every column the transforms move is read from the task's layout
(:class:`~neuronsmae.protocol.EnvInfo` and the ``relative`` features' own layout). They need
the cooperative task with the poses in the observation and no LiDAR, abstract or discrete
actions, two enemies for ``enemies`` and two agents for ``allies``; :func:`task_group`
refuses any other task.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from neuronsmae.protocol.env_info import EnvInfo, StateLayout
from neuronsmae.trainers.core.buffer import Batch
from neuronsmae.trainers.core.features import Relative, feature_dim, get_features
from neuronsmae.trainers.core.point_order import PointOrder

GENERATORS = ("enemies", "field", "allies")
"""Names of the symmetries :func:`task_group` can combine."""


class UnknownSymmetryError(ValueError):
    """An unknown symmetry name, or a task whose layouts the symmetries do not know."""


@dataclass(frozen=True)
class ColumnMap:
    """How a symmetry acts on the last axis of a vector: gather, change signs, half-turn yaws.

    ``y[..., c] = sign[c] · x[..., index[c]]``, then the columns in ``turn`` (a yaw divided by
    π) gain 1 and wrap back into [−1, 1).
    """

    index: torch.Tensor
    """``[D]`` int64: the input column each output column comes from."""
    sign: torch.Tensor
    """``[D]`` float32: −1 for positions under a half turn, else 1."""
    turn: torch.Tensor
    """``[D]`` bool: columns holding a normalised yaw that gains half a turn."""

    @classmethod
    def identity(cls, width: int) -> ColumnMap:
        return cls(torch.arange(width), torch.ones(width), torch.zeros(width, dtype=torch.bool))

    def then(self, other: ColumnMap) -> ColumnMap:
        """This map followed by ``other`` (both are needed when generators combine)."""
        index = self.index[other.index]
        sign = self.sign[other.index] * other.sign
        turn = self.turn[other.index] ^ other.turn
        return ColumnMap(index, sign, turn)

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        y = x[..., self.index] * self.sign
        return torch.where(self.turn, torch.remainder(y + 2.0, 2.0) - 1.0, y)


@dataclass(frozen=True)
class Symmetry:
    """One element of the group: its action on observations, state, actions and agents."""

    name: str
    obs: ColumnMap
    state: ColumnMap
    actions: torch.Tensor
    """``[A]`` int64: the new label of each action."""
    agents: torch.Tensor
    """``[n]`` int64: the agent each new agent slot comes from."""
    points: PointOrder | None = None
    """After the maps above, list the candidate points in the environment's order again
    (an element that turns the field, in a task with the points in its observation)."""

    def then(self, other: Symmetry) -> Symmetry:
        return Symmetry(
            f"{self.name}+{other.name}",
            self.obs.then(other.obs),
            self.state.then(other.state),
            other.actions[self.actions],
            self.agents[other.agents],
            self.points or other.points,
        )


def _swap(width: int, pairs: Sequence[tuple[int, int, int]]) -> torch.Tensor:
    """A gather index of ``width`` columns exchanging blocks ``(a, b, length)``."""
    index = torch.arange(width)
    for a, b, length in pairs:
        index[a : a + length], index[b : b + length] = (
            torch.arange(b, b + length),
            torch.arange(a, a + length),
        )
    return index


def _state_swap(state: StateLayout, a: int, b: int) -> ColumnMap:
    """Exchange robots ``a`` and ``b`` of the global state."""
    width = StateLayout.PER_ROBOT
    index = _swap(state.size, [(state.robot(a).start, state.robot(b).start, width)])
    return replace(ColumnMap.identity(state.size), index=index)


def _enemies(info: EnvInfo, relative: Relative | None, width: int) -> Symmetry:
    obs, k = info.obs, info.obs.k
    e0, e1 = obs.enemy(0), obs.enemy(1)
    pairs = [
        (obs.pose(e0)[0], obs.pose(e1)[0], 3),
        (obs.hp_of(e0), obs.hp_of(e1), 1),
        (obs.bullets_of(e0), obs.bullets_of(e1), 1),
    ]
    if k:
        pairs.append((obs.point(0, 0)[0], obs.point(1, 0)[0], 2 * k))
    if relative is not None:
        pairs.append((relative.enemy_block(0).start, relative.enemy_block(1).start,
                      relative.per_enemy))  # fmt: skip
    relabel = [info.action(1 - j, c) for j, c in map(info.split, range(info.n_actions))]
    return Symmetry(
        "enemies",
        replace(ColumnMap.identity(width), index=_swap(width, pairs)),
        _state_swap(info.state, info.team_size, info.team_size + 1),
        torch.tensor(relabel),
        torch.arange(info.n_agents),
    )


def _field(info: EnvInfo, relative: Relative | None, width: int) -> Symmetry:
    # The relative features are built from differences of positions and of angles: only
    # their per-point blocks move, with the points.
    points = PointOrder(info, relative) if info.obs.k else None

    def half_turn(size: int, xy: Sequence[int], yaw: Sequence[int]) -> ColumnMap:
        sign, turn = torch.ones(size), torch.zeros(size, dtype=torch.bool)
        sign[list(xy)] = -1.0
        turn[list(yaw)] = True
        return ColumnMap(torch.arange(size), sign, turn)

    obs = half_turn(width, info.obs.xy_columns(), info.obs.yaw_columns())
    state = half_turn(info.state_shape, info.state.xy_columns(), info.state.yaw_columns())
    actions, agents = torch.arange(info.n_actions), torch.arange(info.n_agents)
    return Symmetry("field", obs, state, actions, agents, points)


def _allies(info: EnvInfo, relative: Relative | None, width: int) -> Symmetry:
    del relative  # each agent keeps its own observation
    return Symmetry(
        "allies",
        ColumnMap.identity(width),
        _state_swap(info.state, 0, 1),
        torch.arange(info.n_actions),
        torch.tensor([1, 0]),
    )


Builder = Callable[[EnvInfo, Relative | None, int], Symmetry]
"""Builds one generator from the task, the relative features (if used) and the input width."""
_BUILDERS: dict[str, Builder] = {"enemies": _enemies, "field": _field, "allies": _allies}


def parse_generators(text: str) -> tuple[str, ...]:
    """``"enemies,field"`` → ``("enemies", "field")``; ``"none"`` or ``""`` → ``()``."""
    names = tuple(p.strip() for p in text.split(",") if p.strip() and p.strip() != "none")
    unknown = [n for n in names if n not in _BUILDERS]
    if unknown or len(set(names)) != len(names):
        raise UnknownSymmetryError(
            f"augment must be 'none' or a comma list of distinct names from "
            f"{', '.join(GENERATORS)}; got {text!r}"
        )
    return names


def task_group(generators: Sequence[str], features: str, info: EnvInfo) -> list[Symmetry]:
    """Every element of the group the named generators span, identity first, acting on
    observations after the feature set ``features``.

    No generators give the identity alone, for any task; otherwise raises
    :class:`UnknownSymmetryError` for a task the transforms do not know (module docstring).
    """
    width = feature_dim(features, info)
    base = Symmetry(
        "identity",
        ColumnMap.identity(width),
        ColumnMap.identity(info.state_shape),
        torch.arange(info.n_actions),
        torch.arange(info.n_agents),
    )
    if not generators:
        return [base]
    _check_task(generators, info)
    featurizer = get_features(features, info)
    relative = featurizer if isinstance(featurizer, Relative) else None
    group = [base]
    for chosen in itertools.product((False, True), repeat=len(generators)):
        if not any(chosen):
            continue
        element = base
        for name, use in zip(generators, chosen, strict=True):
            if use:
                element = element.then(_BUILDERS[name](info, relative, width))
        group.append(replace(element, name=element.name.removeprefix("identity+")))
    return group


def _check_task(generators: Sequence[str], info: EnvInfo) -> None:
    needs = {
        "the cooperative mode": info.mode == "cooperative" and info.n_agents == info.team_size,
        "poses in the observation and no LiDAR": info.obs.vector and not info.obs.lidar_beams,
        "abstract or discrete actions": info.action_space in ("abstract", "discrete"),
        "the candidate points in the observation": "field" not in generators
        or info.action_space != "abstract"
        or info.obs.k > 0,
        "two enemies": "enemies" not in generators or info.n_enemies == 2,
        "two agents": "allies" not in generators or info.n_agents == 2,
    }
    missing = [need for need, met in needs.items() if not met]
    if missing:
        raise UnknownSymmetryError(
            f"augment={','.join(generators)!r} needs {', '.join(missing)}; this task has "
            f"mode={info.mode!r}, {info.n_agents} agents, {info.n_enemies} enemies, "
            f"action_space={info.action_space!r}, vector_obs={info.vector_obs}, "
            f"lidar_beams={info.lidar_beams}. Use augment='none'"
        )


_EPISODE_FIELDS = ("obs", "state", "avail", "alive", "actions", "last_actions")
"""The batch fields a symmetry changes (rewards, terminations and padding it does not)."""


def transform(batch: Batch, g: Symmetry) -> Batch:
    """``batch`` as it reads after the symmetry ``g`` (every episode alike)."""
    agents, relabel = g.agents, g.actions
    inverse = torch.argsort(relabel)  # avail'[..., relabel[a]] = avail[..., a]
    obs = g.obs.apply(batch.obs[:, :, agents])
    avail = batch.avail[:, :, agents][..., inverse]
    actions = relabel[batch.actions[:, :, agents]]
    if g.points is not None:
        obs, avail, actions = g.points.relist(obs, avail, actions)
    return replace(
        batch,
        obs=obs,
        state=g.state.apply(batch.state),
        avail=avail,
        alive=batch.alive[:, :, agents],
        actions=actions,
        last_actions=torch.cat([batch.last_actions[:, :1], actions], dim=1),
    )


def augment(batch: Batch, group: Sequence[Symmetry], rng: np.random.Generator) -> Batch:
    """Each episode of ``batch`` under an element of ``group`` drawn uniformly at random."""
    if len(group) <= 1:
        return batch
    pick = torch.from_numpy(rng.integers(len(group), size=batch.obs.shape[0]))
    fields = {f: getattr(batch, f).clone() for f in _EPISODE_FIELDS}
    for i, g in enumerate(group[1:], start=1):
        rows = pick == i
        if bool(rows.any()):
            part = replace(batch, **{f: getattr(batch, f)[rows] for f in _EPISODE_FIELDS})
            moved = transform(part, g)
            for f in _EPISODE_FIELDS:
                fields[f][rows] = getattr(moved, f)
    return replace(batch, **fields)
