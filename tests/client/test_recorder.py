"""The client's Recorder: transparent wrapping, file per episode, exact replays (also via RM)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from neuronsmae.client import RM
from neuronsmae.client.recorder import Recorder
from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.interface import ArenaAPI
from neuronsmae.protocol.recording import existing_recordings, read_recording, write_recording
from neuronsmae.server.arena import Arena
from neuronsmae.server.tools.replay import replay
from tests.client.conftest import free_port, same


def play(env: ArenaAPI, rng: np.random.Generator, limit: int | None = None) -> dict[str, Any]:
    """Random available actions until the episode ends (or ``limit`` decisions)."""
    done, info, k = False, {}, 0
    while not done and (limit is None or k < limit):
        actions = [int(rng.choice(np.flatnonzero(m))) for m in env.get_avail_actions()]
        _, _, done, info = env.step(actions)
        k += 1
    return info


def test_recorded_episodes_replay_identically_and_the_wrapper_is_transparent(
    tmp_path: Path,
) -> None:
    bare, wrapped = Arena(seed=2), Recorder(Arena(seed=2), tmp_path, meta={"by": "test"})
    r1, r2 = np.random.default_rng(9), np.random.default_rng(9)
    assert same(wrapped.reset({"level": "easy"}, seed=11), bare.reset({"level": "easy"}, seed=11))
    info = play(wrapped, r1)
    assert same(info, play(bare, r2))  # recording changes nothing the caller sees
    assert same(wrapped.get_state(), bare.get_state())
    wrapped.reset({"level": "hard"})  # no seed: the recorder picks one, and records it
    play(wrapped, r1)
    wrapped.close()
    bare.close()
    first, second = (read_recording(p) for p in wrapped.paths)
    assert wrapped.paths[0].name == "episode_00000_s11.jsonl.gz"
    assert (first.seed, first.contexts, first.meta) == (11, {"level": "easy"}, {"by": "test"})
    assert first.complete and first.winner == info["winner"]
    assert second.contexts == {"level": "hard"} and f"_s{second.seed}." in wrapped.paths[1].name
    for rec in (first, second):
        assert replay(rec).decisions == len(rec.decisions)


def test_select_and_limit_pick_the_episodes_written(tmp_path: Path) -> None:
    env = Recorder(Arena(seed=1), tmp_path, select=lambda seed, ctx: seed >= 100, limit=2,
                   prefix="eval_")  # fmt: skip
    rng = np.random.default_rng(0)
    for seed in (5, 100, 6, 101, 102):
        env.reset(seed=seed)
        play(env, rng, limit=2)  # cut short by the next reset: still a readable file
    env.close()
    assert [p.name for p in env.paths] == ["eval_00000_s100.jsonl.gz", "eval_00001_s101.jsonl.gz"]
    assert sorted(tmp_path.iterdir()) == sorted(env.paths)
    rec = read_recording(env.paths[1])
    assert len(rec.decisions) == 2 and not rec.complete
    assert replay(rec).decisions == 2


def test_recordings_already_there_are_never_overwritten(tmp_path: Path) -> None:
    """A second recorder (or match) in the same folder wrote its episode_00000_s0 over the
    first one's."""
    first = Recorder(Arena(seed=1), tmp_path)
    first.reset(seed=0)
    play(first, np.random.default_rng(0), limit=3)
    first.close()
    kept = first.paths[0].read_bytes()
    with pytest.raises(InvalidOptionError, match=r"already holds 1 recording.* overwritten"):
        Recorder(Arena(seed=1), tmp_path)
    other = Recorder(Arena(seed=1), tmp_path, prefix="episode_b_")  # another series: fine
    other.reset(seed=0)
    other.close()
    assert [p.name for p in other.paths] == ["episode_b_00000_s0.jsonl.gz"]
    with pytest.raises(InvalidOptionError, match="exists: a recording is never overwritten"):
        write_recording(first.paths[0], read_recording(first.paths[0]))
    assert first.paths[0].read_bytes() == kept
    assert existing_recordings(tmp_path, "episode_") == first.paths  # not episode_b_'s


def test_recorder_keeps_the_interface_and_passes_the_rest_through(tmp_path: Path) -> None:
    for name in ArenaAPI.__abstractmethods__:
        assert getattr(Recorder, name).__doc__ == getattr(ArenaAPI, name).__doc__
    env = Recorder(Arena(seed=0), tmp_path)
    env.reset(seed=1)
    assert env.agent_name(0) == "blue_0"  # not part of ArenaAPI: the arena's own
    env.close()


def test_an_arena_it_cannot_rebuild_must_be_described(tmp_path: Path) -> None:
    class Opaque:  # an arena-like object with a seed but no options to rebuild it from
        seed = 0

        def close(self) -> None:
            pass

    with pytest.raises(InvalidOptionError, match="arena_seed= and options="):
        Recorder(Opaque(), tmp_path)  # type: ignore[arg-type]
    Recorder(Opaque(), tmp_path, arena_seed=0, options={}).close()  # type: ignore[arg-type]


def test_out_dir_must_be_a_directory(tmp_path: Path) -> None:
    a_file = tmp_path / "taken"
    a_file.write_text("not a directory")
    with pytest.raises(InvalidOptionError, match="exists and is not a directory"):
        Recorder(Arena(seed=0), a_file)


@pytest.mark.slow
def test_episode_recorded_through_rm_replays_in_process(tmp_path: Path) -> None:
    # A launched server with graphics "on": the arena renders headless either way, and the
    # frame crosses the wire as the same uint8 array the replay draws in process.
    rm = RM(seed=4, port=free_port(), no_graphics=False, time_scale=0, timeout=30)
    env = Recorder(rm, tmp_path)
    try:
        env.reset({"level": "middle"}, seed=8)
        play(env, np.random.default_rng(1))
        remote_frame = env.render()
    finally:
        env.close()
    rec = read_recording(env.paths[0])
    result = replay(rec, render=True)
    assert rec.complete and result.decisions == len(rec.decisions)
    assert remote_frame.dtype == np.uint8 and remote_frame.ndim == 3
    assert same(remote_frame, result.frames[-1])


@pytest.mark.parametrize(
    ("settings", "said"),
    [
        ({"arena_seed": -1}, "arena_seed must be an integer in [0, 9223372036854775807], got -1"),
        ({"arena_seed": 1.5}, "arena_seed must be an integer"),
        ({"limit": -1}, "limit must be None or an integer ≥ 0, got -1"),
        ({"prefix": "../escape_"}, "prefix must be the start of a file name"),
        ({"prefix": "runs/ep_"}, "prefix must be the start of a file name"),
    ],
)
def test_bad_recorder_settings_are_refused_by_name(
    settings: dict[str, Any], said: str, tmp_path: Path
) -> None:
    """A negative seed was NumPy's ValueError; a prefix with a path wrote outside out_dir."""
    arena = Arena(seed=1)
    try:
        with pytest.raises(InvalidOptionError) as exc:
            Recorder(arena, tmp_path / "rec", **settings)
        assert said in str(exc.value)
        assert Recorder(arena, tmp_path / "rec", limit=0, prefix="blue_").limit == 0
    finally:
        arena.close()
