"""Self-play training through Ray: the pool grows, draws follow the rule, a resumed run
keeps the same schedule (opponents, snapshots, seeds, counts), and a fixed checkpoint can
be the opponent.

One local Ray (2 CPUs) serves the module. The runs are tiny and synchronous (iterations of
two episodes), so the pool at each episode is a function of the episode alone.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch

from neuronsmae.trainers.play.pool import OpponentPool, SelfPlayConfig
from neuronsmae.trainers.run.cli import main
from tests.trainers.checkpoints import make_checkpoint

pytestmark = [pytest.mark.ray, pytest.mark.slow, pytest.mark.usefixtures("local_ray")]

TINY = [
    "workers=1", "env=inprocess", "sync=true", "iteration_episodes=2", "envs_per_worker=2",
    "agent_hidden=16", "hypernet_hidden=8", "mixer_embed=8", "batch_size=4",
    "learning_starts=2", "eval_every=0", "keep_best=false", "final_eval_episodes=2",
    "max_minutes=0", "checkpoint_every=4", "snapshot_every=4", "worker_cpus=0.5",
]  # fmt: skip


def _train(out: Path, episodes: int, *extra: str, resume: bool = False, code: int = 0) -> None:
    sets = [a for kv in (*TINY, *extra) for a in ("--set", kv)]
    argv = ["--resume"] if resume else ["--alg", "vdn", *sets]
    assert main([*argv, "--out", str(out), "--episodes", str(episodes), "--quiet"]) == code


def _opponents(run: Path) -> list[str]:
    with (run / "episodes.csv").open() as f:
        return [row["opponent"] for row in csv.DictReader(f)]


def _snapshots(run: Path) -> list[str]:
    return sorted(p.name for p in (run / "snapshots").glob("*.pt"))


def test_the_pool_grows_and_the_draws_follow_the_rule(tmp_path: Path) -> None:
    _train(tmp_path, 12, "opponent=easy,self")
    assert _snapshots(tmp_path) == [f"self_{e:08d}.pt" for e in (0, 4, 8, 12)]
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert saved["opponents"] == {"snapshots": [0, 4, 8, 12]}
    # Episode k met what δ-uniform sampling over the pool of that moment draws.
    pool = OpponentPool("easy,self", SelfPlayConfig(snapshot_every=4), seed=1)
    drawn = _opponents(tmp_path)
    for k, got in enumerate(drawn):
        while len(pool.snapshots) <= k // 4:  # snapshots at 0, 4, 8 exist before episode k
            pool.add_snapshot(4 * len(pool.snapshots), None)
        assert got == pool.draw(k).id
        assert got in {m.id for m in pool.candidates()}
    assert {"bot:easy", "self:0"} <= set(drawn) and len(drawn) == 12
    with (tmp_path / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert all(('"bot_team": "red"' in r["contexts"]) == (r["opponent"] == "bot:easy")
               for r in rows)  # fmt: skip
    snap = torch.load(tmp_path / "snapshots" / "self_00000004.pt", weights_only=True)
    assert snap["counters"]["episodes"] == 4 and set(snap["learner"]) == {"agent"}


def test_a_resumed_self_play_run_keeps_the_schedule_and_counts(tmp_path: Path) -> None:
    whole, split = tmp_path / "whole", tmp_path / "split"
    _train(whole, 12, "opponent=easy,self", "delta=0.0")
    _train(split, 8, "opponent=easy,self", "delta=0.0")
    before = torch.load(split / "snapshots" / "self_00000004.pt", weights_only=True)
    _train(split, 12, resume=True)
    assert _opponents(split) == _opponents(whole)
    assert _snapshots(split) == _snapshots(whole)
    after = torch.load(split / "snapshots" / "self_00000004.pt", weights_only=True)
    for name, tensor in before["learner"]["agent"].items():  # kept, not retaken
        assert torch.equal(tensor, after["learner"]["agent"][name])
    with (whole / "episodes.csv").open() as a, (split / "episodes.csv").open() as b:
        seeds = [[r["seed"] for r in csv.DictReader(f)] for f in (a, b)]
    assert seeds[0] == seeds[1]
    ends = [torch.load(run / "checkpoint.pt", weights_only=True) for run in (whole, split)]
    counted = [{k: c["counters"][k] for k in ("episodes", "env_steps", "updates")} for c in ends]
    assert counted[0] == counted[1] and counted[0]["updates"] > 0
    # (The weights after the resume differ a little: the replay buffer is not checkpointed,
    # so the resumed learner samples from the episodes it has played since; checkpoint.py.)


def test_a_fixed_checkpoint_is_an_opponent(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    ckpt = make_checkpoint(tmp_path / "fixed.pt", 4)
    _train(tmp_path / "run", 4, f"opponent={ckpt}")
    assert set(_opponents(tmp_path / "run")) == {f"ckpt:{ckpt}"}
    three = make_checkpoint(tmp_path / "3v3.pt", 4, n_blue=3, n_red=3)
    _train(tmp_path / "bad", 4, f"opponent={three}", code=2)
    assert "another task layout" in capsys.readouterr().err


@pytest.mark.parametrize("what", ["empty folder", "junk file"])
def test_an_opponent_checkpoint_that_cannot_be_read_stops_the_run_before_ray(
    what: str, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from neuronsmae.trainers.run import train

    monkeypatch.setattr(train, "start_ray", lambda cfg: pytest.fail("Ray started"))
    entry = tmp_path / "opp"  # was found only once the workers ran, 7-10 s in
    if what == "empty folder":
        entry.mkdir()
    else:
        entry.write_bytes(b"not a checkpoint")
    out = tmp_path / "run"
    argv = ["--opponent", f"easy,{entry}", "--out", str(out), "--episodes", "2", "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"opponent entry '{entry}'" in err
    assert ("no checkpoint at" if what == "empty folder" else "is not a NeuronsMAE") in err
