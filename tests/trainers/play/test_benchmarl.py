"""The "benchmarl" loader of the ``neuronsmae.policies`` group takes BenchMARL checkpoints only:
anything else is left to the other loaders, without importing BenchMARL."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.trainers.play.benchmarl import find_checkpoint, load


def experiment_folder(root: Path, *frames: int) -> Path:
    folder = root / "mappo_coop_continuous_mlp__x"
    (folder / "checkpoints").mkdir(parents=True)
    (folder / "config.pkl").write_bytes(b"")
    for n in frames:
        (folder / "checkpoints" / f"checkpoint_{n}.pt").write_bytes(b"")
    return folder


def test_other_text_is_left_to_the_other_loaders(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"")  # the trainers' checkpoint
    for text in ("easy", str(run), str(run / "checkpoint.pt"), str(tmp_path / "missing")):
        assert load(text) is None


def test_the_loader_imports_neither_benchmarl_nor_torch_for_other_text() -> None:
    """Every loader of the group is imported by neuronsmae-match, with or without the extra."""
    code = (
        "import sys; from neuronsmae.trainers.play.benchmarl import load; "
        "assert load('easy') is None; "
        "print(sorted(m for m in ('benchmarl', 'torch', 'torchrl') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_checkpoint_file_or_the_latest_of_a_folder(tmp_path: Path) -> None:
    folder = experiment_folder(tmp_path, 200, 1000, 600)
    latest = folder / "checkpoints" / "checkpoint_1000.pt"
    assert find_checkpoint(str(folder)) == latest
    assert find_checkpoint(str(folder / "checkpoints" / "checkpoint_200.pt")) == (
        folder / "checkpoints" / "checkpoint_200.pt"
    )


def test_a_folder_without_checkpoints_is_refused(tmp_path: Path) -> None:
    folder = experiment_folder(tmp_path)
    with pytest.raises(InvalidOptionError, match="without checkpoints"):
        load(str(folder))
