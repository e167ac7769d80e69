"""The task a run trains on: the arena options from the configuration, and what the learner
makes of the environment's ``get_env_info()``.

:class:`ArenaGroup` is the ``arena`` group of the training configuration: action space, team
sizes, observability, LiDAR, reward and spawn as typed keys (``arena.n_blue=3``), any other
arena option through ``arena.options`` (``"k=6;episode_steps=1500"``). The mode is not a
key: the trainer picks it (cooperative against bots; competitive once a policy plays red,
:mod:`neuronsmae.trainers.play.opponents`).

The learner sizes itself from the environment: :func:`blue_view` is the environment's
description from the learning team's side (in competitive mode the arena's agents are blue
then red; the learner controls the blue ones; the training run's ``resolve_learner`` then
turns the ``auto`` learner settings into the ones this task admits). The Q-learners choose
among discrete actions: continuous actions are refused with an error naming the action
spaces that work.
"""

from __future__ import annotations

import ast
import dataclasses
from dataclasses import dataclass
from typing import Any

from neuronsmae.protocol.env_info import ARENA_OPTIONS, EnvInfo
from neuronsmae.trainers.checks import ConfigError, check_choice, check_types

Q_ACTION_SPACES = ("abstract", "discrete")
"""The action spaces the Q-learners (IQL, VDN, QMIX) train on: a finite set per agent."""
OBSERVABILITY = ("full", "partial")
REWARDS = ("dense", "sparse")
SPAWNS = ("random", "corners")
RESERVED = ("mode", "gui", "blue_level", "seed")
"""Arena options the trainer sets itself: ``arena.options`` may not name them."""


def refuse_continuous(action_space: str, where: str) -> None:
    """Raise :class:`ConfigError` unless the Q-learners can act in ``action_space``."""
    if action_space == "continuous":
        raise ConfigError(
            f"{where}='continuous': the Q-learners (iql, vdn, qmix) choose one of a finite set "
            f"of actions and cannot output velocities; valid: {', '.join(Q_ACTION_SPACES)} "
            "(abstract: target × candidate point; discrete: target × stop/forward/back/left/"
            "right). Continuous control needs a policy-gradient learner, which the trainers "
            "do not have"
        )
    check_choice(where, action_space, Q_ACTION_SPACES)


def _literal(text: str) -> Any:
    """``"6"`` → 6, ``"0.5"`` → 0.5, ``"true"`` → True, anything else the text itself."""
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    try:
        return ast.literal_eval(text.strip())
    except (ValueError, SyntaxError):
        return text.strip()


def parse_options(text: str) -> dict[str, Any]:
    """``"k=6;episode_steps=1500"`` → ``{"k": 6, "episode_steps": 1500}``."""
    out: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in text.split(";"))):
        key, sep, value = (x.strip() for x in item.partition("="))
        if not sep or not key:
            raise ConfigError(f"arena.options entry {item!r}: expected key=value")
        out[key] = _literal(value)
    return out


@dataclass(frozen=True)
class ArenaGroup:
    """The arena options the workers open their arenas with (docs/options.md)."""

    action_space: str = "abstract"
    """abstract (target × candidate point, the paper's) or discrete (target × five body
    moves); continuous is refused: the Q-learners pick among a finite set of actions."""
    n_blue: int = 2
    """Robots on the learning (blue) team, 1 to 3."""
    n_red: int = 2
    """Robots on the red team, 1 to 3 (unequal teams train against bots only: a policy on red
    needs the blue layout, competitive mode needs equal teams)."""
    observability: str = "full"
    """full, or partial: an enemy outside the camera's view or sight is padded out."""
    lidar: bool = False
    """Append the 61-beam LiDAR scan to each observation."""
    vector_obs: bool = True
    """Keep the referee vector (poses, candidate points, time, HP, bullets) in observations;
    off with ``lidar`` on trains on the scan alone."""
    reward: str = "dense"
    """dense (damage, kills, win) or sparse (the win or loss only)."""
    spawn: str = "random"
    """random (the released build) or corners (the RMUA birth areas)."""
    options: str = ""
    """Any other arena options, ``key=value`` separated by ``;`` (``k=6;episode_steps=1500``;
    names as in docs/options.md, checked here; the arena checks their values when the
    workers start). The mode,
    ``gui``, ``blue_level`` and the seed are the trainer's."""

    def __post_init__(self) -> None:
        check_types(self)
        refuse_continuous(self.action_space, "arena.action_space")
        check_choice("arena.observability", self.observability, OBSERVABILITY)
        check_choice("arena.reward", self.reward, REWARDS)
        check_choice("arena.spawn", self.spawn, SPAWNS)
        for name in ("n_blue", "n_red"):
            if not 1 <= getattr(self, name) <= 3:
                raise ConfigError(f"arena.{name} must be in [1, 3], got {getattr(self, name)}")
        if not (self.vector_obs or self.lidar):
            raise ConfigError("arena.vector_obs and arena.lidar are both off: enable one")
        extra = parse_options(self.options)
        typed = {f.name for f in dataclasses.fields(self)} - {"options"}
        unknown = sorted(set(extra) - ARENA_OPTIONS)
        if unknown:
            raise ConfigError(
                f"arena.options sets unknown option(s) {unknown}; valid: "
                f"{sorted(ARENA_OPTIONS - typed - set(RESERVED))} (docs/options.md)"
            )
        taken = sorted(set(extra) & (typed | set(RESERVED)))
        if taken:
            raise ConfigError(
                f"arena.options sets {taken}: give the typed keys as arena.<name>; "
                f"{', '.join(RESERVED)} are the trainer's"
            )
        if "action_space" in extra:  # pragma: no cover - refused above as a typed key
            refuse_continuous(extra["action_space"], "arena.options action_space")

    def arena_options(self, mode: str) -> dict[str, Any]:
        """The keyword options of ``Arena``/``VecArena``/``VecRM`` for ``mode``."""
        typed = {
            f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "options"
        }
        return {**typed, **parse_options(self.options), "mode": mode}


def trained_options(config: dict[str, Any]) -> dict[str, Any]:
    """The arena options a run was trained with, without the mode, from its saved config
    (runs from before the ``arena`` group trained the default task)."""
    known = {f.name for f in dataclasses.fields(ArenaGroup)}
    group = ArenaGroup(**{k: v for k, v in config.get("arena", {}).items() if k in known})
    options = group.arena_options("cooperative")
    del options["mode"]
    return options


def blue_view(info: EnvInfo) -> EnvInfo:
    """``info`` as the learning team sees it: its agents are blue's (the first
    ``team_size`` of a competitive arena's agents, all of a cooperative arena's)."""
    if info.continuous:
        refuse_continuous(info.action_space, "action_space")
    n = info.team_size
    return dataclasses.replace(info, n_agents=n, agents=info.agents[:n])
