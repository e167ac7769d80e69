"""Faults: kill a server, a Ray rollout worker and the learner; measure loss and recovery.

    python -m bench.faults [--repeats 3] [--skip ray learner]

1. **Server** (``--repeats`` times per case), run under the fleet supervisor
   (``python -m neuronsmae.server.serving.fleet``, checking every 0.5 s), which restarts it. A
   client (``RM``, timeout 5 s) loses it with SIGKILL:
   * *mid-step*: the server is paced (``--time-scale 1``: a decision lasts 0.4 s) and is
     killed 0.2 s into answering a step;
   * *mid-reset*: the server is frozen (SIGSTOP), sent a reset, then killed;
   * *between episodes*: killed after an episode ended, before the next reset.
   Measured: what the client raised and how long after the kill; how long until a reset
   succeeds on the restarted server; whether the retried request said the episode was lost
   (``ResetNeededError``); whether the new episode equals a fresh in-process ``Arena``.
2. **Ray rollout worker**: ``ray.kill`` of a worker while it plays (as
   tests/trainers/run/test_training.py does): restarts, time until the interrupted episodes
   land (replayed whole on a fresh actor), and that no seed is stored twice or partially.
3. **Learner**: ``neuronsmae-train`` SIGKILLed (its whole process group) some episodes after
   a checkpoint, then ``--resume``: the episodes since the checkpoint and the replay buffer
   are what is lost; measured: time to the first new episode, the final counters, and that
   every episode is recorded once. Then the same with SIGINT (Ctrl-C), which stops the run
   where it is with a checkpoint: only the replay buffer is lost.

Writes bench/out/faults.json; exits 1 when a recovery fails.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import at_least, free_port, machine, same, table, write_json
from neuronsmae.client import RM
from neuronsmae.protocol.errors import ResetNeededError, ServerUnavailableError
from neuronsmae.server.arena import Arena

TIMEOUT = 5.0
PATIENCE = 120.0
"""Seconds any single recovery may take before it counts as failed."""


# ---- 1. servers ----------------------------------------------------------------------------


class Supervised:
    """``neuronsmae-fleet`` with one server; it restarts the server when it dies."""

    def __init__(self, port: int, time_scale: float, folder: Path) -> None:
        self.port, self.state = port, folder / f"state-{port}.json"
        cmd = [sys.executable, "-m", "neuronsmae.server.serving.fleet", "--base-port", str(port),
               "--count", "1", "--time-scale", str(time_scale), "--interval", "0.5",
               "--state-file", str(self.state), "--log-dir", str(folder)]  # fmt: skip
        self.log = (folder / f"fleet-{port}.log").open("wb")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self.log,
                                     stderr=self.log, start_new_session=True)  # fmt: skip

    def server_pid(self, other_than: int | None = None) -> int:
        """The running server's pid (a new one, when ``other_than`` is given)."""
        deadline = time.monotonic() + PATIENCE
        while time.monotonic() < deadline:
            try:
                pid = json.loads(self.state.read_text())["servers"][0]["pid"]
            except (OSError, ValueError, KeyError, IndexError):
                pid = None
            if pid and pid != other_than:
                return int(pid)
            time.sleep(0.1)
        raise RuntimeError(f"the supervisor on {self.port} never reported a server")

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


def _until(call: Callable[[], Any], patience: float = PATIENCE) -> Any:
    """``call()`` again every 0.1 s while the server is unavailable."""
    deadline = time.monotonic() + patience
    while True:
        try:
            return call()
        except ServerUnavailableError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def _allowed(arena: Any) -> list[int]:
    return [int(np.flatnonzero(m)[0]) for m in arena.get_avail_actions()]


def server_case(case: str, sup: Supervised, seed: int) -> dict[str, Any]:
    """Kill the supervised server as ``case`` says; what the client saw, and recovery."""
    pid = sup.server_pid()
    env = _until(lambda: RM(seed=seed, port=sup.port, launch=False, timeout=TIMEOUT))
    outcome: dict[str, Any] = {}
    try:
        env.reset()
        played = 0
        if case == "between episodes":
            while not env.step(_allowed(env))[2]:
                pass  # to the end of the episode: then nothing is in flight
        else:
            for _ in range(3):
                env.step(_allowed(env))
                played += 1
        if case == "mid-reset":
            played = 0  # the episode being started is lost, with no decisions yet
        if case == "mid-reset":
            os.kill(pid, signal.SIGSTOP)
        call = env.reset if case != "mid-step" else lambda: env.step(_allowed(env))
        if case == "between episodes":
            killed = time.monotonic()
            os.kill(pid, signal.SIGKILL)
            _attempt(call, outcome)
        else:
            worker = threading.Thread(target=_attempt, args=(call, outcome))
            worker.start()
            time.sleep(0.2 if case == "mid-step" else 0.3)  # mid-step: half a 0.4 s decision
            killed = time.monotonic()
            os.kill(pid, signal.SIGKILL)
            worker.join(TIMEOUT + 5)
        sup.server_pid(other_than=pid)  # the supervisor has started a new one
        try:
            _until(lambda: env.step(_allowed(env)))
            lost_confirmed = False
        except ResetNeededError:
            lost_confirmed = True
        reachable = time.monotonic() - killed
        local = Arena(seed=seed)
        identical = same(env.reset(), local.reset())
        recovered = time.monotonic() - killed
        for _ in range(5):
            actions = _allowed(local)
            identical &= same(env.step(actions), local.step(actions))
        local.close()
    finally:
        env.close()
    return {
        "case": case,
        "client_error": type(outcome.get("error")).__name__,
        "error_after_ms": 1000 * (outcome.get("at", float("nan")) - killed),
        "in_flight": {"mid-step": "step", "mid-reset": "reset"}.get(case, "nothing"),
        "decisions_lost": played,
        "retry_said_reset_needed": lost_confirmed,
        "reachable_after_s": reachable,
        "new_episode_after_s": recovered,
        "new_episode_identical": identical,
    }


