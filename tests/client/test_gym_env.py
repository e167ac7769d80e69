"""The Gymnasium face: ``check_env``, spaces, masks, infos, termination, seeding, options,
rendering, registration, and parity over RM."""

from __future__ import annotations

import re
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
from neuronsmae.client import source as source_module
from neuronsmae.client.gym_env import ENV_ID
from neuronsmae.client.infos import ROBOT_KEYS, SCALAR_KEYS
from neuronsmae.client.spaces import Layout
from neuronsmae.client.viewer import display_problem
from neuronsmae.protocol.errors import InvalidActionError, InvalidContextError, InvalidOptionError
from neuronsmae.server import Arena
from neuronsmae.server.config import ArenaConfig

from .conftest import Server, free_port, numeric, same

KINDS = ("abstract", "discrete", "continuous")
SHORT = {"episode_steps": 200}
"""Short episodes (4 s, 10 abstract decisions): the checkers run whole episodes."""
BLUE_LOSES = {"coef": 10.0, "opponent_hp": 10000.0}
"""Contexts under which red wipes blue out within a few decisions."""
RM_TIMEOUT = 60.0
"""A fresh server JIT-compiles on its first step; on a loaded machine that exceeds 10 s."""
IN_PROCESS = "neuronsmae.server:Arena"
WRAPPED = ".*is different from the unwrapped"
"""check_env's advice to check ``env.unwrapped`` when given what ``make`` returns."""


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


def run_episode(env: Any, seed: int | None, options: dict[str, Any] | None = None) -> list[Any]:
    """Random masked actions until the episode ends; returns every step's 5-tuple."""
    _, info = env.reset(seed=seed, options=options)
    env.action_space.seed(0 if seed is None else seed)
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


@pytest.mark.slow
def test_check_env_passes_with_default_arguments() -> None:
    # Exactly as a user would: a private unpaced server behind the registered id.
    env = gymnasium.make("NeuronsMAE/Coop-v0")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            warnings.filterwarnings("ignore", message=WRAPPED)
            check_env(env)
    finally:
        env.close()


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


@pytest.mark.slow
def test_default_instances_run_side_by_side() -> None:
    envs = [gymnasium.make(ENV_ID) for _ in range(2)]
    try:
        ports = {env.unwrapped.arena.port for env in envs}  # type: ignore[attr-defined]
        assert len(ports) == 2
        # Unseeded: each first episode seeded from entropy, so the two differ.
        first = [env.reset()[0] for env in envs]
        assert not np.array_equal(first[0], first[1])
        for env in envs:
            env.step(env.action_space.sample())
    finally:
        for env in envs:
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
    rows = layout.joint_to_arena(np.array([[[1, -1, 0.5, t] for t in cases]]))
    np.testing.assert_array_equal(rows[0, :, 3], list(cases.values()))
    for bad in (-0.01, 3.01, float("nan")):
        with pytest.raises(InvalidActionError, match="blue_0"):
            layout.to_arena("blue_0", [0, 0, 0, bad])
        with pytest.raises(InvalidActionError, match=r"target|finite"):
            layout.joint_to_arena(np.array([[[0, 0, 0, bad]]]))


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
    with pytest.raises(InvalidActionError, match="4 finite numbers"):  # NumPy read "1" as 1.0
        cont.step(np.array([["1", "0", "0", "0"], ["0", "1", "0", "1"]]))


# ---- infos, rewards, termination, truncation ------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_time_limit_truncates(make: Callable[..., CoopEnv], kind: str) -> None:
    env = make(kind)
    steps = run_episode(env, seed=3)
    *_, (_, reward, terminated, truncated, info) = steps
    assert truncated and not terminated
    assert info["t"] == 200 and info["episode_limit"]
    assert env.arena_info["winner"] is not None
    assert all(not (s[2] or s[3]) for s in steps[:-1])
    assert not any(s[4]["episode_limit"] for s in steps[:-1])
    assert len(steps) == env.arena.get_env_info()["episode_limit"]
    # The team reward: every blue robot's reward, not their sum.
    assert reward == env.arena_info["team_reward"][0]
    assert info["battle_won"] == (env.arena_info["winner"] == "blue")


