"""Checkpoints: everything a run needs to resume, loadable with ``weights_only=True``.

A checkpoint holds only tensors and plain Python values (config as a dict, counters, RNG
states as tuples and dicts), so ``torch.load(path, weights_only=True)`` reads it: loading a
checkpoint never executes pickled code. It is written to a temporary file and renamed, so a
run killed while saving leaves the previous checkpoint intact. The replay is saved beside
it (:func:`save_replay`, ``replay.npz``: NumPy arrays, read without pickle) when the run's
``eval.save_replay`` is on, each time after the checkpoint, with the checkpoint's episode
count; a resumed run loads it only if that count is the checkpoint's (a run killed between
the two writes refills its replay instead).
"""

from __future__ import annotations

import dataclasses
import os
import random
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.protocol.errors import NeuronsMAEError
from neuronsmae.trainers.core.agent import AGENT_NETWORKS, one_hot_width
from neuronsmae.trainers.core.buffer import ReplayStateError
from neuronsmae.trainers.core.features import FEATURES, HEADS, feature_dim
from neuronsmae.trainers.core.learner import AgentSpec, EnvSpec

CHECKPOINT_NAME = "checkpoint.pt"
"""File name of a run's latest checkpoint inside its run directory."""
REPLAY_NAME = "replay.npz"
"""File name of the replay saved with the latest checkpoint, inside the run directory."""
FORMAT = 2
"""Bumped when the layout changes incompatibly (2: the nested training config, and agent
specs that carry the environment's layout)."""


class CheckpointError(NeuronsMAEError, ValueError):
    """A file given as a checkpoint is not one this version reads: not a torch file, not
    loadable with ``weights_only=True`` (it would run pickled code), or another format."""

    code = "invalid_checkpoint"


class MissingCheckpointError(CheckpointError, FileNotFoundError):
    """No checkpoint where one was expected (a run stopped before its first one, or a
    mistyped path)."""

    code = "missing_checkpoint"


@dataclass
class Counters:
    """Progress of a run, carried across ``--resume``."""

    episodes: int = 0
    """Training episodes stored in the buffer."""
    env_steps: int = 0
    """Decisions taken in those episodes."""
    updates: int = 0
    """Gradient updates."""
    samples: int = 0
    """Decision steps drawn into those updates (a transition replay's batch of 2,000 is
    2,000; an episode batch counts its episodes' steps)."""
    rounds: int = 0
    """Training rounds (iterations in synchronous mode) that learned."""
    learn_seconds: float = 0.0
    """Wall time the learner spent in updates (drawing batches included), over all
    sessions; the rest of ``wall_seconds`` the loop waited for episodes or evaluated."""
    wall_seconds: float = 0.0
    """Training wall time over all sessions of the run."""
    restarts: int = 0
    """Rollout-worker restarts over all sessions."""


def policy_weights(learner_state: dict[str, Any]) -> dict[str, np.ndarray]:
    """The agent's weights in a saved learner state, as NumPy arrays."""
    return {k: v.numpy() for k, v in learner_state["agent"].items()}


def checkpoint_path(path: str | os.PathLike[str]) -> Path:
    """A checkpoint file from either its own path or its run directory
    (:class:`CheckpointError` unless ``path`` is text or a path)."""
    if not isinstance(path, (str, os.PathLike)):
        raise CheckpointError(
            f"a checkpoint is named by a path (str or os.PathLike) to its file or run "
            f"directory, got {type(path).__name__} {path!r:.60}"
        )
    p = Path(path)
    return p / CHECKPOINT_NAME if p.is_dir() else p


