"""The per-agent Gymnasium face, held to the contract EPyMARL's ``gymma`` wrapper and its
episode and parallel runners rely on (read from EPyMARL's source; none of it is copied
here): ``gymnasium.make(key, **env_args)`` in a process that never imported NeuronsMAE,
``TimeLimit`` on top, per-agent ``Tuple`` spaces it iterates, flattens and ranks by ``.n``,
``unwrapped.n_agents``, Python-int actions, a reward list it sums, numeric infos it adds up
across episodes, ``info["episode_limit"]`` telling the time limit from a real end, and
environments built in ``fork``-ed worker processes."""

from __future__ import annotations

import pickle
import subprocess
import sys
import textwrap
from collections.abc import Callable, Iterator
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit

from neuronsmae.client import AgentsEnv
from neuronsmae.client.gym_env import AGENTS_ENV_ID, agents_ids
from neuronsmae.client.infos import SCALAR_KEYS
from neuronsmae.protocol.errors import InvalidActionError, NotCopyableError
from neuronsmae.server import Arena

from .conftest import numeric, same

KEY = f"neuronsmae.client:{AGENTS_ENV_ID}"
"""What a user puts in ``env_args.key``: importable with no prior import."""
IN_PROCESS = "neuronsmae.server:Arena"
SHORT = {"episode_steps": 200}
"""10 abstract decisions an episode."""
BLUE_LOSES = {"coef": 10.0, "opponent_hp": 10000.0}
"""Contexts under which red wipes blue out within a few decisions."""


@pytest.fixture
def make() -> Iterator[Callable[..., gymnasium.Env[Any, Any]]]:
    """``gymma``'s construction: ``make(key, **env_args)`` then ``TimeLimit``; closed after."""
    built: list[gymnasium.Env[Any, Any]] = []

    def build(time_limit: int = 10, **env_args: Any) -> gymnasium.Env[Any, Any]:
        env = TimeLimit(gymnasium.make(KEY, **{"env": IN_PROCESS, **env_args}), time_limit)
        built.append(env)
        return env

    yield build
    for env in built:
        env.close()


def flat(env: gymnasium.Env[Any, Any], obs: Any) -> list[np.ndarray]:
    """Each agent's observation flattened through its own space, as ``gymma`` does."""
    return [spaces.flatten(s, o) for s, o in zip(env.observation_space, obs, strict=True)]


def episode(env: gymnasium.Env[Any, Any], rng: np.random.Generator, **reset: Any) -> dict[str, Any]:
    """One episode as EPyMARL's episode runner plays it: Python-int actions for every agent,
    the summed reward, ``terminated or truncated`` as the end; returns what it would log."""
    n = env.unwrapped.n_agents  # type: ignore[attr-defined]
    width = max(env.action_space, key=lambda s: s.n).n  # type: ignore[attr-defined]
    obs, info = env.reset(**reset)
    assert len(flat(env, obs)) == n and info.keys() == set(SCALAR_KEYS) and numeric(info)
    total, steps = 0.0, 0
    while True:
        actions = [int(a) for a in rng.integers(width, size=n)]
        obs, rewards, terminated, truncated, info = env.step(actions)
        assert isinstance(rewards, list) and len(rewards) == n
        total += float(sum(rewards))
        steps += 1
        if terminated or truncated:
            return {
                "return": total, "steps": steps, "info": info, "obs": flat(env, obs),
                "limit": bool(info.get("episode_limit", False)),
                "terminated": terminated, "truncated": truncated,
            }  # fmt: skip


def test_make_finds_the_key_without_a_prior_import() -> None:
    # The key alone, as EPyMARL passes it (its configuration takes no other arguments).
    code = textwrap.dedent("""
        import sys, gymnasium
        from gymnasium.wrappers import TimeLimit
        env = TimeLimit(gymnasium.make("neuronsmae.client:NeuronsMAE/Agents-InProcess-v0"), 50)
        assert type(env.unwrapped.arena).__module__ == "neuronsmae.server.arena"
        obs, info = env.reset(seed=1)
        obs, rewards, terminated, truncated, info = env.step([0, 0])
        assert env.unwrapped.n_agents == len(rewards) == 2
        env.close()
        print(sorted(m for m in sys.modules if m.startswith("neuronsmae.client.")
                     and m.endswith(("agents_env", "gym_env"))))
    """)
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=180
    )
    assert out.stdout.strip() == "['neuronsmae.client.agents_env', 'neuronsmae.client.gym_env']"


