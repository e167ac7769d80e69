"""Training through Ray: the CLI end to end with resume, the sync loop, and worker faults.

One local Ray (2 CPUs) serves the whole module; workers ask for half a CPU each so two of
them fit beside the learner. The runs are tiny (a few episodes, a 16-unit GRU): they check
the plumbing, not learning.
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import ray
import torch

from neuronsmae.trainers.core.buffer import Batch, Episode
from neuronsmae.trainers.play.evaluate import GreedyPolicy, evaluate_checkpoint, load_policy
from neuronsmae.trainers.play.rollout import Request
from neuronsmae.trainers.run.cli import main
from neuronsmae.trainers.run.config import ConfigError, make_config, preset
from neuronsmae.trainers.run.contexts import ContextSpec
from neuronsmae.trainers.run.interrupt import TrainingInterrupted
from neuronsmae.trainers.run.sampler import PlacementError
from neuronsmae.trainers.run.train import TEST_SEED_OFFSET, Trainer, train_seed

pytestmark = [pytest.mark.ray, pytest.mark.slow, pytest.mark.usefixtures("local_ray")]

TINY = [
    "eval_episodes=2",
    "final_eval_episodes=2",
    "batch_size=4",
    "learning_starts=4",
    "worker_cpus=0.5",
    "agent_hidden=16",
    "hypernet_hidden=8",
    "mixer_embed=8",
    "train_every=1",
    "envs_per_worker=2",  # chunks of two episodes: evaluations fall due between them
]


def _sets(*extra: str) -> list[str]:
    return [arg for kv in (*TINY, *extra) for arg in ("--set", kv)]


def _episodes_column(path: Path) -> list[int]:
    with path.open() as f:
        return [int(row["episodes"]) for row in csv.DictReader(f)]


def test_cli_two_workers_checkpoint_then_resume(tmp_path: Path) -> None:
    out = tmp_path / "run"
    base = ["--alg", "qmix", "--level", "easy", "--workers", "2", "--out", str(out), "--quiet"]
    # Served arenas (the default env) in two groups stepped in turn.
    assert main([*base, "--episodes", "8", *_sets("eval_every=4", "cluster.groups=2")]) == 0
    first = torch.load(out / "checkpoint.pt", weights_only=True)
    assert first["config"]["env"] == "remote" and first["config"]["cluster"]["groups"] == 2
    assert first["counters"]["episodes"] == 8 and first["counters"]["updates"] > 0
    assert first["config"]["alg"] == "qmix" and first["config"]["workers"] == 2
    # The replay is saved beside the checkpoint, marked with its episodes, and comes back.
    with np.load(out / "replay.npz") as saved:
        assert int(saved["_episodes"]) == 8 and int(saved["_size"]) == 8
    again = Trainer(make_config(first["config"], {"episodes": 12, "progress": False}),
                    resume=True)  # fmt: skip
    try:
        assert len(again.buffer) == 8 and again.buffer.added == 8
    finally:
        again.close()

    assert main(["--resume", "--out", str(out), "--episodes", "12", "--quiet"]) == 0
    second = torch.load(out / "checkpoint.pt", weights_only=True)
    assert second["counters"]["episodes"] == 12
    assert second["counters"]["updates"] > first["counters"]["updates"]
    assert second["counters"]["env_steps"] > first["counters"]["env_steps"]
    # From Python as from the command line, a resumed run keeps what shapes its networks.
    other = make_config(second["config"], {"alg": "vdn", "episodes": 16, "progress": False})
    with pytest.raises(ConfigError, match="this changes alg 'qmix' -> 'vdn'"):
        Trainer(other, resume=True)

    # The match command plays the checkpoint through the registered policy entry point.
    from neuronsmae.trainers.play.match import play

    result = play(str(out / "checkpoint.pt"), "easy", 2, 1_000_000_000)
    assert result["episodes"] == 2
    assert result["blue_win_rate"] + result["red_win_rate"] + result["draw_rate"] == 1.0
    assert second["config"]["learner"]["agent_hidden"] == 16  # the saved config was kept
    steps = _episodes_column(out / "train.csv")
    assert steps == sorted(steps) and steps[-1] == 12
    assert _episodes_column(out / "eval.csv")[-1] == 12
    with (out / "eval.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["split"] for r in rows} == {"validation", "test"}
    assert [r["weights"] for r in rows if r["split"] == "test"][-2:] == ["latest", "best"]
    best = torch.load(out / "best.pt", weights_only=True)  # the match command loads it too
    assert best["agent_spec"] == second["agent_spec"]
    assert play(str(out / "best.pt"), "easy", 1, 1_000_000_000)["episodes"] == 1

    result = evaluate_checkpoint(out, "easy", episodes=2, seed=7)
    assert 0.0 <= result["win_rate"] <= 1.0 and result["eval_episodes"] == 2
    assert result["episodes_trained"] == 12 and result["alg"] == "qmix"
    policy, probe = GreedyPolicy(out / "checkpoint.pt"), GreedyPolicy(out / "checkpoint.pt")
    obs = list(np.random.default_rng(0).random((2, 37), dtype=np.float32))
    q = probe.q_values(obs)  # the checkpoint's Q; the greedy choice among actions 3 and 5
    want = [3 if q[i, 3] > q[i, 5] else 5 for i in range(2)]
    mask = np.zeros(8, np.int8)
    mask[[3, 5]] = 1
    assert policy.act(obs, [mask, mask]) == want


def test_sync_loop_takes_one_episode_per_worker(tmp_path: Path) -> None:
    cfg = make_config(
        {
            "alg": "iql",
            "workers": 2,
            "episodes": 4,
            "sync": True,
            "out": str(tmp_path),
            "progress": False,
            "eval_every": 0,
        },
        dict(kv.split("=") for kv in TINY),
        # augment and the replay of lost starts ride along: they must work inside the real loop
        {"learning_starts": 2, "augment": "enemies,field,allies", "start_replay": 1.0},
    )
    trainer = Trainer(cfg)
    assert len(trainer.learning.group) == 8
    assert trainer.spec.input_dim == trainer.learner.agent.fc1.in_features
    result = trainer.run()
    assert result["counters"]["episodes"] == 4
    # one training round per iteration of 2 episodes (the first fills learning_starts)
    assert trainer.learner.updates == 2 * cfg.learner.updates_per_round
    # p = 1: the second iteration replays the first iteration's starts not won (each once,
    # never both at once) and plays fresh seeds only for the rest
    first = {e.info["seed"]: e.info["winner"] == "blue" for e in list(trainer.recent)[:2]}
    lost = sorted(seed for seed, won in first.items() if not won)
    assert lost  # the untrained agents lose a start of the first iteration: replay is exercised
    second = trainer.stored_seeds[2:]
    assert sorted(s for s in second if s in first) == lost
    fresh = [train_seed(cfg.seed, k, cfg.eval.eval_seed) for k in range(4)]
    assert all(s in first or s in fresh[2:] for s in second)
    assert result["start_replays"] == len(lost) and set(fresh[:2]) == set(first)
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=True)["starts"]
    assert saved["replays"] == len(lost) and len(saved["seeds"]) == len(saved["plays"])


def test_validation_and_test_seeds_are_disjoint_and_best_weights_are_tested(
    tmp_path: Path,
) -> None:
    cfg = make_config(
        {"alg": "vdn", "workers": 1, "episodes": 6, "out": str(tmp_path), "progress": False},
        dict(kv.split("=") for kv in TINY),
        {"eval_every": 2, "eval_episodes": 3, "final_eval_episodes": 4},
    )
    trainer = Trainer(cfg)
    played: dict[str, set[int]] = {"validation": set(), "test": set()}
    run = trainer.sampler.run

    def recording_run(requests: list[Request]) -> list[Episode]:
        test = requests[0].seed >= cfg.eval.eval_seed + TEST_SEED_OFFSET
        split = "test" if test else "validation"
        played[split].update(r.seed for r in requests)
        sent = ray.get(trainer.sampler.weights_ref).weights

        def same(w: dict[str, np.ndarray]) -> bool:
            return all(np.array_equal(sent[k], v) for k, v in w.items())

        if not same(trainer.learner.acting_weights()):  # the best-validated weights' test
            assert split == "test" and trainer.best is not None and same(trainer.best[0])
        return run(requests)

    trainer.sampler.run = recording_run  # type: ignore[method-assign]
    import neuronsmae.trainers.run.saving as saving

    saves: list[int] = []
    real_save = saving.save_replay

    def counted_save(path: Path, replay: object, episodes: int) -> None:
        saves.append(episodes)
        real_save(path, replay, episodes)

    saving.save_replay = counted_save  # type: ignore[assignment]
    try:
        result = trainer.run()
    finally:
        saving.save_replay = real_save  # type: ignore[assignment]
    # best weights and the final checkpoint share counts with others: one replay write each
    assert saves == sorted(set(saves)) and saves[-1] == 6
    assert played["validation"] == {cfg.eval.eval_seed + k for k in range(3)}
    assert played["test"] == {cfg.eval.eval_seed + TEST_SEED_OFFSET + k for k in range(4)}
    best, validation = result["best"], [e for e in result["evals"] if e["split"] == "validation"]
    assert best["split"] == "test" and best["weights"] == "best"
    top = max(e["win_rate"] for e in validation)
    assert best["validation"]["win_rate"] == top
    # ties go to the later, longer-trained weights
    assert best["chosen_at_episodes"] == max(
        e["episodes"] for e in validation if e["win_rate"] == top
    )
    assert best["validation"]["episodes"] == best["chosen_at_episodes"]
    assert (tmp_path / "best.pt").is_file()
    # the checkpoints hand the match command the weights they were written with
    assert trainer.best is not None
    for path, weights in (
        (tmp_path / "best.pt", trainer.best[0]),
        (tmp_path, trainer.learner.acting_weights()),
    ):
        loaded = load_policy(path).weights
        assert all(np.array_equal(loaded[k], v) for k, v in weights.items())


def test_no_validation_once_the_wall_clock_budget_is_spent(tmp_path: Path) -> None:
    cfg = make_config(
        {"alg": "vdn", "workers": 1, "episodes": 1000, "out": str(tmp_path), "progress": False},
        dict(kv.split("=") for kv in TINY),
        {"eval_every": 1, "max_minutes": 10.0},
    )
    trainer = Trainer(cfg)
    train = trainer.learner.train

    def expiring(batch: Batch) -> dict[str, float]:
        trainer.session_start -= 3600.0  # the ten minutes run out during the first update
        return train(batch)

    trainer.learner.train = expiring  # type: ignore[method-assign]
    result = trainer.run()
    validation = [e for e in result["evals"] if e["split"] == "validation"]
    # every landing before learning began was evaluated (eval_every=1), none after it
    assert validation and all(e["updates"] == 0 for e in validation)
    assert result["counters"]["updates"] > 0
    assert result["final"]["split"] == "test"


def test_killed_worker_is_restarted_and_no_partial_episode_is_stored(tmp_path: Path) -> None:
    n = 10
    cfg = make_config(
        {
            "alg": "vdn",
            "workers": 2,
            "episodes": n,
            "out": str(tmp_path),
            "progress": False,
            "eval_every": 0,
        },
        dict(kv.split("=") for kv in TINY),
    )
    killed: list[int] = []

    def kill_worker_mid_run(trainer: Trainer) -> None:
        playing = [ref for ref, t in trainer.sampler.in_flight.items() if t.worker == 0]
        # still playing: its chunk has not finished (a finished one would be collected whole)
        done, _ = ray.wait(playing, num_returns=len(playing), timeout=0) if playing else ([], [])
        if not killed and trainer.counters.episodes >= 3 and playing and not done:
            ray.kill(trainer.sampler.actors[0])  # the actor dies while playing an episode
            killed.append(trainer.counters.episodes)

    trainer = Trainer(cfg, hook=kill_worker_mid_run)
    result = trainer.run()
    assert killed and result["counters"]["restarts"] >= 1
    assert result["counters"]["episodes"] == n
    # every training seed was stored exactly once: the interrupted one was replayed whole
    assert sorted(trainer.stored_seeds) == sorted(
        train_seed(cfg.seed, k, cfg.eval.eval_seed) for k in range(n)
    )
    buf = trainer.buffer
    for i in range(len(buf)):
        steps = int(buf.lengths[i])
        assert buf.filled[i, :steps].all() and not buf.filled[i, steps:].any()
        assert buf.terminated[i, steps - 1] == 1


def test_the_released_loop_learns_after_each_iteration_and_copies_targets_every_5th(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The paper preset (the released loop) on two workers: iterations of 20 episodes, then
    max(20, 2·⌊stored / 2,000⌋) updates (20 while fewer than 20,000 transitions are stored),
    the targets copied at the first update of iterations 0 and 5; tests at coef 1.5 and 1.0."""
    from neuronsmae.trainers.core.learner import QLearner

    copies: list[int] = []
    real = QLearner.update_targets

    def spy(self: QLearner) -> None:
        copies.append(self.updates)
        real(self)

    monkeypatch.setattr(QLearner, "update_targets", spy)
    tiny = {k: v for k, v in (kv.split("=") for kv in TINY) if k != "batch_size"}
    cfg = make_config(
        preset("paper"),
        tiny,
        {
            "workers": 2, "envs_per_worker": 5, "episodes": 160, "out": str(tmp_path),
            "progress": False, "learning_starts": 0, "eval.eval_every": 0,
        },
    )  # fmt: skip
    seen: list[tuple[int, int]] = []
    result = Trainer(
        cfg, hook=lambda t: seen.append((t.counters.episodes, t.learner.updates))
    ).run()
    assert seen == [(e, e) for e in range(20, 161, 20)]  # 20 updates per iteration
    assert copies == [1, 101]  # the first update of iterations 0 and 5
    assert result["counters"]["rounds"] == 8 and result["counters"]["samples"] > 0
    assert result["extra_tests"]["coef=1.0"]["contexts"] == "coef=1.0"
    assert {"released_win_rate", "win_rate"} <= set(result["final"])
    with (tmp_path / "eval.csv").open() as f:
        assert {r["contexts"] for r in csv.DictReader(f)} == {"main", "coef=1.0"}


