"""Recordings replay exactly; a tampered one is caught at the right decision; videos."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from neuronsmae.protocol.errors import RecordingFormatError, ReplayMismatchError
from neuronsmae.protocol.recording import (
    Decision,
    Recording,
    RecordingWriter,
    decision_hash,
    read_recording,
    write_recording,
)
from neuronsmae.server import Arena
from neuronsmae.server.render import size as render_size
from neuronsmae.server.tools import replay as R

SEED, EPISODE_SEED = 5, 77
CONTEXTS = {"level": "middle"}


def record_random_episode(path: Path, decisions: int | None = None) -> Recording:
    """Play uniformly random available abstract actions, writing as we go (the way the
    client's Recorder does, with the protocol's writer only)."""
    arena = Arena(seed=SEED)
    rng = np.random.default_rng(0)
    arena.reset(CONTEXTS, seed=EPISODE_SEED)
    rec = Recording(SEED, arena.config.to_dict(), EPISODE_SEED, CONTEXTS,
                    decision_hash(arena.get_state()))  # fmt: skip
    writer = RecordingWriter(path, rec)
    done, k = False, 0
    while not done and (decisions is None or k < decisions):
        actions = [int(rng.choice(np.flatnonzero(m))) for m in arena.get_avail_actions()]
        _, rewards, done, info = arena.step(actions)
        writer.decision(Decision.after(actions, arena.get_state(), rewards, done, info))
        k += 1
    if decisions is None:
        writer.close()
    arena.close()
    return read_recording(path) if decisions is None else rec


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "episode.jsonl.gz"
    record_random_episode(path)
    return path


def test_file_is_gzip_json_lines_with_the_documented_header(recorded: Path) -> None:
    with gzip.open(recorded, "rt") as f:
        lines = [json.loads(line) for line in f]
    head = lines[0]
    assert head["format"] == "neuronsmae-episode" and head["version"] == 1
    assert (head["arena_seed"], head["seed"], head["contexts"]) == (SEED, EPISODE_SEED, CONTEXTS)
    assert head["options"]["action_space"] == "abstract" and len(head["hash"]) == 64
    assert [row["k"] for row in lines[1:]] == list(range(1, len(lines)))
    assert lines[-1]["done"] and lines[-1]["winner"] in ("blue", "red", "draw")
    assert not any(row["done"] for row in lines[1:-1])


def test_recorded_episode_replays_with_identical_hashes(recorded: Path) -> None:
    rec = read_recording(recorded)
    result = R.replay(rec)
    assert result.decisions == len(rec.decisions) > 0
    assert result.complete and result.winner == rec.winner
    assert R.main([str(recorded)]) == 0


def test_a_changed_action_is_reported_at_its_decision(
    recorded: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = read_recording(recorded)
    k = 3  # 1-based decision number; both blue robots are alive this early
    old = rec.decisions[k - 1].actions
    # Another enemy and another candidate point: a different goal, so a different motion.
    rec.decisions[k - 1].actions = [(a + 5) % 8 for a in old]
    tampered = write_recording(tmp_path / "tampered.jsonl.gz", rec)
    with pytest.raises(ReplayMismatchError) as err:
        R.replay(read_recording(tampered))
    assert err.value.decision == k
    assert R.main([str(tampered)]) == 1
    assert f"decision {k} differs" in capsys.readouterr().err


def test_a_changed_seed_is_reported_at_the_reset(recorded: Path, tmp_path: Path) -> None:
    rec = read_recording(recorded)
    rec.seed += 1
    with pytest.raises(ReplayMismatchError) as err:
        R.replay(read_recording(write_recording(tmp_path / "seed.jsonl.gz", rec)))
    assert err.value.decision == 0


def test_an_episode_cut_short_still_replays(tmp_path: Path) -> None:
    path = tmp_path / "cut.jsonl.gz"
    record_random_episode(path, decisions=4)  # the writer is never closed, as after a crash
    rec = read_recording(path)
    assert len(rec.decisions) == 4 and not rec.complete and rec.winner is None
    assert R.replay(rec).decisions == 4


def test_not_a_recording_is_a_format_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.jsonl.gz"
    bad.write_bytes(b"not gzip")
    with pytest.raises(RecordingFormatError, match="not a gzip"):
        read_recording(bad)
    with gzip.open(bad, "wt") as f:
        f.write('{"format": "neuronsmae-episode", "version": 99}\n')
    with pytest.raises(RecordingFormatError, match="version 99"):
        read_recording(bad)
    assert R.main([str(bad)]) == 2


def test_gif_has_one_frame_per_decision_plus_the_start(recorded: Path, tmp_path: Path) -> None:
    n = len(read_recording(recorded).decisions)
    gif, half = tmp_path / "ep.gif", tmp_path / "half.gif"
    # Small frames keep the test quick; the encoder is the same at any size.
    assert R.main([str(recorded), "--gif", str(gif), "--scale", "0.25"]) == 0
    assert R.main([str(recorded), "--gif", str(half), "--every", "2", "--scale", "0.25"]) == 0
    w, h = render_size()
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == n + 1
        assert im.size == (round(w / 4), round(h / 4))
    with Image.open(half) as im:  # every 2nd frame, and the last one (the result) always
        assert im.n_frames == len(range(0, n + 1, 2)) + (n % 2)


def test_mp4_without_imageio_ffmpeg_names_the_extra(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "imageio_ffmpeg" else real(name, *a),
    )
    assert R.main([str(recorded), "--mp4", str(tmp_path / "ep.mp4")]) == 2
    assert "pip install 'neuronsmae[video]'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (["--fps", "nan", "--gif", "x.gif"], "--fps must be in [0.1, 50], got nan"),
        (["--fps", "1e-9", "--gif", "x.gif"], "--fps must be in [0.1, 50]"),
        (["--fps", "inf"], "--fps must be in [0.1, 50], got inf"),
        (["--fps", "0"], "--fps must be in [0.1, 50]"),
        (["--every", "0", "--scale", "nan"], "--every must be an integer ≥ 1, got 0; --scale"),
        (["--scale", "0"], "--scale must be in [0.05, 4], got 0.0"),
    ],
)
def test_video_flags_outside_their_range_are_usage_errors_before_any_replay(
    recorded: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str], flags: list[str], named: str,
) -> None:  # fmt: skip
    """NaN or a vanishing frame rate used to crash the GIF writer after the whole replay;
    an infinite one wrote a GIF with zero delays; a bad --every or --scale passed unseen
    unless a video was asked for."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(R, "replay", lambda *a, **k: pytest.fail("replayed a refused run"))
    with pytest.raises(SystemExit) as exc:
        R.main([str(recorded), *flags])
    assert exc.value.code == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "x.gif").exists()


