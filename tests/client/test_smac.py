"""The SMAC adapter, held to what SMAC-style runners (PyMARL's and EPyMARL's episode and
parallel runners, and code written against ``StarCraft2Env``) call: ``get_env_info`` for
the buffer's shapes, ``reset``, ``get_state`` / ``get_avail_actions`` / ``get_obs`` before
each decision, ``step`` with a row of a torch action tensor, ``(reward, terminated, info)``
back with ``info["episode_limit"]`` for bootstrapping, infos summed across episodes,
``get_stats``, ``save_replay`` and ``close``."""

from __future__ import annotations

import pickle
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

from neuronsmae.client import RM, SMACEnv
from neuronsmae.client.infos import SCALAR_KEYS
from neuronsmae.protocol.errors import InvalidActionError, InvalidOptionError
from neuronsmae.server import Arena

from .conftest import numeric, same

torch = pytest.importorskip("torch")

IN_PROCESS = "neuronsmae.server:Arena"
SHORT = {"episode_steps": 200}
"""10 abstract decisions an episode."""
BLUE_LOSES = {"coef": 10.0, "opponent_hp": 10000.0}
"""Contexts under which red wipes blue out within a few decisions."""


@pytest.fixture
def make() -> Iterator[Callable[..., SMACEnv]]:
    built: list[SMACEnv] = []

    def build(**kwargs: Any) -> SMACEnv:
        env = SMACEnv(**{"env": IN_PROCESS, **SHORT, **kwargs})
        built.append(env)
        return env

    yield build
    for env in built:
        env.close()


def run(env: SMACEnv, rng: np.random.Generator) -> dict[str, Any]:
    """One episode as a PyMARL-style episode runner plays it: shapes checked against
    ``get_env_info``, actions drawn from the masks into a torch tensor whose row is handed
    to ``step`` as it is; returns what such a runner records."""
    info = env.get_env_info()
    env.reset()
    steps, total, bootstrap = 0, 0.0, []
    while True:
        state, avail, obs = env.get_state(), env.get_avail_actions(), env.get_obs()
        assert state.shape == (info["state_shape"],)
        assert len(obs) == info["n_agents"] and obs[0].shape == (info["obs_shape"],)
        assert len(avail) == info["n_agents"] and len(avail[0]) == info["n_actions"]
        assert all(avail[i] == env.get_avail_agent_actions(i) for i in range(env.n_agents))
        picks = [rng.choice(np.flatnonzero(np.asarray(a))) for a in avail]
        actions = torch.tensor([picks], dtype=torch.long)  # [batch 1, n_agents]
        reward, terminated, step_info = env.step(actions[0])  # items are 0-d tensors
        assert isinstance(reward, float) and isinstance(terminated, bool)
        total += reward
        steps += 1
        # What the runner stores: an end is terminal unless the time limit caused it.
        bootstrap.append(terminated != step_info.get("episode_limit", False))
        if terminated:
            return {"steps": steps, "return": total, "info": step_info, "terminal": bootstrap}


def test_env_info_matches_what_the_environment_returns(make: Callable[..., SMACEnv]) -> None:
    env = make(action_space="discrete", n_blue=3, n_red=2)
    info = env.get_env_info()
    layout = env.layout
    assert info == {
        "state_shape": layout.state_dim, "obs_shape": layout.obs_dim,
        "n_actions": layout.n_actions, "n_agents": 3, "episode_limit": 40,
    }  # fmt: skip
    assert (env.n_agents, env.n_enemies, env.episode_limit) == (3, 2, 40)  # 5 steps each
    assert env.get_obs_size() == layout.obs_dim and env.get_total_actions() == layout.n_actions
    assert env.get_state_size() == layout.state_dim
    obs, state = env.reset()
    assert same(obs, env.get_obs()) and same(state, env.get_state())
    assert same(env.get_obs_agent(2), obs[2])


def test_a_runner_loop_with_torch_actions_learns_from_the_right_ends(
    make: Callable[..., SMACEnv],
) -> None:
    rng = np.random.default_rng(0)
    timed, wiped = make(seed=1), make(seed=1, episode_steps=3000, contexts=BLUE_LOSES)
    stats: dict[str, Any] = {}
    episodes = [run(timed, rng) for _ in range(3)] + [run(wiped, rng) for _ in range(2)]
    for ep in episodes:
        info = ep["info"]
        assert info.keys() == set(SCALAR_KEYS) and numeric(info)
        stats = {k: stats.get(k, 0) + info.get(k, 0) for k in set(stats) | set(info)}
        assert not any(ep["terminal"][:-1])
    for ep in episodes[:3]:  # time limit: bootstrap from the last state
        assert ep["steps"] == 10 and ep["info"]["episode_limit"] and not ep["terminal"][-1]
    for ep in episodes[3:]:  # wiped out: a real terminal state
        assert ep["steps"] < 150 and not ep["info"]["episode_limit"] and ep["terminal"][-1]
        assert ep["info"]["dead_allies"] == 2 and not ep["info"]["battle_won"]
    assert stats["episode_limit"] == 3
    for env, n in ((timed, 3), (wiped, 2)):
        got = env.get_stats()
        assert got["battles_game"] == n and got["restarts"] == 0
        assert got["timeouts"] == (n if env is timed else 0)
        assert got["win_rate"] == got["battles_won"] / n
    assert wiped.get_stats()["battles_won"] == 0


