"""Team policies from other packages: the ``neuronsmae.policies`` entry-point group.

A tool that pits policies against each other (``neuronsmae-match``, ``neuronsmae-league``)
takes each side as text: a bot level, or anything an installed *loader* recognises, such
as a checkpoint path. A loader is registered in a package's metadata::

    [project.entry-points."neuronsmae.policies"]
    qlearner = "neuronsmae.trainers.play.policies:load"

and called with the text; it returns a :class:`TeamPolicy`, or None when the text is not
its kind (so several loaders coexist; the first that takes it wins, in name order). The
trainers register one for their checkpoints. A team policy drives one team in each of
``K`` arenas and is batched: one call chooses the team's actions in every arena it plays.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from importlib.metadata import entry_points
from typing import Any, Protocol

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError

GROUP = "neuronsmae.policies"
"""The entry-point group of policy loaders."""
LAYOUT_KEYS = (
    "action_space", "n_actions", "obs_shape", "team_size", "n_enemies", "k", "candidate_obs",
    "vector_obs", "lidar_beams",
)  # fmt: skip
"""The ``get_env_info()`` keys a policy's team and the team it drives must share."""


class TeamPolicy(Protocol):
    """One team's controller over a vector of arenas."""

    options: Mapping[str, Any]
    """Arena options the policy was trained with (team sizes, action space, observability,
    ...; never the mode, which the tool picks)."""
    env_info: Mapping[str, Any] | None
    """The ``get_env_info()`` of the team it was built for (None: not recorded); checked
    against the team it drives with :func:`layout_differences`."""

    def start(self, num_envs: int, n_agents: int) -> None:
        """Prepare to drive ``n_agents`` robots in each of ``num_envs`` arenas."""

    def reset(self, arenas: Sequence[int]) -> None:
        """Episodes start in ``arenas``: forget their recurrent state."""

    def act(self, obs: np.ndarray, avail: np.ndarray, arenas: Sequence[int]) -> np.ndarray:
        """Actions ``[m, n_agents]`` for ``arenas`` from their observations
        ``[m, n_agents, obs_dim]`` and masks ``[m, n_agents, n_actions]`` (with continuous
        actions ``[m, n_agents, 4]``: each agent's ``(vx, vy, omega, target)``)."""


Loader = Callable[[str], TeamPolicy | None]
"""``loader(text)``: a policy, or None when ``text`` is not its kind."""


def loaders() -> list[tuple[str, Loader]]:
    """The installed loaders by entry-point name, in name order."""
    found = sorted(entry_points(group=GROUP), key=lambda ep: ep.name)
    return [(ep.name, ep.load()) for ep in found]


def load_team_policy(text: str | os.PathLike[str], what: str, bots: Sequence[str]) -> TeamPolicy:
    """The policy ``text`` names (a path is given to the loaders as its text), from the
    first installed loader that takes it; else :class:`InvalidOptionError` naming ``what``
    (e.g. ``--red``), the bot levels ``bots`` and the loaders installed. Anything but text
    or a path is refused the same way before a loader sees it."""
    if isinstance(text, os.PathLike):
        text = os.fspath(text)
    if not isinstance(text, str):
        raise InvalidOptionError(
            f"{what} {text!r:.60} ({type(text).__name__}) is neither a bot level "
            f"({', '.join(bots)}) nor a policy's text, such as a checkpoint file or run "
            "directory (a str or path)"
        )
    installed = loaders()
    for _, loader in installed:
        policy = loader(text)
        if policy is not None:
            return policy
    names = ", ".join(name for name, _ in installed) or "none installed"
    raise InvalidOptionError(
        f"{what} {text!r} is neither a bot level ({', '.join(bots)}) nor a policy any loader "
        f"of the {GROUP!r} entry points takes (loaders: {names}; the trainers' 'qlearner' "
        "takes a checkpoint file or run directory: pip install 'neuronsmae[train]')"
    )


def layout_differences(built: Mapping[str, Any] | None, side: Mapping[str, Any]) -> list[str]:
    """``"key: built ≠ side"`` for every layout key a policy built for ``built`` does not
    share with the team ``side`` (both ``get_env_info()`` dicts)."""
    if built is None:
        return []
    return [
        f"{key}: {built[key]!r} ≠ {side[key]!r}"
        for key in LAYOUT_KEYS
        if key in built and key in side and built[key] != side[key]
    ]
