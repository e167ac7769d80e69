"""The PettingZoo face: the parallel and AEC API and seed tests, the three constructors,
dead robots, mask forms, numeric infos, options, and parity over RM."""

from __future__ import annotations

import pickle
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
from pettingzoo.utils.conversions import parallel_to_aec

from neuronsmae.client import RM, ArenaParallelEnv, parallel_env
from neuronsmae.client.infos import ROBOT_KEYS, SCALAR_KEYS
from neuronsmae.client.pz_env import env as aec_env
from neuronsmae.client.pz_env import raw_env
from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidOptionError,
    NotCopyableError,
    ResetNeededError,
)
from neuronsmae.server import Arena

from .conftest import Server, numeric, same

KINDS = ("abstract", "discrete", "continuous")
MODES = ("cooperative", "competitive")
SHORT = {"episode_steps": 200}
"""Short episodes (4 s): the checkers run whole episodes."""
BLUE_LOSES = {"coef": 10.0, "opponent_hp": 10000.0}
"""Contexts under which red destroys blue robots one by one within a few decisions."""
RM_TIMEOUT = 60.0
"""A fresh server JIT-compiles on its first step; on a loaded machine that exceeds 10 s."""
FACE_ARGS = ("render_mode", "contexts", "masks", "remove_dead")
IN_PROCESS = "neuronsmae.server:Arena"


def factory(
    kind: str = "abstract", mode: str = "cooperative", **options: Any
) -> Callable[[], Arena]:
    return lambda: Arena(seed=7, action_space=kind, mode=mode, **{**SHORT, **options})


@pytest.fixture
def make() -> Iterator[Callable[..., ArenaParallelEnv]]:
    """Build parallel envs over in-process arenas; all are closed when the test ends."""
    built: list[ArenaParallelEnv] = []

    def build(kind: str = "abstract", mode: str = "cooperative", **kwargs: Any) -> ArenaParallelEnv:
        face = {k: kwargs.pop(k) for k in FACE_ARGS if k in kwargs}
        env = ArenaParallelEnv(env=factory(kind, mode, **kwargs), **face)
        built.append(env)
        return env

    yield build
    for env in built:
        env.close()


def mask_of(env: ArenaParallelEnv, obs: Any, info: dict[str, Any], agent: str) -> np.ndarray:
    key = env.layout.mask_key
    return info[key] if env.masks == "info" else obs[agent][key]


def sample(env: ArenaParallelEnv, obs: Any, infos: dict[str, Any], agent: str) -> Any:
    """A random action the agent's mask allows (continuous: any action, target masked)."""
    space = env.action_space(agent)
    mask = mask_of(env, obs, infos[agent], agent)
    if isinstance(space, spaces.Discrete):
        return space.sample(mask=mask)
    action = space.sample()
    action[3] = space.np_random.choice(np.flatnonzero(mask))
    return action


def play(env: ArenaParallelEnv, seed: int, **reset: Any) -> list[tuple[Any, ...]]:
    """One whole episode of masked random actions; every step's 5-tuple plus ``agents``."""
    obs, infos = env.reset(seed=seed, **reset)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(seed + i)
    steps = []
    while env.agents:
        step = env.step({a: sample(env, obs, infos, a) for a in env.agents})
        steps.append((*step, list(env.agents)))
        obs, infos = step[0], step[4]
    return steps


# ---- the checkers ---------------------------------------------------------------------------


@pytest.mark.slow
def test_api_and_seed_tests_pass_with_default_arguments() -> None:
    # Exactly as a user would: private unpaced servers, one per environment.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(parallel_env())
        parallel_seed_test(parallel_env)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("kind", KINDS)
def test_parallel_api_and_seed_tests_pass(kind: str, mode: str) -> None:
    env = ArenaParallelEnv(env=factory(kind, mode))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the API test reports its findings as warnings
        parallel_api_test(env, num_cycles=100)
        parallel_seed_test(lambda: ArenaParallelEnv(env=factory(kind, mode)), num_cycles=50)
    env.close()