def test_the_reward_is_the_team_reward(make: Callable[..., SMACEnv]) -> None:
    env = make(seed=2)
    arena = Arena(seed=2, **SHORT)
    try:
        env.reset()
        arena.reset(None, None)
        for action in range(8):
            reward, terminated, _ = env.step([np.int64(action), torch.tensor(1)])
            _, rewards, done, info = arena.step([action, 1])
            assert reward == float(rewards[0]) == info["team_reward"][0]
            assert terminated == done
    finally:
        arena.close()


def test_actions_accept_anything_int_takes_and_refuse_the_rest(
    make: Callable[..., SMACEnv],
) -> None:
    env = make(seed=5)
    arena = Arena(seed=5, **SHORT)
    try:
        env.reset()
        arena.reset(None, None)
        # 0-d and one-element tensors, numpy ints and integral floats act as those ints do
        for loose, plain in (([torch.tensor(0), torch.tensor([1])], [0, 1]),
                             ([np.int32(2), 3.0], [2, 3])):  # fmt: skip
            reward, _, _ = env.step(loose)
            _, rewards, _, _ = arena.step(plain)
            assert reward == float(rewards[0])
            assert same(env.get_obs(), list(arena.get_obs()))
    finally:
        arena.close()
    with pytest.raises(InvalidActionError, match="agent 1: an action is an integer"):
        env.step([0, "left"])
    with pytest.raises(InvalidActionError, match="expected 2 actions"):
        env.step([0])
    with pytest.raises(InvalidActionError, match="agent 0: an action is an integer"):
        env.step([float("nan"), 0])
    with pytest.raises(InvalidActionError, match=r"a sequence of 2 .* got None"):
        env.step(None)  # type: ignore[arg-type]
    for bad in ({0: 3, 1: 5}, {3, 5}, "35"):  # its keys, no order, its characters
        with pytest.raises(InvalidActionError, match="a sequence of 2 per-agent actions"):
            env.step(bad)  # type: ignore[arg-type]
    for bad in (-1, 2, 1.0, True):
        with pytest.raises(IndexError, match=r"agent_id must be an integer in \[0, 1\]"):
            env.get_obs_agent(bad)  # type: ignore[arg-type]
        with pytest.raises(IndexError, match=r"agent_id must be an integer in \[0, 1\]"):
            env.get_avail_agent_actions(bad)  # type: ignore[arg-type]


def test_seeded_runs_repeat_and_unseeded_ones_differ(make: Callable[..., SMACEnv]) -> None:
    def episodes(env: SMACEnv) -> list[Any]:
        rng = np.random.default_rng(3)
        return [(run(env, rng), env.get_obs()) for _ in range(2)]

    assert same(episodes(make(seed=6)), episodes(make(seed=6)))
    assert make(seed=6).seed() == 6
    assert not same(make().reset(), make().reset())


def test_refuses_what_smac_does_not_have() -> None:
    with pytest.raises(InvalidOptionError, match=r"'abstract', 'discrete'"):
        SMACEnv(env=IN_PROCESS, action_space="continuous")
    with pytest.raises(InvalidOptionError, match="cooperative"):
        SMACEnv(env=IN_PROCESS, mode="competitive")
    with pytest.raises(InvalidOptionError, match="max_cycles"):
        SMACEnv(env=IN_PROCESS, max_cycles=3)


def test_render_save_replay_and_pickling(make: Callable[..., SMACEnv]) -> None:
    env = make(seed=4)
    env.reset()
    frame = env.render()
    assert frame is not None and frame.dtype == np.uint8 and frame.shape[2] == 3
    assert same(env.render("rgb_array"), frame)
    with pytest.raises(InvalidOptionError, match="render_mode='human'"):
        env.render("human")  # no window was asked for when the environment was built
    with pytest.raises(InvalidOptionError, match="'rgb_array', 'human'"):
        env.render("ansi")
    assert env.save_replay() is None
    copy = pickle.loads(pickle.dumps(env))
    try:
        assert same(copy.reset(), make(seed=4).reset())
    finally:
        copy.close()


@pytest.mark.slow
def test_default_arguments_play_over_a_private_server() -> None:
    env = SMACEnv(seed=9, **SHORT)
    local = SMACEnv(env=IN_PROCESS, seed=9, **SHORT)
    try:
        assert isinstance(env.arena, RM)
        assert same(run(env, np.random.default_rng(0)), run(local, np.random.default_rng(0)))
    finally:
        env.close()
        local.close()