def test_annihilation_terminates(make: Callable[..., CoopEnv]) -> None:
    env = make("abstract", episode_steps=3000)
    *_, (_, reward, terminated, truncated, info) = run_episode(
        env, seed=5, options={"contexts": BLUE_LOSES}
    )
    assert terminated and not truncated
    assert not info["battle_won"] and not info["episode_limit"]
    assert info["dead_allies"] == 2 and not info["alive"][:2].any()
    assert env.arena_info["winner"] == "red"
    assert info["t"] < 3000 and reward == env.arena_info["team_reward"][0] < 0
    np.testing.assert_array_equal(info["hp_fraction"][:2], [0.0, 0.0])
    # A destroyed robot may only no-op.
    np.testing.assert_array_equal(info["action_mask"][:, 0], [1, 1])
    assert not info["action_mask"][:, 1:].any()


def test_infos_are_numeric_with_the_same_keys_after_reset_and_step(
    make: Callable[..., CoopEnv],
) -> None:
    env = make("abstract", zones=True)
    _, first = env.reset(seed=2)
    assert set(first) == {*SCALAR_KEYS, *ROBOT_KEYS, "action_mask"} and numeric(first)
    assert first["t"] == 0 and not first["battle_won"] and first["alive"].all()
    np.testing.assert_array_equal(first["hp_fraction"], np.ones(4, np.float32))
    # Over what a robot can hold: its 370, and with zones a 20 s episode's one bonus of 100.
    np.testing.assert_allclose(first["bullets_fraction"], np.full(4, 370 / 470), rtol=1e-6)
    steps = run_episode(env, seed=2)
    for *_, info in steps:
        assert info.keys() == first.keys() and numeric(info)
        for key in first:
            assert np.shape(info[key]) == np.shape(first[key])
            assert np.asarray(info[key]).dtype == np.asarray(first[key]).dtype, key
    # What the numeric info leaves out stays in arena_info (zones: a dict and a log).
    assert {"winner", "components", "zones", "zone_log"} <= env.arena_info.keys()
    raw, info = env.arena_info, steps[-1][4]
    assert info["reward_damage"] + info["reward_kill"] + info["reward_win"] == pytest.approx(
        steps[-1][1]
    )
    np.testing.assert_array_equal(info["kills"], raw["kills"])
    np.testing.assert_allclose(info["hp_fraction"][:2], np.asarray(raw["hp"][:2]) / 600, atol=1e-6)
    env.reset(seed=2)
    assert env.arena_info == {}


def test_contexts_merge_and_reach_the_arena(make: Callable[..., CoopEnv]) -> None:
    env = make("discrete", contexts={"coef": 10.0})
    env.reset(seed=0, options={"contexts": {"opponent_hp": 1.0}})
    env.step(np.zeros(2, dtype=np.int64))
    assert max(env.arena_info["hp"][2:]) <= 1.0  # per-episode key applied ...
    assert env.contexts == {"coef": 10.0}  # ... without replacing the constructor's
    with pytest.raises(InvalidContextError):
        env.reset(options={"contexts": {"no_such_key": 1}})


# ---- seeding and the spec -------------------------------------------------------------------


def test_first_unseeded_reset_draws_entropy_unless_a_seed_was_given() -> None:
    def first_obs(**kwargs: Any) -> np.ndarray:
        env = CoopEnv(env=IN_PROCESS, **SHORT, **kwargs)
        try:
            return env.reset()[0]
        finally:
            env.close()

    assert not np.array_equal(first_obs(), first_obs())  # Gymnasium's entropy seeding
    assert np.array_equal(first_obs(seed=3), first_obs(seed=3))  # the constructor's seed wins
    np.testing.assert_array_equal(first_obs(seed=3), np.stack(Arena(seed=3, **SHORT).reset()))
    # An arena the caller built keeps its own seed.
    a, b = CoopEnv(env=Arena(seed=4, **SHORT)), CoopEnv(env=Arena(seed=4, **SHORT))
    try:
        assert np.array_equal(a.reset()[0], b.reset()[0])
    finally:
        a.close()
        b.close()


