"""Rollout workers on real in-process arenas: whole episodes, batched play equal to playing
one arena at a time, and nothing on failure."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from neuronsmae.protocol import EnvInfo
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.buffer import EpisodeReplayBuffer
from neuronsmae.trainers.core.learner import EnvSpec, agent_spec
from neuronsmae.trainers.play.rollout import Request, RolloutWorker


class EnvFailure(RuntimeError):
    """Raised by the wrapper below, standing in for a dead env server."""


class FailingStep:
    """Wraps a real arena and raises on the ``fail_at``-th step (a crash mid-episode)."""

    def __init__(self, env: Any, fail_at: int) -> None:
        self.env, self.fail_at, self.steps = env, fail_at, 0

    def step_async(self, actions: Any, **kwargs: Any) -> Any:
        self.steps += 1
        if self.steps == self.fail_at:
            raise EnvFailure("env server died")
        return self.env.step_async(actions, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)


@pytest.fixture(scope="module")
def worker() -> Iterator[RolloutWorker]:
    w = RolloutWorker(0, "inprocess", env_seed=5, port=0)
    yield w
    w.close()


def _policy(w: RolloutWorker) -> tuple[Policy, EnvSpec]:
    env = EnvSpec.of(EnvInfo.from_dict(w.env_info()))
    spec = agent_spec(env, 16, True, True)
    weights = {k: v.numpy() for k, v in spec.build().state_dict().items()}
    return Policy(spec, weights), env


def test_whole_episode_is_valid_and_storable(worker: RolloutWorker) -> None:
    policy, env = _policy(worker)
    ep = worker.run_episode(policy, 0, 1.0, seed=11, contexts={"level": "easy"})
    assert ep.terminated and 1 <= ep.length <= env.episode_limit
    assert ep.info["winner"] in ("blue", "red", "draw")
    assert ep.length == env.episode_limit or ep.info["winner"] != "draw"
    buf = EpisodeReplayBuffer(
        2, env.n_agents, env.obs_dim, env.state_dim, env.n_actions, env.episode_limit
    )
    buf.add(ep)
    # a destroyed robot only ever took its no-op
    dead = ~ep.alive[:-1]
    assert (ep.actions[dead] == 0).all()
    assert np.isfinite(ep.obs).all() and np.isfinite(ep.state).all()


def test_same_seed_same_greedy_episode(worker: RolloutWorker) -> None:
    policy, _ = _policy(worker)
    a = worker.run_episode(policy, 0, 0.0, seed=3, contexts={"level": "easy"})
    b = worker.run_episode(policy, 0, 0.0, seed=3, contexts={"level": "easy"})
    assert np.array_equal(a.actions, b.actions) and np.allclose(a.rewards, b.rewards)
    assert np.array_equal(a.state, b.state)
    other = worker.run_episode(policy, 0, 0.0, seed=4, contexts={"level": "easy"})
    assert not np.array_equal(a.state[0], other.state[0])  # the seed reaches the arena


def test_env_failure_mid_episode_returns_nothing(worker: RolloutWorker) -> None:
    policy, _ = _policy(worker)
    real = worker.env
    worker.env = FailingStep(real, fail_at=5)  # type: ignore[assignment]
    try:
        with pytest.raises(EnvFailure):
            worker.run_episode(policy, 0, 0.2, seed=4, contexts={"level": "easy"})
    finally:
        worker.env = real


def test_a_batched_worker_plays_each_request_as_one_arena_would(worker: RolloutWorker) -> None:
    """Three arenas, seven requests (so arenas take several in turn and one waits idle at
    the end): each greedy episode equals the one-arena worker's for the same request."""
    policy, _ = _policy(worker)
    batched = RolloutWorker(1, "inprocess", env_seed=50, port=None, envs=3)
    try:
        requests = [
            Request(100 + k, 0.0, {"level": ["easy", "middle", 1][k % 3], "coef": 0.5 + k / 10})
            for k in range(7)
        ]
        episodes = batched.run(policy, 7, requests)  # a version the shared worker never saw
        assert [e.info["seed"] for e in episodes] == [r.seed for r in requests]
        for request, got in zip(requests, episodes, strict=True):
            want = worker.run_episode(policy, 7, 0.0, request.seed, request.contexts)
            assert got.info["contexts"] == dict(request.contexts)
            assert np.array_equal(got.actions, want.actions)
            assert np.array_equal(got.rewards, want.rewards)
            assert np.array_equal(got.obs, want.obs) and np.array_equal(got.state, want.state)
            assert np.array_equal(got.avail, want.avail) and np.array_equal(got.alive, want.alive)
            assert got.info["winner"] == want.info["winner"]
    finally:
        batched.close()


def test_exploring_episodes_are_whole_and_keep_their_own_epsilon() -> None:
    worker = RolloutWorker(2, "inprocess", env_seed=60, port=None, envs=4)
    try:
        policy, env = _policy(worker)
        requests = [Request(200 + k, [0.0, 1.0][k % 2], {"level": "easy"}) for k in range(6)]
        episodes = worker.run(policy, 0, requests)
        buf = EpisodeReplayBuffer(
            8, env.n_agents, env.obs_dim, env.state_dim, env.n_actions, env.episode_limit
        )
        for request, episode in zip(requests, episodes, strict=True):
            buf.add(episode)  # validates every row: none half-played
            assert episode.info["epsilon"] == request.epsilon and episode.terminated
            greedy = worker.run(policy, 0, [Request(request.seed, 0.0, request.contexts)])[0]
            explored = not np.array_equal(episode.actions, greedy.actions)
            assert explored == (request.epsilon == 1.0)  # each arena at its own epsilon
        assert worker.run(policy, 0, []) == []
    finally:
        worker.close()


@pytest.mark.slow
@pytest.mark.parametrize(("groups", "servers"), [(2, 1), (1, 2), (2, 2)])
def test_groups_and_servers_of_a_served_vector_play_what_one_arena_plays(
    worker: RolloutWorker, groups: int, servers: int
) -> None:
    """Four served arenas, in one or two groups (stepped in turn while the worker chooses
    the other group's actions), on one or two private servers: each greedy episode equals
    the in-process one-arena one."""
    policy, _ = _policy(worker)
    served = RolloutWorker(
        3, "remote", env_seed=70, port=None, envs=4, groups=groups, servers=servers
    )
    assert len(served.env.ports) == servers  # type: ignore[attr-defined]
    version = 100 + 10 * groups + servers  # a fresh policy: the fixture worker must load it
    try:
        requests = [Request(300 + k, 0.0, {"level": "hard"}) for k in range(6)]
        for request, got in zip(requests, served.run(policy, version, requests), strict=True):
            want = worker.run_episode(policy, version, 0.0, request.seed, request.contexts)
            assert np.array_equal(got.actions, want.actions)
            assert np.array_equal(got.obs, want.obs) and np.array_equal(got.state, want.state)
            assert np.array_equal(got.rewards, want.rewards)
    finally:
        served.close()