def test_the_ids_for_the_paper_bots_and_in_process_arenas() -> None:
    ids = agents_ids()
    assert ids["NeuronsMAE/Agents-v0"] == {}
    assert ids["NeuronsMAE/Agents-hard-v0"] == {"contexts": {"level": "hard"}}
    assert ids["NeuronsMAE/Agents-InProcess-middle-v0"] == {
        "env": IN_PROCESS, "contexts": {"level": "middle"}
    }  # fmt: skip
    assert len(ids) == 8 and all(i in gymnasium.registry for i in ids)

    def first_steps(env_id: str, level: str) -> list[Any]:
        env = gymnasium.make(env_id, seed=2, **SHORT)
        arena = Arena(seed=2, **SHORT)
        try:
            assert isinstance(env.unwrapped.arena, Arena)  # type: ignore[attr-defined]
            out = [env.reset()[0], arena.reset({"level": level})]
            for _ in range(6):
                out += [env.step([3, 5])[:2], arena.step([3, 5])[:2]]
            return out
        finally:
            env.close()
            arena.close()

    hard = first_steps("NeuronsMAE/Agents-InProcess-hard-v0", "hard")
    assert same(hard[0::2], hard[1::2])
    easy = first_steps("NeuronsMAE/Agents-InProcess-v0", "easy")
    assert same(easy[0::2], easy[1::2])
    assert not same(hard[0::2], easy[0::2])


@pytest.mark.parametrize("kind", ["abstract", "discrete"])
def test_spaces_are_per_agent_tuples_gymma_can_rank_and_flatten(
    make: Callable[..., gymnasium.Env[Any, Any]], kind: str
) -> None:
    env = make(action_space=kind, n_blue=3, **SHORT)
    layout = env.unwrapped.layout  # type: ignore[attr-defined]
    assert env.unwrapped.n_agents == 3  # type: ignore[attr-defined]
    assert isinstance(env.observation_space, spaces.Tuple)
    assert isinstance(env.action_space, spaces.Tuple)
    assert len(env.observation_space) == len(env.action_space) == 3
    longest_action = max(env.action_space, key=lambda s: s.n)  # type: ignore[attr-defined]
    assert spaces.flatdim(longest_action) == layout.n_actions
    longest_obs = max(env.observation_space, key=lambda s: s.shape)  # type: ignore[attr-defined]
    assert spaces.flatdim(longest_obs) == layout.obs_dim
    obs, _ = env.reset(seed=0)
    assert all(o.shape == (layout.obs_dim,) and o.dtype == np.float32 for o in flat(env, obs))
    # No state_size: gymma then takes its state to be the concatenated observations.
    assert not hasattr(env.unwrapped, "state_size")
    assert env.unwrapped.state().shape == (layout.state_dim,)  # type: ignore[attr-defined]


def test_the_runner_loop_logs_numbers_and_tells_the_time_limit_from_an_end(
    make: Callable[..., gymnasium.Env[Any, Any]],
) -> None:
    rng = np.random.default_rng(0)
    timed = make(time_limit=20, seed=3, **SHORT)
    wiped = make(time_limit=150, seed=3, episode_steps=3000, contexts=BLUE_LOSES)
    stats: dict[str, Any] = {}
    episodes = [episode(timed, rng) for _ in range(2)] + [episode(wiped, rng) for _ in range(2)]
    for ep in episodes:
        info = ep["info"]
        assert info.keys() == set(SCALAR_KEYS) and numeric(info)
        # EPyMARL adds every info value of an episode's last step across episodes.
        stats = {k: stats.get(k, 0) + info.get(k, 0) for k in set(stats) | set(info)}
    for ep in episodes[:2]:  # the arena's own time limit (10 decisions), before TimeLimit's
        assert ep["steps"] == 10 and ep["truncated"] and not ep["terminated"] and ep["limit"]
    for ep in episodes[2:]:  # blue wiped out: a real end, to be learned from
        assert ep["steps"] < 150 and ep["terminated"] and not ep["limit"]
        assert ep["info"]["dead_allies"] == 2 and not ep["info"]["battle_won"]
    assert stats["episode_limit"] == 2 and stats["dead_allies"] >= 4
    assert all(isinstance(v / len(episodes), float) for v in stats.values())


def test_rewards_are_the_team_reward_for_every_agent(
    make: Callable[..., gymnasium.Env[Any, Any]],
) -> None:
    env = make(seed=5, **SHORT)
    env.reset(seed=5)
    arena = Arena(seed=5, **SHORT)
    try:
        arena.reset(None, 5)
        for _ in range(10):
            _, rewards, terminated, truncated, _ = env.step([1, 2])
            _, expected, done, _ = arena.step([1, 2])
            assert rewards == [float(r) for r in expected] and rewards[0] == rewards[1]
            assert (terminated or truncated) == done
            if done:
                break
    finally:
        arena.close()