def test_make_fills_max_episode_steps_from_the_arena() -> None:
    for options, limit in ((SHORT, 10), ({"action_space": "discrete"}, 200)):
        env = gymnasium.make(ENV_ID, env=IN_PROCESS, **options)
        try:
            assert env.spec is not None and env.spec.max_episode_steps == limit
            assert env.unwrapped.spec.max_episode_steps == limit  # type: ignore[union-attr]
        finally:
            env.close()
    assert CoopEnv(env=IN_PROCESS).spec is None  # built directly, as Gymnasium's


# ---- options, construction, rendering -------------------------------------------------------


def test_client_knows_every_arena_option() -> None:
    import dataclasses

    assert {f.name for f in dataclasses.fields(ArenaConfig)} == source_module.ARENA_OPTIONS


@pytest.mark.usefixtures("no_launch")
def test_unknown_options_are_refused_before_anything_starts() -> None:
    with pytest.raises(InvalidOptionError, match=r"max_cycles.*episode_steps"):
        CoopEnv(max_cycles=25)
    with pytest.raises(InvalidOptionError, match=r"\['colour'\].*valid options.*n_blue"):
        gymnasium.make(ENV_ID, colour="red")
    with pytest.raises(InvalidOptionError, match="port"):  # RM's arguments only when served
        CoopEnv(env=IN_PROCESS, port=10000)
    with pytest.raises(InvalidOptionError, match="module:attr"):
        CoopEnv(env="neuronsmae.server.Arena")
    with pytest.raises(InvalidOptionError, match="importable"):
        CoopEnv(env="neuronsmae.server:NoSuchArena")
    with pytest.raises(InvalidOptionError, match="render_mode"):
        CoopEnv(render_mode="ascii")


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
    with pytest.raises(InvalidOptionError, match="n_blue"):
        CoopEnv(env=arena_factory("abstract"), n_blue=3)
    with pytest.raises(InvalidOptionError, match="seed"):
        CoopEnv(env=arena_factory("abstract"), seed=3)


