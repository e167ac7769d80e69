"""Red's opponents on the rollout worker: batched per opponent, exactly as if played alone."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuronsmae.protocol import EnvInfo
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.buffer import Episode
from neuronsmae.trainers.core.learner import EnvSpec, agent_spec
from neuronsmae.trainers.play.rollout import Request, RolloutWorker
from neuronsmae.trainers.play.task import blue_view

pytestmark = pytest.mark.slow  # plays a dozen whole episodes


def _policy(info: EnvInfo, seed: int) -> Policy:
    spec = agent_spec(EnvSpec.of(info, "relative"), 16, True, True, "relative", "points", info)
    torch.manual_seed(seed)
    return Policy(spec, {k: v.numpy() for k, v in spec.build().state_dict().items()})


def _requests() -> list[Request]:
    """Two snapshots and the easy bot on red, mixed over the arenas."""
    opponents = ["self:0", "bot:easy", "self:5", "self:0", "self:5"]
    return [
        Request(40 + i, 0.0, {"level": "easy", "bot_team": "red" if o == "bot:easy" else "none"},
                opponent=o)
        for i, o in enumerate(opponents)
    ]  # fmt: skip


def _play(envs: int, groups: int) -> tuple[list[Episode], dict[str, Policy]]:
    worker = RolloutWorker(0, "inprocess", 9, None, {"mode": "competitive"}, envs, groups)
    try:
        info = blue_view(EnvInfo.from_dict(worker.env_info()))
        blue = _policy(info, 1)
        pool = {"self:0": _policy(info, 2), "self:5": _policy(info, 3)}
        if envs == 1:  # one episode at a time
            return [worker.run(blue, 0, [r], pool, 0)[0] for r in _requests()], pool
        return worker.run(blue, 0, _requests(), pool, 0), pool
    finally:
        worker.close()


def test_opponents_batched_over_arenas_play_as_one_at_a_time() -> None:
    alone, _ = _play(envs=1, groups=1)
    for envs, groups in ((3, 1), (4, 2)):
        batched, _ = _play(envs, groups)
        assert [e.info["opponent"] for e in batched] == [e.info["opponent"] for e in alone]
        for a, b in zip(alone, batched, strict=True):
            assert np.array_equal(a.actions, b.actions) and np.array_equal(a.state, b.state)
            assert a.info["winner"] == b.info["winner"]
    assert alone[0].obs.shape[1] == 2  # blue's rows only


def test_the_opponent_sent_is_the_one_that_plays() -> None:
    """One start against each snapshot: the same first state, then the episodes part ways,
    and the first is the batched run's episode against that snapshot."""
    worker = RolloutWorker(0, "inprocess", 9, None, {"mode": "competitive"}, 1)
    try:
        info = blue_view(EnvInfo.from_dict(worker.env_info()))
        blue = _policy(info, 1)
        pool = {"self:0": _policy(info, 2), "self:5": _policy(info, 3)}
        first, second = (
            worker.run(blue, 0, [Request(40, 0.0, {"level": "easy", "bot_team": "none"},
                                         opponent=o)], pool, 0)[0]
            for o in ("self:0", "self:5")
        )  # fmt: skip
    finally:
        worker.close()
    assert np.array_equal(first.state[0], second.state[0])
    assert not np.array_equal(first.state, second.state)
    batched, _ = _play(envs=3, groups=1)
    assert np.array_equal(first.state, batched[0].state)


def test_a_bot_on_red_plays_as_in_the_cooperative_task() -> None:
    competitive, _ = _play(envs=3, groups=1)
    worker = RolloutWorker(0, "inprocess", 9, None, {"mode": "cooperative"}, 1)
    try:
        info = blue_view(EnvInfo.from_dict(worker.env_info()))
        request = Request(41, 0.0, {"level": "easy"})
        (coop,) = worker.run(_policy(info, 1), 0, [request])
    finally:
        worker.close()
    assert np.array_equal(coop.state, competitive[1].state)
    assert np.array_equal(coop.actions, competitive[1].actions)


def test_an_opponent_not_sent_is_an_error() -> None:
    worker = RolloutWorker(0, "inprocess", 9, None, {"mode": "competitive"}, 1)
    try:
        info = blue_view(EnvInfo.from_dict(worker.env_info()))
        request = Request(40, 0.0, {"bot_team": "none"}, opponent="self:7")
        with pytest.raises(KeyError, match="self:7"):
            worker.run(_policy(info, 1), 0, [request], {"self:0": _policy(info, 2)}, 0)
    finally:
        worker.close()
