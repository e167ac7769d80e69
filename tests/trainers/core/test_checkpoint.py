"""The replay saved beside a checkpoint: loaded only with the checkpoint it was saved with."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from neuronsmae.trainers.core.buffer import EpisodeReplayBuffer, TransitionReplayBuffer
from neuronsmae.trainers.core.checkpoint import (
    REPLAY_NAME,
    CheckpointError,
    load_replay,
    save_replay,
)

from ..conftest import ACTIONS, LIMIT, N_AGENTS, OBS, STATE, make_episode


def _filled(kind: type, capacity: int, episodes: int) -> EpisodeReplayBuffer:
    rng = np.random.default_rng(9)
    buf = kind(capacity, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(episodes):
        buf.add(make_episode(LIMIT, rng, dead_from=1))
    return buf


@pytest.mark.parametrize("kind", [EpisodeReplayBuffer, TransitionReplayBuffer])
def test_a_replay_comes_back_with_the_checkpoint_it_was_saved_with(
    kind: type, tmp_path: Path
) -> None:
    saved = _filled(kind, 30, 5)
    path = tmp_path / REPLAY_NAME
    save_replay(path, saved, episodes=40)
    assert sorted(p.name for p in tmp_path.iterdir()) == [REPLAY_NAME]  # no .tmp left
    fresh = kind(30, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    assert load_replay(path, fresh, episodes=40) is None
    assert (len(fresh), fresh.next_slot, fresh.added) == (len(saved), saved.next_slot,
                                                          saved.added)  # fmt: skip
    for name, array in saved.arrays().items():
        assert np.array_equal(fresh.arrays()[name], array), name


def test_a_replay_of_another_checkpoint_or_size_is_not_loaded_and_says_why(
    tmp_path: Path,
) -> None:
    path = tmp_path / REPLAY_NAME
    empty = EpisodeReplayBuffer(4, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    assert load_replay(path, empty, 10) == f"no {REPLAY_NAME}"
    save_replay(path, _filled(EpisodeReplayBuffer, 8, 6), episodes=10)
    # killed between the checkpoint at 20 episodes and its replay: the replay is older
    older = load_replay(path, empty, 20)
    assert older == f"{REPLAY_NAME} was saved at 10 episodes, the checkpoint at 20"
    said = load_replay(path, empty, 10)  # resumed with a smaller learner.buffer_size
    assert said is not None and "does not fit" in said and "capacity of 4" in said
    assert len(empty) == 0


def test_a_file_that_is_no_replay_is_a_checkpoint_error_and_no_pickle_is_read(
    tmp_path: Path,
) -> None:
    path = tmp_path / REPLAY_NAME
    path.write_bytes(b"not an archive")
    buf = EpisodeReplayBuffer(4, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    with pytest.raises(CheckpointError, match="is not a replay neuronsmae-train wrote"):
        load_replay(path, buf, 0)
    save_replay(path, buf, 0)
    path.write_bytes(path.read_bytes()[:200])  # a truncated archive
    with pytest.raises(CheckpointError, match="is not a replay"):
        load_replay(path, buf, 0)
    with open(path, "wb") as f:  # an object array needs pickle to load: refused
        np.savez(f, _episodes=np.int64(0), obs=np.array([object()], dtype=object))
    with pytest.raises(CheckpointError, match="is not a replay"):
        load_replay(path, buf, 0)
