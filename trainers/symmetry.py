"""Symmetries of the abstract 2 v 2 task, for replaying episodes in an equivalent form.

Three relabellings leave the cooperative task unchanged, so a stored episode stays a
valid episode after any of them:

* ``enemies`` swaps the two enemy slots. The bots choose by position (nearest robot,
  nearest point), not by index, so the enemy called 0 could as well have been called 1
  (up to ties); actions ``4j + k`` become ``4(1 − j) + k``.
* ``field`` turns the whole scene half a turn about the field's centre. The layout is
  centrally symmetric (``docs/reference.md``, "Arena"; the obstacles to within 2 cm, the spawn
  ranges to within 12 cm), and so are the physics and the bots: every position ``(x, y)``
  becomes ``(−x, −y)`` in the normalised frame and every yaw gains π. The ``relative``
  features are built from differences of positions and of angles, so they do not change at
  all.
* ``allies`` swaps the two learning agents. Observations are egocentric (self first), so
  each agent keeps its own observation; only their order, and the blue rows of the global
  state, change.

Replaying each sampled episode under a random element of the group they generate shows
the network every scene in all its equivalent forms (``augment`` in the trainer's config),
the way image models see flipped images: the Q-values of a relabelled scene must be the
relabelled Q-values, and the learner no longer has to discover that from data.

The transforms assume the layouts the trainers build on: the full 37-value abstract 2 v 2
observation (``docs/options.md``), its ``relative`` extension
(:mod:`neuronsmae.trainers.features`), the 21-value global state (per robot x, y, yaw, HP,
bullets, blue first, then the time) and 8 actions. :func:`task_group` refuses any other.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from neuronsmae.trainers.buffer import Batch
from neuronsmae.trainers.features import LAYOUT_37, RELATIVE_PER_ENEMY, feature_dim

N_AGENTS, N_ENEMY, K = 2, 2, 4
N_ACTIONS = N_ENEMY * K
STATE_DIM = 5 * (N_AGENTS + N_ENEMY) + 1
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

    def then(self, other: Symmetry) -> Symmetry:
        return Symmetry(
            f"{self.name}+{other.name}",
            self.obs.then(other.obs),
            self.state.then(other.state),
            other.actions[self.actions],
            self.agents[other.agents],
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


def _enemies(obs_dim: int) -> Symmetry:
    pairs = [(6, 9, 3), (12, 20, 2 * K), (31, 32, 1), (35, 36, 1)]
    if obs_dim > LAYOUT_37:
        pairs.append((LAYOUT_37, LAYOUT_37 + RELATIVE_PER_ENEMY, RELATIVE_PER_ENEMY))
    state = _swap(STATE_DIM, [(5 * N_AGENTS, 5 * (N_AGENTS + 1), 5)])
    return Symmetry(
        "enemies",
        replace(ColumnMap.identity(obs_dim), index=_swap(obs_dim, pairs)),
        replace(ColumnMap.identity(STATE_DIM), index=state),
        (torch.arange(N_ACTIONS) + K) % N_ACTIONS,
        torch.arange(N_AGENTS),
    )


def _field(obs_dim: int) -> Symmetry:
    def half_turn(width: int, xy: Sequence[int], yaw: Sequence[int]) -> ColumnMap:
        sign, turn = torch.ones(width), torch.zeros(width, dtype=torch.bool)
        sign[list(xy)] = -1.0
        turn[list(yaw)] = True
        return ColumnMap(torch.arange(width), sign, turn)

    robots = N_AGENTS + N_ENEMY
    obs_xy = [3 * r + c for r in range(robots) for c in (0, 1)] + list(range(12, 12 + 4 * K))
    obs = half_turn(obs_dim, obs_xy, [3 * r + 2 for r in range(robots)])
    state_xy = [5 * r + c for r in range(robots) for c in (0, 1)]
    state = half_turn(STATE_DIM, state_xy, [5 * r + 2 for r in range(robots)])
    return Symmetry("field", obs, state, torch.arange(N_ACTIONS), torch.arange(N_AGENTS))


def _allies(obs_dim: int) -> Symmetry:
    state = _swap(STATE_DIM, [(0, 5, 5)])
    return Symmetry(
        "allies",
        ColumnMap.identity(obs_dim),
        replace(ColumnMap.identity(STATE_DIM), index=state),
        torch.arange(N_ACTIONS),
        torch.tensor([1, 0]),
    )


_BUILDERS = {"enemies": _enemies, "field": _field, "allies": _allies}


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


def task_group(
    generators: Sequence[str],
    features: str,
    obs_dim: int,
    state_dim: int,
    n_actions: int,
    n_agents: int,
) -> list[Symmetry]:
    """Every element of the group the named generators span, identity first.

    ``obs_dim`` is the width *after* the feature set. No generators give the identity
    alone, for any task; otherwise raises :class:`UnknownSymmetryError` if the task is not
    the abstract 2 v 2 whose layouts the transforms know.
    """
    base = Symmetry(
        "identity",
        ColumnMap.identity(obs_dim),
        ColumnMap.identity(state_dim),
        torch.arange(n_actions),
        torch.arange(n_agents),
    )
    if not generators:
        return [base]
    expected = feature_dim(features, LAYOUT_37)
    if (obs_dim, state_dim, n_actions, n_agents) != (expected, STATE_DIM, N_ACTIONS, N_AGENTS):
        raise UnknownSymmetryError(
            f"augment knows the abstract 2 v 2 layouts only (obs {expected} with features "
            f"{features!r}, state {STATE_DIM}, {N_ACTIONS} actions, {N_AGENTS} agents); got obs "
            f"{obs_dim}, state {state_dim}, {n_actions} actions, {n_agents} agents. "
            "Use augment='none'"
        )
    group = [base]
    for chosen in itertools.product((False, True), repeat=len(generators)):
        if not any(chosen):
            continue
        element = base
        for name, use in zip(generators, chosen, strict=True):
            if use:
                element = element.then(_BUILDERS[name](obs_dim))
        group.append(replace(element, name=element.name.removeprefix("identity+")))
    return group


_EPISODE_FIELDS = ("obs", "state", "avail", "alive", "actions", "last_actions")
"""The batch fields a symmetry changes (rewards, terminations and padding it does not)."""


def transform(batch: Batch, g: Symmetry) -> Batch:
    """``batch`` as it reads after the symmetry ``g`` (every episode alike)."""
    agents, relabel = g.agents, g.actions
    inverse = torch.argsort(relabel)  # avail'[..., relabel[a]] = avail[..., a]
    return replace(
        batch,
        obs=g.obs.apply(batch.obs[:, :, agents]),
        state=g.state.apply(batch.state),
        avail=batch.avail[:, :, agents][..., inverse],
        alive=batch.alive[:, :, agents],
        actions=relabel[batch.actions[:, :, agents]],
        last_actions=torch.where(
            batch.last_actions >= 0, relabel[batch.last_actions.clamp(min=0)], -1
        )[:, :, agents],
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
