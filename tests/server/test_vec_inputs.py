"""VecArena's input rules, written against ``VecArenaAPI`` so that the client's tests run the
same checks on a ``VecRM`` over one server and over several (``tests/client``).

* The action row of an arena that does not step in a call (not ``active``, or
  autoresetting) is ignored, unchecked; so are the actions of a bot-driven team.
* Every entry of ``seeds`` and ``contexts`` is checked, whether its arena resets or not.
* Seeds, counts and contexts of the wrong type are typed errors naming the field.
"""

from __future__ import annotations

import numpy as np
import pytest

from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
)
from neuronsmae.protocol.interface import VecArenaAPI
from neuronsmae.server import Arena, VecArena

SHORT = {"episode_steps": 40}
"""Two decisions per episode: an arena ends (and autoresets) within a few steps."""


def ignored_rows_are_not_checked(vec: VecArenaAPI) -> None:
    """``vec``: 4 arenas built with :data:`SHORT`."""
    vec.reset(seed=0)
    bad = np.zeros((4, 2), np.int64)
    bad[3] = [9, -1]
    vec.step(bad, active=[True, True, True, False])  # arena 3 does not step: row ignored
    with pytest.raises(InvalidActionError, match="arena 3: agent 0: action 9"):
        vec.step(bad)  # now it steps: checked
    vec.reset(seed=0)
    vec.step(np.zeros((4, 2), np.int64))
    dones = vec.step(np.zeros((4, 2), np.int64))[2]
    assert dones.all()  # every arena autoresets at the next step
    _, rewards, dones, infos = vec.step(np.full((4, 2), 9))  # every row ignored
    assert not dones.any() and infos == [{}] * 4 and not rewards.any()
    with pytest.raises(InvalidActionError, match="arena 0: agent 0: action 9"):
        vec.step(np.full((4, 2), 9))  # they step again: checked


def given_entries_are_checked(vec: VecArenaAPI) -> None:
    """``vec``: 4 arenas; no arena resets in the steps below, yet their entries count."""
    vec.reset(seed=0)
    t_before = vec.get_state()[:, -1].copy()
    zeros = np.zeros((4, 2), np.int64)
    with pytest.raises(InvalidContextError, match="arena 0: unknown context key 'zz'"):
        vec.step(zeros, contexts=[{"zz": 1}, None, None, None])
    with pytest.raises(InvalidContextError, match=r"arena 1: seed -1 is out of range"):
        vec.step(zeros, seeds=[None, -1, None, None])
    with pytest.raises(InvalidContextError, match="arena 2: contexts must be a mapping"):
        vec.step(zeros, contexts=[None, None, "VK1", None])
    with pytest.raises(InvalidContextError, match="seeds must have 4 entries"):
        vec.step(zeros, seeds=[None] * 3)
    assert vec.get_state()[:, -1].tobytes() == t_before.tobytes()  # nothing moved
    vec.step(zeros, contexts=[{"VK1": np.float32(0.2)}, None, None, None], seeds=[1] * 4)


def reset_arguments_are_typed(vec: VecArenaAPI) -> None:
    """``vec``: 4 arenas."""
    with pytest.raises(InvalidContextError, match="arena 0: contexts must be a mapping"):
        vec.reset(["a", "b", "c", "d"])
    with pytest.raises(InvalidContextError, match=r"an int .* or a sequence of 4 ints or None"):
        vec.reset(seed=1.5)
    with pytest.raises(InvalidContextError, match="seed must have 4 entries"):
        vec.reset(seed=[None] * 3)
    obs = vec.reset({"VK1": np.float32(0.25), "level": np.int64(1)}, seed=np.int64(3))
    assert obs.tobytes() == vec.reset({"VK1": 0.25, "level": 1}, seed=3).tobytes()


def bot_team_rows_are_not_checked(vec: VecArenaAPI) -> None:
    """``vec``: 2 competitive arenas. With ``bot_team="red"`` red's entries are ignored."""
    vec.reset([{"bot_team": "red"}, None], seed=0)
    rows = np.zeros((2, 4), np.int64)
    rows[0, 2:] = 99
    vec.step(rows)
    with pytest.raises(InvalidActionError, match="arena 1: agent 2"):
        vec.step(rows[::-1].copy())


def test_ignored_rows_are_not_checked() -> None:
    with VecArena(seed=0, num_envs=4, **SHORT) as vec:
        ignored_rows_are_not_checked(vec)


def test_given_seeds_and_contexts_are_checked_every_call() -> None:
    with VecArena(seed=0, num_envs=4) as vec:
        given_entries_are_checked(vec)


def test_reset_arguments_are_typed() -> None:
    with VecArena(seed=0, num_envs=4) as vec:
        reset_arguments_are_typed(vec)


def test_bot_team_rows_are_not_checked() -> None:
    with VecArena(seed=0, num_envs=2, mode="competitive") as vec:
        bot_team_rows_are_not_checked(vec)


@pytest.mark.parametrize("seed", [1.5, "3", True, None, -1, 2**63 - 1])
def test_the_seed_option_is_an_integer(seed: object) -> None:
    """1.5 gave seeds [1, 2], "3" [3, 4], True [1, 2]; None a builtin TypeError."""
    with pytest.raises(InvalidOptionError, match=r"seed must be an integer in \[0, "):
        VecArena(seed=seed, num_envs=2)  # type: ignore[arg-type]


def test_numpy_counts_and_seeds_are_accepted() -> None:
    with VecArena(seed=np.int64(4), num_envs=np.int64(2)) as vec:
        assert vec.num_envs == 2 and type(vec.num_envs) is int and vec.seed == 4
        with pytest.raises(InvalidOptionError, match="num_envs"):
            VecArena(num_envs=np.bool_(True))  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [np.float32(0.2), np.float64(0.2), np.float16(0.2)])
def test_numpy_context_values_are_numbers(value: object) -> None:
    """Stored as plain Python numbers; the episode equals the one given the float."""
    a, b = Arena(seed=0), Arena(seed=0)
    try:
        got = a.reset({"VK1": value, "opponent_hp": np.int32(300), "coef": np.int64(2)})
        want = b.reset({"VK1": float(value), "opponent_hp": 300, "coef": 2})  # type: ignore[arg-type]
        assert np.stack(got).tobytes() == np.stack(want).tobytes()
        assert type(a.context.blue_dynamics["vk1"]) is float
        assert type(a.context.opponent_hp) is float
        with pytest.raises(InvalidContextError, match="'coef' must be a number"):
            a.reset({"coef": np.bool_(True)})
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("contexts", ["VK1", ["VK1"], 3])
def test_contexts_must_be_a_mapping(contexts: object) -> None:
    """``dict("VK1")`` was a builtin ValueError ("dictionary update sequence ...")."""
    with Arena(seed=0) as a, pytest.raises(InvalidContextError, match="contexts must be a mapping"):
        a.reset(contexts)  # type: ignore[arg-type]