def _attempt(call: Callable[[], Any], out: dict[str, Any]) -> None:
    try:
        call()
    except ServerUnavailableError as exc:
        out["error"] = exc
    out["at"] = time.monotonic()


def servers(repeats: int, folder: Path) -> list[dict[str, Any]]:
    rows = []
    for time_scale, cases in ((1.0, ["mid-step"]), (0.0, ["mid-reset", "between episodes"])):
        sup = Supervised(free_port(), time_scale, folder)
        try:
            for case in cases:
                for r in range(repeats):
                    rows.append(server_case(case, sup, seed=10 + r))
                    print(f"server {case} #{r}: {rows[-1]}", flush=True)
        finally:
            sup.stop()
    return rows


TINY: dict[str, Any] = {
    "eval_episodes": 2,
    "final_eval_episodes": 2,
    "batch_size": 4,
    "learning_starts": 4,
    "worker_cpus": 0.5,
    "agent_hidden": 16,
    "hypernet_hidden": 8,
    "mixer_embed": 8,
    "train_every": 1,
    "envs_per_worker": 2,
}
"""Training settings small enough that a faulted run takes seconds (the faults, not the
learning, are under test); ``envs_per_worker=2`` plays chunks of two episodes."""


# ---- 2. a Ray rollout worker ---------------------------------------------------------------


def ray_worker(folder: Path, episodes: int = 16) -> dict[str, Any]:
    import ray

    from neuronsmae.trainers.run.config import make_config
    from neuronsmae.trainers.run.train import Trainer, train_seed

    base = {"alg": "vdn", "workers": 2, "episodes": episodes, "out": str(folder / "ray"),
            "progress": False, "eval_every": 0}  # fmt: skip
    cfg = make_config(base, TINY)
    state: dict[str, Any] = {}

    def hook(trainer: Trainer) -> None:
        now = time.monotonic()
        if "killed_at" not in state:
            mine = [t for t in trainer.sampler.in_flight.values() if t.worker == 0]
            if trainer.counters.episodes >= 4 and mine:
                state["seeds"] = {r.seed for t in mine for r in t.requests}
                ray.kill(trainer.sampler.actors[0])  # dies while playing those episodes
                state["killed_at"] = now
        elif "recovered_at" not in state and state["seeds"] <= set(trainer.stored_seeds):
            state["recovered_at"] = now

    t0 = time.monotonic()
    trainer = Trainer(cfg, hook=hook)
    result = trainer.run()
    expected = sorted(train_seed(cfg.seed, k, cfg.eval.eval_seed) for k in range(episodes))
    buf, partial = trainer.buffer, 0
    for i in range(len(buf)):  # a stored episode is filled up to its length and no further
        n = int(buf.lengths[i])
        partial += not (buf.filled[i, :n].all() and not buf.filled[i, n:].any())
    return {
        "episodes": result["counters"]["episodes"],
        "restarts": result["counters"]["restarts"],
        "episodes_interrupted": len(state.get("seeds", ())),
        "replayed_after_s": state.get("recovered_at", float("nan")) - state["killed_at"],
        "every_seed_stored_once": sorted(trainer.stored_seeds) == expected,
        "partial_episodes_stored": int(partial),
        "run_wall_s": time.monotonic() - t0,
    }


# ---- 3. the learner ------------------------------------------------------------------------


def _episodes_logged(path: Path) -> list[int]:
    """The ``episodes`` column of train.csv (one row per training round)."""
    try:
        with path.open() as f:
            return [int(row["episodes"]) for row in csv.DictReader(f)]
    except (OSError, KeyError, ValueError):
        return []


def _checkpoint_episodes(run: Path) -> int:
    import torch

    try:
        return int(torch.load(run / "checkpoint.pt", weights_only=True)["counters"]["episodes"])
    except (OSError, RuntimeError, EOFError, KeyError):
        return 0


def _stored(run: Path) -> list[int]:
    """The ``episode`` column of episodes.csv (one row per stored training episode)."""
    try:
        with (run / "episodes.csv").open() as f:
            return [int(row["episode"]) for row in csv.DictReader(f)]
    except (OSError, KeyError, ValueError):
        return []


