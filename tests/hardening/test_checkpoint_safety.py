"""Checkpoints are loaded with ``weights_only=True``: a malicious pickle runs nothing."""

from __future__ import annotations

import ast
import os
import pickle
from pathlib import Path
from typing import Any

import pytest

torch = pytest.importorskip("torch")

from neuronsmae.trainers.checkpoint import load_checkpoint  # noqa: E402

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
    with pytest.raises(pickle.UnpicklingError, match=r"[Ww]eights only"):
        load_checkpoint(tmp_path)  # the run directory form, as --resume uses it
    assert not marker.exists()


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_plain_pickle_file_posing_as_a_checkpoint_is_refused(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(pickle.dumps(_Payload(marker)))
    with pytest.raises(pickle.UnpicklingError):
        load_checkpoint(path)
    assert not marker.exists()


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
