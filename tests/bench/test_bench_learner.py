"""bench_learner: one tiny cell end to end, its JSON and the batches' thread choice."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from bench.bench_learner import main


@pytest.mark.parametrize("prefetch", ["on", "off"])
def test_a_tiny_cell_is_timed_beside_the_reference_and_written_out(
    tmp_path: Path, prefetch: str
) -> None:
    out = tmp_path / "learner.json"
    threads = torch.get_num_threads()
    try:
        assert main(["--learners", "defaults", "--algs", "vdn", "--batches", "2", "--threads",
                     "1", "--device", "cpu", "--updates", "1", "--repeats", "1", "--reference",
                     "--prefetch", prefetch, "--out", str(out)]) == 0  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    (row,) = json.loads(out.read_text())["rows"]
    assert (row["learner"], row["alg"], row["batch"], row["threads"]) == ("defaults", "vdn", 2, 1)
    assert row["prefetch"] is (prefetch == "on")
    assert row["new"]["ms_per_update"] > 0 and row["reference"]["ms_per_update"] > 0
    assert row["speedup"] == pytest.approx(
        row["reference"]["ms_per_update"] / row["new"]["ms_per_update"]
    )