@pytest.mark.usefixtures("no_launch")
def test_human_rendering_says_clearly_when_there_is_no_display(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(InvalidOptionError, match=r"no display.*rgb_array"):
        gymnasium.make(ENV_ID, render_mode="human")
    # The metadata then offers what works here, so check_env does not ask for a window.
    env = CoopEnv(env=IN_PROCESS, **SHORT)
    try:
        assert env.metadata["render_modes"] == ["rgb_array"]
        assert "human" in CoopEnv.metadata["render_modes"]  # make passes "human" through
    finally:
        env.close()


@pytest.mark.skipif(display_problem() is not None, reason="needs a display (e.g. xvfb-run)")
def test_human_rendering_opens_a_window_where_there_is_a_display() -> None:
    env = gymnasium.make(ENV_ID, env=IN_PROCESS, render_mode="human", **SHORT)
    try:
        env.reset(seed=0)
        window = env.unwrapped._renderer.window  # type: ignore[attr-defined]
        assert window.is_open and env.render() is None
        env.step(env.action_space.sample())
    finally:
        env.close()
    assert not window.is_open


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
    code = (
        "import gymnasium\n"
        f"env = gymnasium.make('neuronsmae.client:{ENV_ID}', env={IN_PROCESS!r})\n"
        "obs, _ = env.reset(seed=0)\n"
        "assert env.observation_space.contains(obs)\n"
        "env.close()\n"
        "print('ok')\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "ok"


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
        # Unseeded episodes go on from the constructor's seed, on both sides alike.
        assert same(run_episode(remote, seed=None), run_episode(local, seed=None))
    finally:
        remote.close()
        local.close()


@pytest.mark.slow
def test_every_face_refuses_a_bad_reset_seed_as_the_arena_does(
    start_server: Callable[..., Server],
) -> None:
    """Served, ``reset(seed=2**63)`` was the server's MalformedMessageError and
    ``seed=2**64 + 5`` "cannot encode message: Integer value out of range"; in process it
    was InvalidContextError naming seed and its range. The Gymnasium faces raised
    Gymnasium's own ``Error`` for -1 and 1.5 (the PettingZoo face InvalidContextError). Now
    every face, served or not, raises the arena's error, before anything is sent."""
    from neuronsmae.client.agents_env import AgentsEnv
    from neuronsmae.client.pz_env import ArenaParallelEnv

    port = start_server().port
    for face in (CoopEnv, AgentsEnv, ArenaParallelEnv):
        for seed in (2**63, 2**64 + 5, -1, 1.5, True, np.int64(-3)):
            said = []
            for where in (
                {"port": port, "launch": False, "timeout": RM_TIMEOUT},
                {"env": IN_PROCESS},
            ):
                env = face(seed=1, **where, **SHORT)
                try:
                    with pytest.raises(Exception) as caught:
                        env.reset(seed=seed)
                    said.append((type(caught.value), str(caught.value)))
                    env.reset(seed=np.int64(2**63 - 1))  # the largest seed, a NumPy integer
                finally:
                    env.close()
            assert said[0] == said[1], (face.__name__, seed)
            assert said[0][0] is InvalidContextError, (face.__name__, seed, said[0])
            assert "seed" in said[0][1] and "[0, 9223372036854775807]" in said[0][1]


@pytest.mark.slow
def test_an_explicit_port_launches_a_server_there() -> None:
    port = free_port()
    env = gymnasium.make(ENV_ID, seed=3, port=port, timeout=RM_TIMEOUT, **SHORT)
    try:
        arena = env.unwrapped.arena  # type: ignore[attr-defined]
        assert isinstance(arena, RM) and arena.port == port
        steps = run_episode(env.unwrapped, seed=0)
        assert steps[-1][3] and not steps[-1][2]
    finally:
        env.close()


@pytest.mark.parametrize(
    ("options", "said"),
    [
        ([1], "reset options must be a dict (read: ['contexts']), got [1]"),
        ({"contexts": 3}, "options['contexts'] must be a dict of context names to values"),
    ],
)
def test_bad_reset_options_are_refused_by_every_face(options: Any, said: str) -> None:
    """A list was an AttributeError and a non-dict contexts a TypeError. Other keys stay
    ignored: PettingZoo's API test passes one of its own."""
    from neuronsmae.client.agents_env import AgentsEnv
    from neuronsmae.client.pz_env import ArenaParallelEnv
    from neuronsmae.client.vec_env import CoopVectorEnv
    from neuronsmae.server.vec import VecArena

    faces = [CoopEnv(env=Arena(seed=4, **SHORT)), AgentsEnv(env=Arena(seed=4, **SHORT)),
             ArenaParallelEnv(env=Arena(seed=4, **SHORT)),
             CoopVectorEnv(num_envs=2, env=VecArena(seed=4, num_envs=2, **SHORT))]  # fmt: skip
    try:
        for face in faces:
            with pytest.raises(InvalidOptionError) as exc:
                face.reset(seed=1, options=options)
            assert said in str(exc.value), type(face).__name__
            face.reset(seed=1, options={"contexts": {"coef": 1.2}})
    finally:
        for face in faces:
            face.close()


@pytest.mark.parametrize(
    ("kwargs", "said"),
    [
        ({"env": "neuronsmae.server:Arena", "contexts": 3}, "contexts must be a dict of context"),
        ({"env": 3}, "env must be an ArenaAPI, a zero-argument factory of one, a 'module:attr'"),
    ],
)
def test_a_bad_env_or_contexts_argument_is_refused_by_every_face(
    kwargs: dict[str, Any], said: str
) -> None:
    """``contexts=3`` was a TypeError and ``env=3`` "'int' object is not callable"."""
    from neuronsmae.client.agents_env import AgentsEnv
    from neuronsmae.client.pz_env import ArenaParallelEnv
    from neuronsmae.client.smac import SMACEnv
    from neuronsmae.client.vec_env import CoopVectorEnv

    for face in (CoopEnv, AgentsEnv, ArenaParallelEnv, SMACEnv):
        with pytest.raises(InvalidOptionError, match=re.escape(said)):
            face(**kwargs)
    vec_said = said.replace("ArenaAPI", "VecArenaAPI")
    vec_kwargs = {**kwargs, "env": "neuronsmae.server:VecArena"} if "contexts" in kwargs else kwargs
    with pytest.raises(InvalidOptionError, match=re.escape(vec_said)):
        CoopVectorEnv(num_envs=2, **vec_kwargs)