def test_each_episode_draws_its_contexts_and_a_resumed_run_draws_the_same(
    tmp_path: Path,
) -> None:
    spec_text = "coef=0.5,1.5;Friction_coeff=0.2..0.4"
    base = ["--alg", "vdn", "--workers", "2", "--out", str(tmp_path), "--quiet"]
    assert main([*base, "--episodes", "8", *_sets(f"contexts={spec_text}")]) == 0
    assert main(["--resume", "--out", str(tmp_path), "--episodes", "12", "--quiet"]) == 0
    spec = ContextSpec.parse(spec_text)
    with (tmp_path / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    eval_seed = make_config().eval.eval_seed
    ks = []
    for row in rows:
        k = (int(row["seed"]) - 1 * 1_000_003) % eval_seed  # the run seed is 1
        assert train_seed(1, k, eval_seed) == int(row["seed"])
        assert json.loads(row["contexts"]) == {"level": "easy", **spec.sample(1, k)}
        ks.append(k)
    assert sorted(ks) == list(range(12))  # both sessions, no episode lost or repeated
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert saved["config"]["contexts"] == spec_text


@pytest.mark.parametrize(
    ("layer", "said"),
    [({"contexts": "coef=0.5..20"}, "'coef'=20.0 is out of range; valid: [0.0, 10.0]"),
     ({"contexts": "foo=1"}, "unknown context key 'foo'"),
     ({"eval_contexts": "coef=-5"}, "'coef'=-5.0 is out of range")],
)  # fmt: skip
def test_contexts_the_arena_refuses_stop_the_run_before_any_worker_starts(
    layer: dict[str, str], said: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from neuronsmae.trainers.run import train

    monkeypatch.setattr(train, "start_ray", lambda cfg: pytest.fail("Ray started"))
    cfg = make_config(
        dict(kv.split("=") for kv in TINY), {"workers": 1, "episodes": 4, "out": str(tmp_path)}
    )  # an arena's reset found these 7-15 s in, once the workers had started
    with pytest.raises(ConfigError, match=re.escape(said)):
        Trainer(make_config(cfg.to_dict(), layer))


def test_a_worker_count_the_cluster_cannot_hold_is_refused_at_once(tmp_path: Path) -> None:
    """This module's Ray has 2 CPUs: ten half-CPU workers can never be placed."""
    cfg = make_config(
        dict(kv.split("=") for kv in TINY),
        {"workers": 10, "episodes": 4, "out": str(tmp_path), "env": "inprocess"},
    )
    start = time.monotonic()
    with pytest.raises(
        PlacementError, match=r"10 rollout workers cannot be placed \(CPU: 5 needed"
    ):
        Trainer(cfg)
    assert time.monotonic() - start < 30


def test_a_crashed_then_stopped_run_resumes_with_every_episode_recorded_once(
    tmp_path: Path,
) -> None:
    cfg = make_config(
        {"alg": "vdn", "workers": 1, "episodes": 16, "out": str(tmp_path), "progress": False},
        dict(kv.split("=") for kv in TINY),
        {"checkpoint_every": 4, "eval_every": 4},
    )

    def crash(trainer: Trainer) -> None:
        if trainer.counters.episodes >= 6:  # killed between the checkpoints at 4 and 8
            raise RuntimeError("the machine went down")

    with pytest.raises(RuntimeError, match="went down"):
        Trainer(cfg, hook=crash).run()
    assert _episodes_column(tmp_path / "train.csv")[-1] >= 6  # rows past the checkpoint

    def ctrl_c(trainer: Trainer) -> None:
        if trainer.counters.episodes >= 10 and not trainer.stop.requested:
            os.kill(os.getpid(), signal.SIGINT)  # through the run's own handler

    with pytest.raises(TrainingInterrupted, match="--resume") as stopped:
        Trainer(cfg, resume=True, hook=ctrl_c).run()
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=True)["counters"]
    assert saved["episodes"] == stopped.value.episodes >= 10  # saved where it stopped
    with (tmp_path / "episodes.csv").open() as f:
        stored = [int(r["episode"]) for r in csv.DictReader(f)]
    assert stored == list(range(1, saved["episodes"] + 1))

    result = Trainer(cfg, resume=True).run()
    assert result["counters"]["episodes"] == 16
    with (tmp_path / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(r["episode"]) for r in rows] == list(range(1, 17))
    # the episodes played again after the crash kept their seeds
    assert [int(r["seed"]) for r in rows] == [
        train_seed(cfg.seed, k, cfg.eval.eval_seed) for k in range(16)
    ]
    steps = _episodes_column(tmp_path / "train.csv")
    assert steps == sorted(steps) and len(set(steps)) == len(steps) and steps[-1] == 16
    evals = _episodes_column(tmp_path / "eval.csv")
    assert evals == sorted(evals) and evals.count(8) == 1
    with pytest.raises(ConfigError, match="finished its 16 episodes"):
        Trainer(cfg, resume=True)


def test_the_best_weights_never_run_ahead_of_the_checkpoint_a_resume_takes(
    tmp_path: Path,
) -> None:
    """best.pt was written at each new best validation, checkpoint.pt only every
    checkpoint_every episodes: a run killed between them resumed with best weights (and a
    'chosen at' row) from the stretch it then trained again."""
    cfg = make_config(
        {"alg": "vdn", "workers": 1, "episodes": 12, "out": str(tmp_path), "progress": False},
        dict(kv.split("=") for kv in TINY),
        {"checkpoint_every": 100, "eval_every": 4},
    )

    def crash(trainer: Trainer) -> None:
        if trainer.counters.episodes >= 6:  # after the first validation, long before 100
            raise RuntimeError("the machine went down")

    with pytest.raises(RuntimeError, match="went down"):
        Trainer(cfg, hook=crash).run()
    best = torch.load(tmp_path / "best.pt", weights_only=True)
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=True)  # none was, before
    assert best["selection"]["episodes"] <= saved["counters"]["episodes"]

    best["selection"]["episodes"] = 99  # as an older version could leave it
    torch.save(best, tmp_path / "best.pt")
    result = Trainer(cfg, resume=True).run()
    assert (tmp_path / "best.pt.after-checkpoint").is_file()  # set aside, not trusted
    assert result["best"]["chosen_at_episodes"] <= 12
    chosen = torch.load(tmp_path / "best.pt", weights_only=True)["selection"]["episodes"]
    assert chosen == result["best"]["chosen_at_episodes"]