def test_the_video_writers_refuse_a_rate_outside_its_range(tmp_path: Path) -> None:
    from neuronsmae.protocol.errors import InvalidOptionError
    from neuronsmae.server.tools.video import write_gif, write_video

    frame = np.zeros((8, 8, 3), dtype=np.uint8)
    for fps in (float("nan"), 0.0, 1e-9, 51.0, float("inf")):
        with pytest.raises(InvalidOptionError, match=r"fps must be in \[0.1, 50\]"):
            write_gif(tmp_path / "a.gif", [frame], fps)
    with pytest.raises(InvalidOptionError, match="every must be an integer ≥ 1"):
        write_video(tmp_path / "a.gif", [frame], every=0)
    assert not (tmp_path / "a.gif").exists()
    assert write_gif(tmp_path / "b.gif", [frame, frame], 50.0).exists()


def test_a_truncated_header_is_not_called_empty(recorded: Path, tmp_path: Path) -> None:
    """A gzip stream cut before its first newline, or a header line cut short, said
    "empty file": they are truncated, and only a file without content is empty."""
    raw = recorded.read_bytes()
    cut = tmp_path / "cut.jsonl.gz"
    cut.write_bytes(raw[:60])  # the gzip stream ends early, inside the header line
    with pytest.raises(RecordingFormatError, match="truncated or corrupt: the gzip stream"):
        read_recording(cut)
    header = gzip.decompress(raw).split(b"\n")[0]
    half = tmp_path / "half.jsonl.gz"
    half.write_bytes(gzip.compress(header[: len(header) // 2]))  # a header without its end
    with pytest.raises(RecordingFormatError, match="header line is cut short"):
        read_recording(half)
    assert R.main([str(half)]) != 0
    empty = tmp_path / "empty.jsonl.gz"
    empty.write_bytes(gzip.compress(b""))
    with pytest.raises(RecordingFormatError, match="empty file"):
        read_recording(empty)
