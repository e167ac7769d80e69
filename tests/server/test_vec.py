"""VecArena: K in-process arenas against K plain arenas, autoreset, atomic refusals."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from neuronsmae.protocol.errors import (
    ClosedError,
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    ResetNeededError,
)
from neuronsmae.server import Arena, VecArena

CONTEXTS = {"level": "easy", "coef": 0.8}


def random_actions(avail: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One random available action per agent of every arena: ``[K, n_agents]``."""
    return (avail * rng.random(avail.shape)).argmax(-1)


class Replica:
    """K plain arenas driven by hand the way a VecArena drives its own (next-step autoreset)."""

    def __init__(self, seed: int, k: int, **options: Any) -> None:
        self.arenas = [Arena(seed=seed + i, **options) for i in range(k)]
        self.done = [False] * k
        self.contexts: list[Any] = [None] * k

    def reset(self, contexts: list[Any], seeds: list[Any]) -> np.ndarray:
        self.contexts = list(contexts)
        self.done = [False] * len(self.arenas)
        pairs = zip(self.arenas, contexts, seeds, strict=True)
        return np.stack([np.stack(a.reset(c, s)) for a, c, s in pairs])

    def step(self, actions: np.ndarray, seeds: list[Any], contexts: list[Any]) -> tuple:
        obs, rewards, dones, infos = [], [], [], []
        for i, arena in enumerate(self.arenas):
            if self.done[i]:
                self.contexts[i] = contexts[i] or self.contexts[i]
                obs.append(np.stack(arena.reset(self.contexts[i], seeds[i])))
                rewards.append([0.0] * len(actions[i]))
                dones.append(False)
                infos.append({})
                self.done[i] = False
            else:
                o, r, d, info = arena.step(list(actions[i]))
                obs.append(np.stack(o))
                rewards.append(r)
                dones.append(d)
                infos.append(info)
                self.done[i] = d
        return np.stack(obs), np.array(rewards), np.array(dones), infos

    def close(self) -> None:
        for arena in self.arenas:
            arena.close()


def same_step(a: tuple, b: tuple) -> bool:
    obs, rewards, dones, infos = a
    return (
        obs.dtype == b[0].dtype
        and obs.tobytes() == b[0].tobytes()
        and rewards.tobytes() == np.asarray(b[1], np.float64).tobytes()
        and dones.tolist() == list(b[2])
        and infos == b[3]
    )


@pytest.mark.parametrize(
    "options", [{}, {"action_space": "discrete", "n_blue": 3, "n_red": 2, "episode_steps": 300}]
)
def test_each_arena_plays_like_a_plain_arena_through_autoresets(options: dict[str, Any]) -> None:
    k, rng = 3, np.random.default_rng(0)
    vec, replica = VecArena(seed=40, num_envs=k, **options), Replica(40, k, **options)
    try:
        per_arena = [CONTEXTS, None, {"level": "hard"}]
        seeds = [None, 7, None]
        assert vec.reset(per_arena, seeds).tobytes() == replica.reset(per_arena, seeds).tobytes()
        resets = np.zeros(k, dtype=int)
        for t in range(140):
            actions = random_actions(vec.get_avail_actions(), rng)
            new_seeds = [1000 + t, None, 2000 + t]
            new_contexts = [None, {"level": "middle"}, None]
            resets += np.asarray(replica.done, dtype=int)
            got = vec.step(actions, seeds=new_seeds, contexts=new_contexts)
            assert same_step(got, replica.step(actions, new_seeds, new_contexts))
            state = np.stack([a.get_state() for a in replica.arenas])
            assert vec.get_state().tobytes() == state.tobytes()
            masks = np.stack([np.stack(a.get_avail_actions()) for a in replica.arenas])
            assert vec.get_avail_actions().tobytes() == masks.tobytes()
        assert (resets >= 1).all(), resets  # every arena went through an autoreset
    finally:
        vec.close()
        replica.close()