def save_checkpoint(
    path: Path,
    *,
    config: dict[str, Any],
    env: EnvSpec,
    spec: AgentSpec,
    learner_state: dict[str, Any],
    counters: Counters,
    np_rng: np.random.Generator,
    selection: dict[str, Any] | None = None,
    starts: dict[str, Any] | None = None,
    opponents: dict[str, Any] | None = None,
    finished: bool = False,
) -> None:
    """Write the checkpoint atomically (temporary file, then rename).

    ``learner_state`` is ``QLearner.state_dict()``: its ``agent`` entry is what acting needs.
    ``selection`` is the evaluation that chose these weights (for ``best.pt``).
    ``starts`` is the start replay's state (``StartReplay.state_dict()``) and ``opponents``
    the opponent pool's (its snapshots), for ``--resume``. ``finished``: written after the
    run's final evaluation (a resumed run that was not finished evaluates again).
    """
    payload = {
        "format": FORMAT,
        "config": config,
        "env": asdict(env),
        "agent_spec": asdict(spec),
        "learner": learner_state,
        "counters": asdict(counters),
        "selection": selection,
        "starts": starts,
        "opponents": opponents,
        "finished": finished,
        "rng": {
            "torch": torch.get_rng_state(),
            "numpy": np_rng.bit_generator.state,
            "python": random.getstate(),
        },
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a checkpoint (file or run directory) with ``weights_only=True``."""
    p = checkpoint_path(path)
    if not p.is_file():
        raise MissingCheckpointError(f"no checkpoint at {p}")
    try:
        payload = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch reports a bad file as any of several error types
        raise CheckpointError(
            f"{p} is not a NeuronsMAE checkpoint: torch.load(weights_only=True) cannot read "
            f"it ({type(exc).__name__}); give a checkpoint.pt, best.pt or snapshot written by "
            "neuronsmae-train, or its run directory"
        ) from exc
    found = payload.get("format") if isinstance(payload, dict) else None
    if type(found) is not int or found != FORMAT:
        raise CheckpointError(f"{p} has checkpoint format {found!r}, not {FORMAT!r}")
    return payload


def save_replay(path: Path, replay: Any, episodes: int) -> None:
    """Write ``replay.state_dict()`` (a replay buffer's) to ``path`` atomically, marked with
    ``episodes``, the training episodes of the checkpoint it goes with."""
    state = replay.state_dict()
    counters = {k: np.int64(state.pop(k)) for k in ("next_slot", "size", "added")}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:  # a file object: np.savez would append .npz to a name
        np.savez(f, _episodes=np.int64(episodes), **{f"_{k}": v for k, v in counters.items()},
                 **state)  # fmt: skip
    os.replace(tmp, path)


def load_replay(path: Path, replay: Any, episodes: int) -> str | None:
    """Load the replay at ``path`` into ``replay`` if it was saved with a checkpoint of
    ``episodes`` episodes and fits it (a resumed run may have a smaller buffer); returns why
    not (None: loaded). A file that is not such a replay is refused with
    :class:`CheckpointError`."""
    if not path.is_file():
        return f"no {path.name}"
    try:
        with np.load(path, allow_pickle=False) as saved:
            stored = {k: saved[k] for k in saved.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # not an archive of arrays
        raise CheckpointError(f"{path} is not a replay neuronsmae-train wrote ({exc})") from None
    at = stored.pop("_episodes", None)
    if at is None or int(at) != episodes:
        return f"{path.name} was saved at {at} episodes, the checkpoint at {episodes}"
    state = {k.removeprefix("_"): v for k, v in stored.items()}
    try:
        replay.load_state_dict(state)
    except ReplayStateError as exc:  # e.g. a smaller learner.buffer_size on resume
        return f"{path.name} does not fit this run's replay ({exc})"
    except KeyError as exc:
        raise CheckpointError(f"{path} lacks the replay array {exc}") from None
    return None


SPEC_FIELDS: dict[str, tuple[type, ...]] = {
    "input_dim": (int,), "n_actions": (int,), "hidden_dim": (int,), "last_action": (bool,),
    "agent_id": (bool,), "features": (str,), "head": (str,), "env_info": (dict, type(None)),
    "network": (str,), "masked": (bool,),
}  # fmt: skip
"""The saved ``agent_spec``'s keys (:class:`AgentSpec`'s fields) and their types."""


def _part(payload: dict[str, Any], key: str, p: Path) -> dict[str, Any]:
    """``payload[key]``, which must be a dict; else :class:`CheckpointError` naming it."""
    value = payload.get(key)
    if not isinstance(value, dict):
        got = "none" if key not in payload else f"{type(value).__name__} {value!r:.60}"
        raise CheckpointError(
            f"{p} is not a complete checkpoint: its {key!r} entry must be a dict, it has {got}"
        )
    return value


def _spec(saved: dict[str, Any], n_agents: Any, p: Path) -> AgentSpec:
    """The saved ``agent_spec`` as an :class:`AgentSpec` whose input width fits its layout."""
    unknown = sorted(set(saved) - set(SPEC_FIELDS), key=str)
    required = [f.name for f in dataclasses.fields(AgentSpec)
                if f.default is dataclasses.MISSING]  # fmt: skip
    missing = [k for k in required if k not in saved]
    if unknown or missing:
        wrong = [f"unknown key(s) {unknown}"] if unknown else []
        wrong += [f"no {missing}"] if missing else []
        raise CheckpointError(
            f"{p}: its agent_spec has {' and '.join(wrong)}; an agent_spec holds "
            f"{list(SPEC_FIELDS)} ({', '.join(required)} required)"
        )
    for key, value in saved.items():
        types = SPEC_FIELDS[key]
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            raise CheckpointError(
                f"{p}: agent_spec {key}={value!r:.60} is a {type(value).__name__}, not "
                f"{' or '.join(t.__name__ for t in types)}"
            )
    spec = AgentSpec(**saved)
    if min(spec.input_dim, spec.n_actions, spec.hidden_dim) < 1:
        raise CheckpointError(f"{p}: agent_spec sizes must be at least 1, got {spec}")
    if spec.features not in FEATURES or spec.head not in HEADS:
        raise CheckpointError(
            f"{p}: agent_spec features={spec.features!r}, head={spec.head!r}; valid: "
            f"features in {list(FEATURES)}, head in {list(HEADS)}"
        )
    if spec.network not in AGENT_NETWORKS:
        raise CheckpointError(
            f"{p}: agent_spec network={spec.network!r}; valid: {list(AGENT_NETWORKS)}"
        )
    extra = one_hot_width(spec, n_agents)
    try:
        spec.featurizer()
        info = None if spec.env_info is None else EnvInfo.from_dict(spec.env_info)
        obs_dim = spec.input_dim - extra if info is None else feature_dim(spec.features, info)
    except (NeuronsMAEError, ValueError, TypeError, KeyError) as exc:
        raise CheckpointError(f"{p}: its agent_spec does not describe a network ({exc})") from exc
    if info is not None and info.n_actions != spec.n_actions:
        raise CheckpointError(
            f"{p}: agent_spec n_actions={spec.n_actions} does not fit its layout, which has "
            f"{info.n_actions} actions"
        )
    if obs_dim < 1 or obs_dim + extra != spec.input_dim:
        raise CheckpointError(
            f"{p}: agent_spec input_dim={spec.input_dim} does not fit its layout: "
            f"{obs_dim} observation columns + {extra} one-hot columns for {n_agents} agents"
        )
    return spec


def _weights(learner: dict[str, Any], spec: AgentSpec, p: Path) -> dict[str, np.ndarray]:
    """The saved agent weights, each with the shape ``spec``'s network has."""
    saved = learner.get("agent")
    if not isinstance(saved, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in saved.items()
    ):
        got = "none" if saved is None else f"{type(saved).__name__} {saved!r:.60}"
        raise CheckpointError(
            f"{p}: its learner state needs the agent's weights ('agent': a dict of name to "
            f"tensor), got {got}"
        )
    try:
        network = spec.build()
    except (NeuronsMAEError, ValueError) as exc:  # a points head its layout cannot have
        raise CheckpointError(f"{p}: its agent_spec does not describe a network ({exc})") from exc
    wanted = {k: list(v.shape) for k, v in network.state_dict().items()}
    given = {k: list(v.shape) for k, v in saved.items()}
    differ = [f"{k} is {given[k]}, not {w}" for k, w in wanted.items()
              if k in given and given[k] != w]  # fmt: skip
    differ += [f"{k} is missing" for k in wanted if k not in given]
    differ += [f"{k} is unexpected" for k in given if k not in wanted]
    if differ:
        raise CheckpointError(
            f"{p}: its agent weights do not fit its agent_spec ({'; '.join(differ[:4])}"
            f"{'; ...' if len(differ) > 4 else ''}): the file mixes parts of different runs"
        )
    return {k: v.numpy() for k, v in saved.items()}


def acting_parts(
    payload: dict[str, Any], path: str | os.PathLike[str]
) -> tuple[AgentSpec, dict[str, np.ndarray], int]:
    """What acting needs from a loaded checkpoint, checked: the agent spec, the agent's
    weights (as NumPy arrays) and the team size it drives. :class:`CheckpointError` naming
    the file and what is wrong when a part is missing, mistyped or does not fit the rest."""
    p = checkpoint_path(path)
    saved = _part(payload, "agent_spec", p)
    learner = _part(payload, "learner", p)
    info = saved.get("env_info")
    n_agents = (info if isinstance(info, dict) else _part(payload, "env", p)).get("n_agents")
    if type(n_agents) is not int or n_agents < 1:
        raise CheckpointError(f"{p}: its team size n_agents={n_agents!r:.60} is not an int ≥ 1")
    spec = _spec(saved, n_agents, p)
    return spec, _weights(learner, spec, p), n_agents


def restore_rng(rng_state: dict[str, Any], np_rng: np.random.Generator) -> None:
    """Put the learner process's random generators back where the checkpoint left them."""
    torch.set_rng_state(rng_state["torch"])
    np_rng.bit_generator.state = rng_state["numpy"]
    version, internal, gauss = rng_state["python"]
    random.setstate((version, tuple(internal), gauss))
