"""The Gymnasium vector face: ``make_vec`` with default arguments, next-step autoreset,
vector infos, and environment ``i`` playing exactly like a single ``CoopEnv`` seeded
``seed + i``."""

from __future__ import annotations

import copy
import gc
import pickle
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from neuronsmae.client import CoopEnv, CoopVectorEnv
from neuronsmae.client.gym_env import ENV_ID
from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    NotCopyableError,
)
from neuronsmae.server import VecArena

SHORT = {"episode_steps": 200}
"""10 abstract decisions an episode, so a few dozen steps pass several autoresets."""


def lockstep(vec: Any, singles: list[Any], seed: int, steps: int) -> int:
    """Step ``vec`` and ``singles`` with the same actions, resetting a single where the
    vector autoresets it; assert every result agrees; return how many autoresets were seen."""
    obs, infos = vec.reset(seed=seed)
    ended = [False] * len(singles)
    for i, env in enumerate(singles):
        one, info = env.reset(seed=seed + i)
        np.testing.assert_array_equal(obs[i], one)
        agree(infos, i, info)
    space = vec.unwrapped.single_action_space
    space.seed(seed)
    autoresets = 0
    for _ in range(steps):
        actions = np.stack([space.sample() for _ in singles])
        obs, rewards, terminated, truncated, infos = vec.step(actions)
        for i, env in enumerate(singles):
            if ended[i]:  # the vector reset it this step: so does the single one
                one, info = env.reset()
                assert rewards[i] == 0 and not terminated[i] and not truncated[i]
                assert infos["t"][i] == 0
                autoresets += 1
                ended[i] = False
            else:
                one, reward, term, trunc, info = env.step(actions[i])
                assert (rewards[i], terminated[i], truncated[i]) == (reward, term, trunc)
                ended[i] = term or trunc
            np.testing.assert_array_equal(obs[i], one)
            agree(infos, i, info)
    return autoresets


def agree(infos: dict[str, Any], i: int, info: dict[str, Any]) -> None:
    """Row ``i`` of vector infos equals a single environment's info, key by key."""
    assert {k for k in infos if not k.startswith("_")} == info.keys()
    for key, value in info.items():
        assert infos["_" + key][i]
        np.testing.assert_array_equal(infos[key][i], value, err_msg=key)


@pytest.mark.slow
def test_make_vec_with_default_arguments_matches_single_environments() -> None:
    # Exactly as a user would: one private vector server of three arenas.
    vec = gymnasium.make_vec("NeuronsMAE/Coop-v0", num_envs=3)
    singles = [gymnasium.make("NeuronsMAE/Coop-v0") for _ in range(3)]
    try:
        assert isinstance(vec, CoopVectorEnv) and len(vec.vec.ports) == 1
        assert vec.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
        assert vec.spec is not None and vec.spec.max_episode_steps == 50
        assert lockstep(vec, singles, seed=21, steps=60) >= 3  # each passed an autoreset
    finally:
        vec.close()
        for env in singles:
            env.close()


def test_in_process_vector_matches_single_environments() -> None:
    vec = CoopVectorEnv(3, env="neuronsmae.server:VecArena", **SHORT)
    singles = [CoopEnv(env="neuronsmae.server:Arena", **SHORT) for _ in range(3)]
    try:
        assert lockstep(vec, singles, seed=5, steps=35) >= 6
    finally:
        vec.close()
        for env in singles:
            env.close()


def test_continuous_actions_and_competitive_refusal() -> None:
    vec = CoopVectorEnv(2, env="neuronsmae.server:VecArena", action_space="continuous", **SHORT)
    singles = [CoopEnv(env="neuronsmae.server:Arena", action_space="continuous", **SHORT)
               for _ in range(2)]  # fmt: skip
    try:
        assert vec.action_space.shape == (2, 2, 4)
        assert lockstep(vec, singles, seed=8, steps=12) == 2
        with pytest.raises(InvalidActionError, match="target"):
            vec.step(np.full((2, 2, 4), 9.0))
    finally:
        vec.close()
        for env in singles:
            env.close()
    with pytest.raises(InvalidOptionError, match="cooperative"):
        CoopVectorEnv(2, env="neuronsmae.server:VecArena", mode="competitive")