def test_one_bad_row_refuses_the_request_and_changes_no_arena() -> None:
    vec = VecArena(seed=3, num_envs=3)
    try:
        vec.reset()
        before = (vec.get_obs(), vec.get_state(), [a.t for a in vec.arenas])
        actions = np.zeros((3, 2), np.int64)
        actions[2, 1] = 8
        with pytest.raises(InvalidActionError, match=r"arena 2: agent 1: action 8 .*\[0, 7\]"):
            vec.step(actions)
        with pytest.raises(InvalidActionError, match="3 rows"):
            vec.step(actions[:2])
        with pytest.raises(InvalidActionError, match="active"):
            vec.step(actions[:, :], active=[True, False])
        after = (vec.get_obs(), vec.get_state(), [a.t for a in vec.arenas])
        assert before[0].tobytes() == after[0].tobytes() and before[2] == after[2]
        assert before[1].tobytes() == after[1].tobytes()
    finally:
        vec.close()


def test_a_bad_context_or_seed_refuses_the_whole_reset() -> None:
    vec = VecArena(seed=3, num_envs=2)
    try:
        vec.reset()
        t_before = [a.t for a in vec.arenas]
        with pytest.raises(InvalidContextError, match="arena 1: unknown context key 'VK9'"):
            vec.reset([{"level": "easy"}, {"VK9": 1.0}])
        with pytest.raises(InvalidContextError, match=r"arena 0: seed .*\[0, "):
            vec.reset(seed=[-1, 4])
        with pytest.raises(InvalidContextError, match="2 entries"):
            vec.reset(seed=[1, 2, 3])
        assert [a.t for a in vec.arenas] == t_before
        vec.step(np.zeros((2, 2), np.int64))  # still playing the same episodes
        assert all(a.t == t + 20 for a, t in zip(vec.arenas, t_before, strict=True))
    finally:
        vec.close()


def test_inactive_arenas_are_left_untouched() -> None:
    vec = VecArena(seed=5, num_envs=2)
    try:
        vec.reset()
        _, rewards, dones, infos = vec.step(np.zeros((2, 2), np.int64), active=[False, True])
        assert [a.t for a in vec.arenas] == [0, 20]
        assert rewards[0].tolist() == [0.0, 0.0] and not dones[0] and infos[0] == {}
        assert infos[1]["t"] == 20
    finally:
        vec.close()


def test_an_int_seed_seeds_arena_i_with_seed_plus_i() -> None:
    vec = VecArena(seed=0, num_envs=3)
    try:
        obs = vec.reset(seed=50)
        for i in range(3):
            solo = Arena(seed=0)
            assert obs[i].tobytes() == np.stack(solo.reset(seed=50 + i)).tobytes()
            solo.close()
    finally:
        vec.close()


def test_reads_and_steps_before_the_first_reset_are_typed_errors() -> None:
    vec = VecArena(seed=0, num_envs=2)
    try:
        for read in (vec.get_obs, vec.get_state, vec.get_avail_actions):
            with pytest.raises(ResetNeededError):
                read()
        with pytest.raises(ResetNeededError):
            vec.step(np.zeros((2, 2), np.int64))
        assert vec.get_env_info()["num_envs"] == 2
    finally:
        vec.close()


@pytest.mark.parametrize("bad", [0, 65, 2.0, True])
def test_the_arena_count_is_checked(bad: object) -> None:
    with pytest.raises(InvalidOptionError, match="num_envs"):
        VecArena(num_envs=bad)  # type: ignore[arg-type]


def test_arenas_used_after_close_raise_a_typed_error() -> None:
    """After close() reset was PyBullet's "Not connected to physics server", step a
    misleading ResetNeededError and get_obs the last episode's observations."""
    one, vec = Arena(seed=0), VecArena(seed=0, num_envs=2)
    one.reset()
    vec.reset()
    one.close()
    vec.close()
    for call, args in ((one.reset, ()), (one.step, ([0, 0],)), (one.get_obs, ()),
                       (one.get_state, ()), (one.get_avail_actions, ()),
                       (vec.reset, ()), (vec.step, (np.zeros((2, 2), np.int64),)),
                       (vec.get_obs, ()), (vec.get_avail_actions, ())):  # fmt: skip
        with pytest.raises(ClosedError, match=r"\(\) on (a )?closed arenas?; make a new"):
            call(*args)
    one.close()  # closing twice is fine
    vec.close()