@pytest.mark.parametrize("masks", ["rllib", "info"])
def test_every_mask_form_passes_the_api_and_seed_tests(masks: str) -> None:
    env = parallel_env(env=factory("discrete", "competitive"), masks=masks, remove_dead=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(env, num_cycles=100)
        parallel_seed_test(lambda: parallel_env(env=factory(), masks=masks), num_cycles=50)
    env.close()


@pytest.mark.parametrize("constructor", [aec_env, raw_env])
def test_aec_constructors_pass_the_api_test(constructor: Callable[..., Any]) -> None:
    env = constructor(env=factory("discrete", "competitive"))
    with warnings.catch_warnings():
        # Advisory notes every Dict-observation environment (PettingZoo classic) gets.
        warnings.filterwarnings("ignore", message="Observation (space|is not)")
        api_test(env, num_cycles=30)
    env.close()
    assert type(parallel_to_aec(ArenaParallelEnv(env=factory()))) is type(aec_env(env=factory()))


@pytest.mark.parametrize("kind", KINDS)
def test_whole_episodes_are_deterministic(make: Callable[..., ArenaParallelEnv], kind: str) -> None:
    # PettingZoo's seed test stops after one step; this compares whole competitive episodes.
    a, b = make(kind, "competitive"), make(kind, "competitive")
    assert same(play(a, seed=4), play(b, seed=4))


def test_first_unseeded_reset_draws_entropy_unless_a_seed_was_given() -> None:
    def first(**kwargs: Any) -> Any:
        env = parallel_env(env=IN_PROCESS, **SHORT, **kwargs)
        try:
            return env.reset()[0]
        finally:
            env.close()

    assert not same(first(), first())
    assert same(first(seed=5), first(seed=5))


# ---- agents, spaces, masks, infos -----------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_spaces_are_cached_per_agent(make: Callable[..., ArenaParallelEnv], kind: str) -> None:
    env = make(kind, "competitive", n_blue=3, n_red=3)
    assert env.possible_agents == ["blue_0", "blue_1", "blue_2", "red_0", "red_1", "red_2"]
    assert env.agents == []  # until reset
    key = "target_mask" if kind == "continuous" else "action_mask"
    obs, infos = env.reset(seed=0)
    assert env.agents == env.possible_agents and set(infos) == set(env.agents)
    for agent in env.possible_agents:
        space = env.observation_space(agent)
        assert space is env.observation_space(agent)
        assert env.action_space(agent) is env.action_space(agent)
        assert set(space.spaces) == {"observation", key} and space.contains(obs[agent])
    assert env.observation_space("blue_0") is not env.observation_space("red_0")
    assert env.state_space.contains(env.state())
    if kind == "continuous":
        space = env.action_space("red_2")
        assert isinstance(space, spaces.Box) and space.shape == (4,) and space.high[3] == 3.0


@pytest.mark.parametrize("masks", ["obs", "rllib", "info"])
def test_mask_forms(make: Callable[..., ArenaParallelEnv], masks: str) -> None:
    env = make("discrete", masks=masks)
    obs, infos = env.reset(seed=0)
    space = env.observation_space("blue_0")
    mask = np.asarray(env.arena.get_avail_actions()[0], dtype=np.int8)
    if masks == "info":
        assert isinstance(space, spaces.Box) and space.contains(obs["blue_0"])
        np.testing.assert_array_equal(infos["blue_0"]["action_mask"], mask)
    else:
        key = {"obs": "observation", "rllib": "observations"}[masks]
        assert set(space.spaces) == {key, "action_mask"} and space.contains(obs["blue_0"])
        np.testing.assert_array_equal(obs["blue_0"]["action_mask"], mask)
        assert "action_mask" not in infos["blue_0"]
    with pytest.raises(InvalidOptionError, match=r"masks='dict'.*'info', 'obs', 'rllib'"):
        parallel_env(env=factory(), masks="dict")


def test_infos_are_numeric_per_team_with_the_same_keys(
    make: Callable[..., ArenaParallelEnv],
) -> None:
    env = make("discrete", "competitive")
    _, first = env.reset(seed=1)
    keys = {*SCALAR_KEYS, *ROBOT_KEYS}
    assert all(info.keys() == keys and numeric(info) for info in first.values())
    assert first["blue_0"]["alive"] is not first["blue_1"]["alive"]  # no shared arrays
    steps = play(env, seed=1)
    for *_, infos, _ in steps:
        assert all(info.keys() == keys and numeric(info) for info in infos.values())
    last = steps[-1][4]
    winner = env.arena_info["winner"]
    assert last["blue_0"]["battle_won"] == (winner == "blue")
    assert last["red_0"]["battle_won"] == (winner == "red")
    assert last["blue_0"]["episode_limit"] and last["red_1"]["episode_limit"]
    assert last["blue_0"]["reward_damage"] == -last["red_0"]["reward_damage"]


def test_destroyed_robots_stay_until_the_episode_ends(
    make: Callable[..., ArenaParallelEnv],
) -> None:
    env = make("abstract", n_blue=3, n_red=3, episode_steps=3000, contexts=BLUE_LOSES)
    steps = play(env, seed=5)
    lone_deaths = 0
    for obs, rewards, term, trunc, infos, agents in steps[:-1]:
        assert agents == env.possible_agents and not any(term.values()) and not any(trunc.values())
        assert set(obs) == set(rewards) == set(env.possible_agents)
        dead = [a for a in obs if not infos[a]["alive"][int(a[-1])]]
        lone_deaths += bool(dead)
        for a in dead:  # a destroyed robot may only no-op, and shares its team's reward
            assert obs[a]["action_mask"].tolist() == [1] + [0] * 11
            assert rewards[a] == rewards["blue_0"]
    assert lone_deaths >= 1
    *_, (_, _, term, trunc, infos, agents) = steps
    assert agents == [] and all(term.values()) and not any(trunc.values())
    assert infos["blue_0"]["dead_allies"] == 3 and not infos["blue_0"]["battle_won"]


def test_remove_dead_takes_destroyed_robots_out_for_good(
    make: Callable[..., ArenaParallelEnv],
) -> None:
    env = make("abstract", n_blue=3, n_red=3, episode_steps=3000, contexts=BLUE_LOSES,
               remove_dead=True)  # fmt: skip
    steps = play(env, seed=5)
    gone: set[str] = set()
    lone_deaths = 0
    for obs, rewards, term, trunc, infos, agents in steps:
        live_before = set(obs)
        assert not live_before & gone, "an agent came back"
        assert set(rewards) == set(term) == set(trunc) == set(infos) == live_before
        dead_now = {a for a in live_before if not infos[a]["alive"][int(a[-1])]}
        assert {a for a in live_before if term[a]} >= dead_now
        assert not any(trunc.values())
        if dead_now and agents:
            lone_deaths += 1  # destroyed while its team fights on
            assert set(agents) == live_before - dead_now
            assert all(obs[a]["action_mask"].tolist() == [1] + [0] * 11 for a in dead_now)
        gone |= {a for a in live_before if term[a] or trunc[a]}
    assert lone_deaths >= 1
    assert gone == set(env.possible_agents)
    assert env.arena_info["winner"] == "red"


def test_time_limit_truncates_every_agent(make: Callable[..., ArenaParallelEnv]) -> None:
    env = make("discrete", "competitive")
    steps = play(env, seed=1)
    *_, (_, rewards, term, trunc, infos, agents) = steps
    assert agents == [] and all(trunc.values()) and not any(term.values())
    assert next(iter(infos.values()))["t"] == 200
    team = env.arena_info["team_reward"]
    assert rewards == {a: team[0] if a.startswith("blue") else team[1] for a in rewards}


def test_a_step_after_the_end_is_empty_and_one_before_the_start_is_refused(
    make: Callable[..., ArenaParallelEnv],
) -> None:
    env = make("discrete")
    with pytest.raises(ResetNeededError):
        env.step({})
    play(env, seed=2)
    assert env.agents == [] and env.step({}) == ({}, {}, {}, {}, {})
    assert env.reset(seed=2)[0].keys() == set(env.possible_agents)


@pytest.mark.parametrize("actions", [None, [0, 0], 3])
def test_actions_that_are_no_dict_are_refused_by_name(actions: Any) -> None:
    """None was a TypeError ("argument of type 'NoneType' is not iterable")."""
    env = parallel_env(env=IN_PROCESS, seed=3, **SHORT)
    try:
        env.reset()
        with pytest.raises(InvalidActionError, match="actions must be a dict of agent name"):
            env.step(actions)
    finally:
        env.close()


def test_pickles_as_its_recipe() -> None:
    env = parallel_env(env=IN_PROCESS, seed=3, masks="info", **SHORT)
    copy = pickle.loads(pickle.dumps(env))
    try:
        assert copy.arena is not env.arena and copy.masks == "info"
        assert same(env.reset(), copy.reset())  # the constructor's seed decides both
    finally:
        env.close()
        copy.close()
    held = parallel_env(env=Arena(seed=3, **SHORT))
    try:
        with pytest.raises(NotCopyableError, match=r"env=<Arena object>.*'module:attr'"):
            pickle.dumps(held)
    finally:
        held.close()


def test_actions_needed_for_live_agents_only(make: Callable[..., ArenaParallelEnv]) -> None:
    env = make("continuous", n_blue=2)
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match="blue_1"):
        env.step({"blue_0": np.zeros(4, dtype=np.float32)})
    zero = np.zeros(4, dtype=np.float32)
    # A name that is no agent (a typo, or red in cooperative mode) was dropped silently.
    for extra in ("red_0", "blue_00"):
        with pytest.raises(InvalidActionError, match=rf"'{extra}'.*live agents are \['blue_0'"):
            env.step({"blue_0": zero, "blue_1": zero, extra: zero})
    obs, *_ = env.step({"blue_0": zero, "blue_1": zero})
    assert set(obs) == {"blue_0", "blue_1"}