def learner(folder: Path, how: str, episodes: int = 60, every: int = 10) -> dict[str, Any]:
    """Stop the learner with ``how`` (``SIGKILL`` or ``SIGINT``, Ctrl-C) to its whole
    process group some episodes after a checkpoint, then resume it to the end."""
    run = folder / f"learner_{how}"
    pairs = {**TINY, "checkpoint_every": every}
    sets = [a for k, v in pairs.items() for a in ("--set", f"{k}={v}")]
    cmd = [sys.executable, "-m", "neuronsmae.trainers.run.cli", "--alg", "vdn", "--level", "easy",
           "--workers", "1", "--episodes", str(episodes), "--out", str(run), "--quiet",
           *sets]  # fmt: skip
    log = (folder / f"learner_{how}.log").open("wb")
    first = subprocess.Popen(cmd, stdout=log, stderr=log, start_new_session=True)
    deadline = time.monotonic() + 600
    while True:  # a checkpoint, then some episodes past it
        ckpt = _checkpoint_episodes(run)
        logged = _episodes_logged(run / "train.csv")
        if ckpt >= every and logged and logged[-1] >= ckpt + every // 2:
            break
        if first.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the first run ended or stalled; see {log.name}")
        time.sleep(0.2)
    signalled = time.monotonic()
    os.killpg(first.pid, getattr(signal, how))  # the learner and everything it started
    first_status = first.wait(120)
    stopped_s = time.monotonic() - signalled
    at_stop, ckpt = max(_stored(run)), _checkpoint_episodes(run)
    train_csv = run / "train.csv"
    stale = (train_csv.stat().st_ino, any(e > ckpt for e in _episodes_logged(train_csv)))

    def new_rows() -> list[int]:  # the resumed run's rows (it rewrites a file with stale rows)
        if stale[1] and train_csv.stat().st_ino == stale[0]:
            return []
        return [e for e in _episodes_logged(train_csv) if e > ckpt]

    t0 = time.monotonic()
    resume = [sys.executable, "-m", "neuronsmae.trainers.run.cli", "--resume", "--out", str(run),
              "--quiet"]  # fmt: skip
    second = subprocess.Popen(resume, stdout=log, stderr=log, start_new_session=True)
    first_new = caught_up = None  # the first episode after resuming; the first past at_stop
    while second.poll() is None and time.monotonic() - t0 < 900:
        new = new_rows()
        if first_new is None and new:
            first_new = time.monotonic() - t0
        if caught_up is None and new and max(new) > at_stop:
            caught_up = time.monotonic() - t0
        time.sleep(0.2)
    code = second.wait(60)
    log.close()
    import torch

    final = torch.load(run / "checkpoint.pt", weights_only=True)["counters"]
    return {
        "signal": how,
        "exit_status": first_status,
        "stopped_after_s": stopped_s,
        "episodes_at_stop": at_stop,
        "checkpoint_episodes": ckpt,
        "episodes_lost": at_stop - ckpt,
        "resume_exit_status": code,
        "resume_to_first_episode_s": first_new,
        "resume_to_past_the_stop_s": caught_up,
        "resume_to_finish_s": time.monotonic() - t0,
        "final_episodes": final["episodes"],
        "final_updates": final["updates"],
        "every_episode_recorded_once": _stored(run) == list(range(1, episodes + 1)),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=at_least(1), default=3)
    parser.add_argument("--skip", nargs="*", default=[], choices=["servers", "ray", "learner"])
    args = parser.parse_args()
    if {"servers", "ray", "learner"} <= set(args.skip):
        parser.error("--skip leaves no part to run: skip at most two of servers, ray, learner")
    report: dict[str, Any] = {"machine": machine(), "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if "servers" not in args.skip:
            rows = servers(args.repeats, folder)
            report["servers"] = rows
            print(table(rows, ["case", "in_flight", "client_error", "error_after_ms",
                               "decisions_lost", "retry_said_reset_needed", "reachable_after_s",
                               "new_episode_after_s", "new_episode_identical"]))  # fmt: skip
            ok &= all(r["client_error"] == "ServerUnavailableError"
                      and r["error_after_ms"] < 1000 * TIMEOUT
                      and r["new_episode_identical"] for r in rows)  # fmt: skip
        if "ray" not in args.skip:
            report["ray_worker"] = ray_worker(folder)
            print("ray worker:", report["ray_worker"])
            ok &= report["ray_worker"]["every_seed_stored_once"]
            ok &= report["ray_worker"]["partial_episodes_stored"] == 0
        if "learner" not in args.skip:
            report["learner"] = [learner(folder, how) for how in ("SIGKILL", "SIGINT")]
            for row in report["learner"]:
                print("learner:", row)
                ok &= row["resume_exit_status"] == 0 and row["every_episode_recorded_once"]
            ok &= report["learner"][1]["exit_status"] == 130  # Ctrl-C: stopped, checkpoint saved
            ok &= report["learner"][1]["episodes_lost"] == 0
    report["ok"] = ok
    print(f"wrote {write_json('faults', report)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