def test_seeding_as_gymma_does_it(make: Callable[..., gymnasium.Env[Any, Any]]) -> None:
    # gymma tries unwrapped.seed(seed) and falls back to reset(seed=seed); later resets are
    # unseeded and continue the seeded RNG, so a run is reproducible from its seed alone.
    runs = []
    for _ in range(2):
        env = make(**SHORT)
        assert not hasattr(env.unwrapped, "seed")
        env.reset(seed=8)
        rng = np.random.default_rng(1)
        runs.append([episode(env, rng) for _ in range(2)])
    assert same(runs[0], runs[1])
    assert not same(runs[0][0]["obs"], runs[0][1]["obs"])


def test_actions_are_checked(make: Callable[..., gymnasium.Env[Any, Any]]) -> None:
    env = make(**SHORT)
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match="expected 2 actions"):
        env.step([0])
    with pytest.raises(InvalidActionError, match=r"agent 1: .*valid: \[0, 7\]"):
        env.step([0, 99])
    with pytest.raises(InvalidActionError, match="agent 0: an action is an integer"):
        env.step([float("nan"), 0])
    with pytest.raises(InvalidActionError, match=r"a sequence of 2 .* got 3"):
        env.step(3)  # type: ignore[arg-type]
    # A dict played its keys, a set its arbitrary order, "35" the actions [3, 5].
    for bad in ({0: 3, 1: 5}, {3, 5}, frozenset({3, 5}), "35", b"35"):
        with pytest.raises(InvalidActionError, match="a sequence of 2 per-agent actions"):
            env.step(bad)  # type: ignore[arg-type]
    with pytest.raises(InvalidActionError, match="agent 0: an action is an integer"):
        env.step(["3", "5"])
    unwrapped = env.unwrapped
    masks = unwrapped.get_avail_actions()  # type: ignore[attr-defined]
    assert [m.shape for m in masks] == [(unwrapped.layout.n_actions,)] * 2  # type: ignore[attr-defined]


def test_continuous_actions_are_per_agent_boxes(
    make: Callable[..., gymnasium.Env[Any, Any]],
) -> None:
    env = make(action_space="continuous", **SHORT)
    assert all(isinstance(s, spaces.Box) and s.shape == (4,) for s in env.action_space)
    env.reset(seed=0)
    env.action_space.seed(0)
    _, rewards, *_ = env.step(env.action_space.sample())
    assert len(rewards) == 2


def test_pickles_as_its_recipe() -> None:
    env = AgentsEnv(env=IN_PROCESS, seed=4, **SHORT)
    copy = pickle.loads(pickle.dumps(env))
    try:
        assert copy.arena is not env.arena
        assert same(env.reset()[0], copy.reset()[0])
    finally:
        env.close()
        copy.close()
    held = AgentsEnv(env=Arena(seed=4, **SHORT))
    try:
        with pytest.raises(NotCopyableError, match="arena object cannot be"):
            pickle.dumps(held)
    finally:
        held.close()


@pytest.mark.slow
def test_forked_workers_each_launch_their_own_server() -> None:
    # EPyMARL's parallel runner: the parent forks its workers (multiprocessing's default on
    # Linux) before touching any environment; each worker makes one with default arguments.
    code = textwrap.dedent(f"""
        import multiprocessing as mp
        import gymnasium

        def worker(conn, seed):
            env = gymnasium.make({KEY!r}, seed=seed)
            obs, _ = env.reset()
            total = 0.0
            for _ in range(5):
                _, rewards, terminated, truncated, info = env.step([0, 1])
                total += sum(rewards)
            conn.send((env.unwrapped.arena.port, obs[0].tolist(), total))
            env.close()

        if __name__ == "__main__":
            ctx = mp.get_context("fork")
            pipes = [ctx.Pipe() for _ in range(2)]
            procs = [ctx.Process(target=worker, args=(child, s))
                     for s, (_, child) in enumerate(pipes)]
            for p in procs:
                p.start()
            results = [parent.recv() for parent, _ in pipes]
            for p in procs:
                p.join(60)
            assert [p.exitcode for p in procs] == [0, 0]
            assert results[0][0] != results[1][0]  # a private server each
            assert results[0][1] != results[1][1]  # seeds 0 and 1 differ
            print("ok")
    """)
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-3000:]


def test_a_fractional_or_boolean_action_is_refused_not_truncated() -> None:
    """The per-agent and SMAC faces took int() of each action: 0.5 became action 0."""
    from neuronsmae.client.spaces import per_agent_actions
    from neuronsmae.protocol.errors import InvalidActionError

    for bad in ([0.5, 0], [True, 1], [float("nan"), 0], [np.array([1, 2]), 0], [None, 0]):
        with pytest.raises(InvalidActionError, match="agent 0: an action is an integer"):
            per_agent_actions(bad, 2)
    whole = [np.float32(2.0), np.array(3)]
    assert per_agent_actions(whole, 2) == [2, 3]  # whole numbers in any numeric form