def test_seeding_entropy_and_constructor_seed() -> None:
    def first(**kwargs: Any) -> np.ndarray:
        vec = CoopVectorEnv(2, env="neuronsmae.server:VecArena", **SHORT, **kwargs)
        try:
            return vec.reset()[0]
        finally:
            vec.close()

    assert not np.array_equal(first(), first())
    same = first(seed=4)
    np.testing.assert_array_equal(same, first(seed=4))
    assert not np.array_equal(same[0], same[1])  # arena i is seeded seed + i


def test_arguments_are_checked() -> None:
    arenas = VecArena(seed=0, num_envs=2, **SHORT)
    with pytest.raises(InvalidOptionError, match="holds 2"):
        CoopVectorEnv(3, env=arenas)
    arenas = VecArena(seed=0, num_envs=2, **SHORT)
    vec = CoopVectorEnv(2, env=arenas)
    try:
        vec.reset(seed=0)
        with pytest.raises(InvalidActionError, match=r"shape \(2, 2\)"):
            vec.step(np.zeros((3, 2), dtype=np.int64))
        with pytest.raises(InvalidOptionError, match="reset_mask"):
            vec.reset(options={"reset_mask": np.array([True, False])})
        with pytest.raises(InvalidContextError, match="seed -5 is out of range"):
            vec.reset(seed=-5)
    finally:
        vec.close()
    with pytest.raises(InvalidOptionError, match="render"):
        CoopVectorEnv(2, env="neuronsmae.server:VecArena", render_mode="rgb_array")
    with pytest.raises(InvalidOptionError, match="max_cycles"):
        gymnasium.make_vec(ENV_ID, num_envs=2, max_cycles=3)


def _copies_play_alike(vec: CoopVectorEnv, copies: list[CoopVectorEnv]) -> None:
    """Each copy is a new environment from the same arguments: its own arenas, the same
    episodes for the same seed and actions (and the original keeps working)."""
    gc.collect()  # the faces built while unpickling are gone: they must not close the copies'
    obs = vec.reset(seed=9)[0]
    zeros = np.zeros(vec.action_space.shape, dtype=np.int64)
    stepped = vec.step(zeros)
    for other in copies:
        assert other.vec is not vec.vec and not other.closed
        np.testing.assert_array_equal(other.reset(seed=9)[0], obs)
        got = other.step(zeros)
        for mine, theirs in zip(stepped[:4], got[:4], strict=True):
            np.testing.assert_array_equal(mine, theirs)


def test_the_vector_face_pickles_and_deepcopies_as_its_recipe() -> None:
    """It was ``TypeError: cannot pickle '_io.BufferedRandom'`` (its servers' log files),
    while the one-arena faces pickle as their recipe."""
    vec = CoopVectorEnv(2, env="neuronsmae.server:VecArena", seed=3, **SHORT)
    copies = [pickle.loads(pickle.dumps(vec)), copy.deepcopy(vec)]
    try:
        assert all(c.num_envs == 2 and c.layout.info == vec.layout.info for c in copies)
        _copies_play_alike(vec, copies)
    finally:
        for env in (vec, *copies):
            env.close()
    held = CoopVectorEnv(2, env=VecArena(seed=0, num_envs=2, **SHORT))
    try:
        for how in (pickle.dumps, copy.deepcopy):
            with pytest.raises(
                NotCopyableError, match=r"env=<VecArena object>.*'neuronsmae.server:VecArena'"
            ):
                how(held)
        assert isinstance(NotCopyableError("x"), TypeError)
    finally:
        held.close()


@pytest.mark.slow
def test_a_served_vector_face_copy_launches_its_own_server() -> None:
    vec = CoopVectorEnv(2, seed=3, **SHORT)  # a private vector server
    clone = pickle.loads(pickle.dumps(vec))
    try:
        assert clone.vec.ports != vec.vec.ports
        servers = [vec.vec._conns[0].server, clone.vec._conns[0].server]
        _copies_play_alike(vec, [clone])
    finally:
        clone.close()
    assert servers[1].proc.poll() is not None and servers[0].proc.poll() is None
    try:
        vec.reset(seed=1)  # closing the copy left the original's server alone
    finally:
        vec.close()
    assert servers[0].proc.poll() is not None
