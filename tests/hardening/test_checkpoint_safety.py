"""Checkpoints are loaded with ``weights_only=True``: a malicious pickle runs nothing."""

from __future__ import annotations

import ast
import os
import pickle
import re
from pathlib import Path
from typing import Any

import pytest

torch = pytest.importorskip("torch")

from neuronsmae.trainers.core.checkpoint import FORMAT, CheckpointError, load_checkpoint  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


class _Payload:
    """Unpickling this creates a file: the proof that pickled code ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[str, ...]]:
        return (os.system, (f"touch {self.marker}",))


def test_malicious_checkpoint_is_refused_and_runs_nothing(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    path = tmp_path / "checkpoint.pt"
    torch.save({"format": 1, "learner": _Payload(marker)}, path)
    with pytest.raises(CheckpointError, match="is not a NeuronsMAE checkpoint") as exc:
        load_checkpoint(tmp_path)  # the run directory form, as --resume uses it
    assert isinstance(exc.value.__cause__, pickle.UnpicklingError)
    assert "eights only" in str(exc.value.__cause__)
    assert not marker.exists()


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_plain_pickle_file_posing_as_a_checkpoint_is_refused(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(pickle.dumps(_Payload(marker)))
    with pytest.raises(CheckpointError, match=r"cannot read it \(UnpicklingError\)"):
        load_checkpoint(path)
    assert not marker.exists()


@pytest.mark.parametrize(
    ("content", "said"),
    [
        (b"garbage", "cannot read it"),
        (b"", "cannot read it"),
        ("list", "format None, not"),
        ("old", "format 1, not"),
    ],
)
def test_a_file_that_is_no_checkpoint_is_a_checkpoint_error_naming_it(
    tmp_path: Path, content: bytes | str, said: str
) -> None:
    """Each of these was a torch or pickle traceback out of neuronsmae-train --resume,
    --opponent and neuronsmae-match."""
    path = tmp_path / "best.pt"
    if content == "list":
        torch.save([1, 2], path)
    elif content == "old":
        torch.save({"format": 1}, path)
    else:
        path.write_bytes(content)
    with pytest.raises(CheckpointError, match=re.escape(f"{path} ") + ".*" + re.escape(said)):
        load_checkpoint(path)
    torch.save({"format": FORMAT}, path)
    assert load_checkpoint(path) == {"format": FORMAT}


def test_the_command_lines_report_a_bad_checkpoint_without_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from neuronsmae.trainers.play import match

    bad = tmp_path / "checkpoint.pt"
    bad.write_bytes(b"garbage")
    assert match.main(["--blue", str(bad), "--episodes", "1"]) == 2
    assert f"{bad} is not a NeuronsMAE checkpoint" in capsys.readouterr().err


def test_every_torch_load_in_the_project_is_weights_only() -> None:
    calls = []
    for pkg in ("trainers", "server", "client", "protocol", "bench"):
        for path in sorted((REPO / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("torch"):
                    # a bare ``load`` would escape the attribute check below
                    assert "load" not in {a.name for a in node.names}, f"{path}:{node.lineno}"
                if (
                    isinstance(node, ast.Call)
                    and isinstance(node.func, ast.Attribute)
                    and node.func.attr == "load"
                    and ast.unparse(node.func.value) in ("torch", "torch.serialization")
                ):
                    safe = any(
                        kw.arg == "weights_only"
                        and isinstance(kw.value, ast.Constant)
                        and kw.value.value is True
                        for kw in node.keywords
                    )
                    calls.append((f"{path.relative_to(REPO)}:{node.lineno}", safe))
    assert calls, "no torch.load found: the checkpoint loader moved?"
    assert [where for where, safe in calls if not safe] == []
