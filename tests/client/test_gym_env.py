"""The Gymnasium face: ``check_env``, spaces, masks, termination, registration, RM parity."""

from __future__ import annotations

import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from neuronsmae.client import RM, CoopEnv
from neuronsmae.client.gym_env import ENV_ID
from neuronsmae.client.spaces import Layout
from neuronsmae.protocol.errors import InvalidActionError, InvalidContextError, InvalidOptionError
from neuronsmae.server import Arena

from .conftest import Server, free_port, same

KINDS = ("abstract", "discrete", "continuous")
SHORT = {"episode_steps": 200}
"""Short episodes (4 s, 10 abstract decisions): the checkers run whole episodes."""
BLUE_LOSES = {"coef": 10.0, "opponent_hp": 10000.0}
"""Contexts under which red wipes blue out within a few decisions."""
RM_TIMEOUT = 60.0
"""A fresh server JIT-compiles on its first step; on a loaded machine that exceeds 10 s."""


def arena_factory(kind: str, **options: Any) -> Callable[[], Arena]:
    return lambda: Arena(seed=7, action_space=kind, **{**SHORT, **options})


@pytest.fixture
def make() -> Iterator[Callable[..., CoopEnv]]:
    """Build CoopEnvs over in-process arenas; all are closed when the test ends."""
    built: list[CoopEnv] = []

    def build(kind: str = "abstract", **kwargs: Any) -> CoopEnv:
        options = {k: kwargs.pop(k) for k in list(kwargs) if k not in ("render_mode", "contexts")}
        env = CoopEnv(env=arena_factory(kind, **options), **kwargs)
        built.append(env)
        return env

    yield build
    for env in built:
        env.close()


def run_episode(env: CoopEnv, seed: int, options: dict[str, Any] | None = None) -> list[Any]:
    """Random masked actions until the episode ends; returns every step's 5-tuple."""
    _, info = env.reset(seed=seed, options=options)
    env.action_space.seed(seed)
    steps = []
    while True:
        if isinstance(env.action_space, gymnasium.spaces.MultiDiscrete):
            action = env.action_space.sample(mask=tuple(info["action_mask"]))
        else:
            action = env.action_space.sample()
        step = env.step(action)
        steps.append(step)
        info = step[4]
        if step[2] or step[3]:
            return steps


# ---- the checkers ---------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_check_env_passes_without_warnings(kind: str) -> None:
    # Through gymnasium.make with a factory, so check_env also re-creates the environment for
    # each render mode and checks that closing twice is allowed.
    env = gymnasium.make(ENV_ID, env=arena_factory(kind), render_mode="rgb_array")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            check_env(env.unwrapped)
    finally:
        env.close()


# ---- spaces and actions ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kind", "n_actions"), [("abstract", 3 * 4), ("discrete", 3 * 5), ("continuous", 3)]
)
def test_spaces_follow_the_arena(make: Callable[..., CoopEnv], kind: str, n_actions: int) -> None:
    env = make(kind, n_blue=2, n_red=3)
    info = env.arena.get_env_info()
    assert env.observation_space == gymnasium.spaces.Box(-1, 1, (2, info["obs_shape"]), np.float32)
    obs, reset_info = env.reset(seed=0)
    assert obs.shape == (2, info["obs_shape"]) and obs.dtype == np.float32
    if kind == "continuous":
        assert isinstance(env.action_space, gymnasium.spaces.Box)
        assert env.action_space.shape == (2, 4)
        np.testing.assert_array_equal(env.action_space.high[:, 3], [3.0, 3.0])
        assert reset_info["target_mask"].shape == (2, n_actions)
        assert "action_mask" not in reset_info
    else:
        assert env.action_space == gymnasium.spaces.MultiDiscrete([n_actions, n_actions])
        assert reset_info["action_mask"].shape == (2, n_actions)
        assert reset_info["action_mask"].dtype == np.int8
        np.testing.assert_array_equal(
            env.action_masks(), reset_info["action_mask"].astype(bool).reshape(-1)
        )


def test_continuous_target_is_read_as_a_bin(make: Callable[..., CoopEnv]) -> None:
    layout = Layout.of(make("continuous", n_red=3).arena)
    cases = {0.0: 0, 0.999: 0, 1.0: 1, 2.5: 2, 3.0: 2}  # the upper edge is the last enemy
    for target, enemy in cases.items():
        assert layout.to_arena("blue_0", np.array([1, -1, 0.5, target])) == [1.0, -1.0, 0.5, enemy]
    for bad in (-0.01, 3.01, float("nan")):
        with pytest.raises(InvalidActionError, match="blue_0"):
            layout.to_arena("blue_0", [0, 0, 0, bad])


def test_bad_joint_actions_raise_with_the_expected_shape(make: Callable[..., CoopEnv]) -> None:
    env = make("discrete")
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match=r"shape \(2,\)"):
        env.step(np.zeros(3, dtype=np.int64))
    with pytest.raises(InvalidActionError):  # the arena's own bound check
        env.step(np.array([0, 99]))
    cont = make("continuous")
    cont.reset(seed=0)
    with pytest.raises(InvalidActionError, match="vx"):
        cont.step(np.array([[5.0, 0, 0, 0], [0, 0, 0, 0]], dtype=np.float32))