def test_render_and_reset_contexts(make: Callable[..., ArenaParallelEnv]) -> None:
    env = make("discrete", render_mode="rgb_array")
    env.reset(seed=0, options={"contexts": {"opponent_hp": 1.0}})
    frame = env.render()
    assert frame is not None and frame.dtype == np.uint8 and frame.shape[2] == 3
    assert env.metadata["render_fps"] == 10.0  # discrete: 5 physics steps per decision
    env.step(dict.fromkeys(env.agents, 0))
    assert max(env.arena_info["hp"][2:]) <= 1.0
    with pytest.warns(UserWarning, match="without a render_mode"):
        assert make("discrete").render() is None


@pytest.mark.usefixtures("no_launch")
def test_options_are_checked_before_anything_starts() -> None:
    with pytest.raises(InvalidOptionError, match="mode"):
        parallel_env(env=factory(), mode="competitive")
    with pytest.raises(InvalidOptionError, match=r"\['max_cycles'\].*episode_steps"):
        parallel_env(max_cycles=25)
    with pytest.raises(InvalidOptionError, match="max_cycles"):
        aec_env(max_cycles=25)


# ---- over the remote client -----------------------------------------------------------------


@pytest.mark.slow
def test_api_and_seed_tests_over_rm(start_server: Callable[..., Server]) -> None:
    ports = [start_server().port for _ in range(2)]
    options = {"action_space": "continuous", "mode": "competitive", **SHORT}

    def remote(port: int) -> ArenaParallelEnv:
        return ArenaParallelEnv(seed=7, port=port, launch=False, timeout=RM_TIMEOUT, **options)

    env = remote(ports[0])
    try:
        assert isinstance(env.arena, RM)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            parallel_api_test(env, num_cycles=100)
        local = ArenaParallelEnv(env=Arena(seed=7, **options))
        try:
            assert same(play(env, seed=2), play(local, seed=2))
        finally:
            local.close()
    finally:
        env.close()
    # The seed test holds two environments at once: one server each.
    pending = iter(ports)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_seed_test(lambda: remote(next(pending)), num_cycles=50)