def test_a_trainer_runs_once_and_one_that_never_ran_leaves_no_run_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from neuronsmae.protocol.errors import ClosedError
    from neuronsmae.trainers.run import train as train_module
    from neuronsmae.trainers.run.records import RunLock

    cfg = make_config(
        dict(kv.split("=") for kv in TINY),
        {"alg": "vdn", "workers": 1, "episodes": 2, "out": str(tmp_path), "progress": False},
    )
    looked = Trainer(cfg)  # built to inspect its networks, then closed unused
    assert looked.spec.n_actions > 0
    looked.close()
    assert not (tmp_path / "config.json").exists()  # the folder still takes a new run

    def broken(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(train_module, "Recorder", broken)
    failing = Trainer(make_config(cfg.to_dict(), {"out": str(tmp_path / "failing")}))
    with pytest.raises(OSError, match="disk full"):
        failing.run()  # the workers and the run's lock are released all the same
    assert failing.closed and not any(failing.sampler.actors)
    RunLock(tmp_path / "failing").release()
    monkeypatch.undo()

    trainer = Trainer(cfg)
    trainer.run()
    finished = (tmp_path / "checkpoint.pt").read_bytes()
    with pytest.raises(ClosedError, match="has run or been closed"):
        trainer.run()  # it restarted Ray and rewrote the checkpoint as unfinished
    assert (tmp_path / "checkpoint.pt").read_bytes() == finished

    # From Python, as from the command line: a resumed run keeps what shapes its networks.
    other = make_config(cfg.to_dict(), {"alg": "iql", "episodes": 4})
    with pytest.raises(ConfigError, match="alg 'vdn' -> 'iql'"):
        Trainer(other, resume=True)
    assert json.loads((tmp_path / "config.json").read_text())["alg"] == "vdn"


def test_a_decoupled_learner_keeps_its_ratio_and_stores_every_episode(tmp_path: Path) -> None:
    """replay_ratio > 0: the learner trains in its own thread while the workers sample; the
    updates stay within the tolerance of ratio × stored episodes, and every episode that
    landed is stored and recorded once."""
    seen: list[tuple[int, int, float]] = []

    def watch(trainer: Trainer) -> None:
        thread = trainer.learning.thread
        assert thread is not None
        seen.append((trainer.counters.episodes, trainer.learner.updates, thread.target()))

    cfg = make_config(
        {k: v for k, v in (kv.split("=") for kv in TINY)},
        {"alg": "vdn", "episodes": 24, "workers": 2, "env": "inprocess", "out": str(tmp_path),
         "progress": False, "eval.eval_every": 0, "learner.replay_ratio": 2.0},
    )  # fmt: skip
    trainer = Trainer(cfg, hook=watch)
    result = trainer.run()
    counters = result["counters"]
    assert counters["episodes"] == 24 == len(trainer.stored_seeds)
    assert len(set(trainer.stored_seeds)) == 24  # each landed episode stored once
    with (tmp_path / "episodes.csv").open() as f:
        assert [int(r["episode"]) for r in csv.DictReader(f)] == list(range(1, 25))
    assert counters["updates"] > 0 and counters["learn_seconds"] > 0
    from bench.baselines_report import scores
    from neuronsmae.trainers.run.marl_eval import check_format

    exported = json.loads((tmp_path / "marl_eval.json").read_text())  # read back
    check_format(exported)
    assert scores(exported)["vdn"]["coop_abstract_easy"].tolist() == [result["final"]["win_rate"]]
    for _, updates, target in seen:  # never ahead of the ratio by more than its slack
        assert updates <= target + max(2.0, 0.1 * target) + 1
    assert counters["updates"] <= 2.0 * (24 - 4) * 1.1 + 2


def test_a_decoupled_learner_that_lags_keeps_up_with_a_throttled_driver(tmp_path: Path) -> None:
    """A ratio the learner cannot keep up with pauses sampling; the driver then waits for the
    learner instead of polling (a polling driver thread starved the learner's of the
    interpreter, and a 30-minute run made 366 updates)."""
    cfg = make_config(
        {k: v for k, v in (kv.split("=") for kv in TINY)},
        {"alg": "vdn", "episodes": 24, "workers": 2, "env": "inprocess", "out": str(tmp_path),
         "progress": False, "eval.eval_every": 0, "learner.replay_ratio": 20.0},
    )  # fmt: skip
    trainer = Trainer(cfg)
    real, polls = trainer.sampler.wait, [0]

    def counted(*args: object, **kwargs: object) -> list[Episode]:
        polls[0] += 1
        return real(*args, **kwargs)  # type: ignore[arg-type]

    trainer.sampler.wait = counted  # type: ignore[method-assign]
    start = time.perf_counter()
    counters = trainer.run()["counters"]
    seconds = time.perf_counter() - start
    assert counters["episodes"] == 24
    assert counters["updates"] >= 0.7 * 20.0 * (24 - 4)  # kept pace within its tolerance
    assert polls[0] < 50 * seconds + 100  # waited on the learner, never spun on the sampler