# ---- rewards, termination, truncation -------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_time_limit_truncates(make: Callable[..., CoopEnv], kind: str) -> None:
    env = make(kind)
    steps = run_episode(env, seed=3)
    *_, (_, reward, terminated, truncated, info) = steps
    assert truncated and not terminated
    assert info["t"] == 200 and info["winner"] is not None
    assert all(not (s[2] or s[3]) for s in steps[:-1])
    assert len(steps) == env.arena.get_env_info()["episode_limit"]
    # The team reward: every blue robot's reward, not their sum.
    assert reward == info["team_reward"][0]


def test_annihilation_terminates(make: Callable[..., CoopEnv]) -> None:
    env = make("abstract", episode_steps=3000)
    *_, (_, reward, terminated, truncated, info) = run_episode(
        env, seed=5, options={"contexts": BLUE_LOSES}
    )
    assert terminated and not truncated
    assert info["winner"] == "red" and not any(info["alive"][:2])
    assert info["t"] < 3000 and reward == info["team_reward"][0] < 0
    # A destroyed robot may only no-op.
    np.testing.assert_array_equal(info["action_mask"][:, 0], [1, 1])
    assert not info["action_mask"][:, 1:].any()


def test_contexts_merge_and_reach_the_arena(make: Callable[..., CoopEnv]) -> None:
    env = make("discrete", contexts={"coef": 10.0})
    env.reset(seed=0, options={"contexts": {"opponent_hp": 1.0}})
    *_, info = env.step(np.zeros(2, dtype=np.int64))
    assert max(info["hp"][2:]) <= 1.0  # per-episode key applied ...
    assert env.contexts == {"coef": 10.0}  # ... without replacing the constructor's
    with pytest.raises(InvalidContextError):
        env.reset(options={"contexts": {"no_such_key": 1}})


# ---- construction, rendering, registration --------------------------------------------------


def test_wraps_an_instance_and_owns_it() -> None:
    arena = Arena(seed=1, **SHORT)
    env = CoopEnv(env=arena, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame is not None and frame.dtype == np.uint8 and frame.ndim == 3
    assert frame.shape[2] == 3
    assert env.metadata["render_fps"] == 2.5  # 20 physics steps of 20 ms per decision
    env.close()
    env.close()
    assert arena.done  # closed with the environment


def test_refuses_other_modes_and_misplaced_options() -> None:
    arena = Arena(seed=1, mode="competitive", **SHORT)
    with pytest.raises(InvalidOptionError, match="cooperative"):
        CoopEnv(env=arena)
    arena.reset()  # a refused instance is left open for its owner
    arena.close()
    with pytest.raises(InvalidOptionError, match="no robot"):
        CoopEnv(env=lambda: Arena(seed=1, mode="bots"))
    with pytest.raises(TypeError, match="n_blue"):
        CoopEnv(env=arena_factory("abstract"), n_blue=3)
    with pytest.raises(ValueError, match="render_mode"):
        CoopEnv(env=arena_factory("abstract"), render_mode="human")


def test_client_faces_do_not_import_the_server() -> None:
    code = (
        "import sys, gymnasium, neuronsmae.client, neuronsmae.client.pz_env\n"
        f"assert {ENV_ID!r} in gymnasium.registry\n"
        "print(sorted(m for m in sys.modules if m.startswith('neuronsmae.server')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "[]"


def test_module_qualified_id_registers_on_make() -> None:
    env = gymnasium.make(f"neuronsmae.client:{ENV_ID}", env=arena_factory("discrete"))
    try:
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


# ---- over the remote client -----------------------------------------------------------------


@pytest.mark.slow
def test_check_env_over_rm_matches_in_process(start_server: Callable[..., Server]) -> None:
    server = start_server()
    options = {"action_space": "discrete", **SHORT}
    remote = CoopEnv(
        seed=7, port=server.port, launch=False, timeout=RM_TIMEOUT, render_mode="rgb_array",
        **options,
    )  # fmt: skip
    local = CoopEnv(env=Arena(seed=7, **options))
    try:
        assert isinstance(remote.arena, RM)
        # Built directly (no spec), so check_env cannot re-make it for other render modes.
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            warnings.filterwarnings("ignore", message=".*not having a spec")
            check_env(remote)
        assert same(run_episode(remote, seed=11), run_episode(local, seed=11))
    finally:
        remote.close()
        local.close()


@pytest.mark.slow
def test_registered_entry_point_launches_a_server() -> None:
    # The default entry point: no env, so an RM that launches (and then stops) its own server.
    env = gymnasium.make(ENV_ID, seed=3, port=free_port(), timeout=RM_TIMEOUT, **SHORT)
    try:
        assert isinstance(env.unwrapped.arena, RM)  # type: ignore[attr-defined]
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
        steps = run_episode(env.unwrapped, seed=0)  # type: ignore[arg-type]
        assert steps[-1][3] and not steps[-1][2]
    finally:
        env.close()
