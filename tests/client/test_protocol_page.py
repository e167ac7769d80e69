"""A raw client written from protocol/README.md, against real servers: the five places where
the page and the server once parted (or the page was silent) now say and do one thing.

1. Vector errors name the arena, ``arena 0`` on a one-arena server too; one-arena
   messages' errors name none.
2. A reply speaks its request's version: version-1 ``configure`` and ``ping`` replies carry
   ``version: 1`` and none of version 2's fields (``arenas``, ``pid``).
3. A mistyped entry (seed, ``active``, ``contexts``) is ``malformed_message``; a field
   without K entries gets the message's own code.
4. On a one-arena server ``step`` and ``vstep`` play one episode: once it ends at either,
   ``step`` needs a reset and ``vstep`` autoresets.
5. ``env_info`` has exactly the page's keys with the page's types; sizes are ints and
   ``episode_limit`` counts decisions.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from neuronsmae.protocol.messages import ErrorReply, OkReply, Reply
from neuronsmae.server.arena import Arena

from .conftest import RawClient, Server

PAGE = Path(__file__).resolve().parents[2] / "protocol" / "README.md"
SESSION = "page-client"


class Wire:
    """Requests as the page spells them: msgpack maps with the envelope fields."""

    def __init__(self, server: Server) -> None:
        self.raw = RawClient(server.port)

    def send(self, kind: str, v: int = 2, **fields: Any) -> Reply:
        reply = self.raw.send(msgpack.packb({"v": v, "type": kind, "session": SESSION, **fields}))
        assert reply is not None, f"no reply to {kind}"
        return reply

    def ok(self, kind: str, v: int = 2, **fields: Any) -> Any:
        reply = self.send(kind, v, **fields)
        assert isinstance(reply, OkReply), reply
        return reply.value

    def error(self, kind: str, **fields: Any) -> ErrorReply:
        reply = self.send(kind, **fields)
        assert isinstance(reply, ErrorReply), reply
        return reply


@pytest.fixture(scope="module")
def one(start_server: Callable[..., Server]) -> Iterator[Wire]:
    """A one-arena server, as ``neuronsmae-server`` starts by default."""
    wire = Wire(start_server())
    yield wire
    wire.send("close")
    wire.raw.close()


@pytest.fixture(scope="module")
def two(start_server: Callable[..., Server]) -> Iterator[Wire]:
    """A server of two arenas (``--arenas 2``)."""
    wire = Wire(start_server("--arenas", "2"))
    yield wire
    wire.send("close")
    wire.raw.close()


def test_vector_errors_name_arena_0_on_a_one_arena_server(one: Wire) -> None:
    one.ok("configure", seed=1, options={})
    one.ok("vreset")
    refused = one.error("vstep", actions=[[9, 0]])
    assert refused.code == "invalid_action"
    assert refused.message.startswith("arena 0: agent 0: action 9 is out of range")
    refused = one.error("vreset", contexts={"zz": 1})
    assert refused.code == "invalid_context"
    assert refused.message.startswith("arena 0: unknown context key 'zz'")
    refused = one.error("vstep", actions=[[0, 0]], contexts=[{"zz": 1}])
    assert refused.message.startswith("arena 0: unknown context key 'zz'")
    # the one-arena messages answer as the arena does in process: no arena index
    refused = one.error("step", actions=[9, 0])
    assert (refused.code, refused.message) == (
        "invalid_action",
        "agent 0: action 9 is out of range; valid: [0, 7]",
    )
    refused = one.error("reset", contexts={"zz": 1})
    assert refused.code == "invalid_context"
    assert refused.message.startswith("unknown context key 'zz'")


def test_a_reply_speaks_its_requests_version(one: Wire) -> None:
    configured = one.ok("configure", v=1, seed=1, options={})
    assert configured["version"] == 1 and set(configured) == {"version", "server", "rebuilt"}
    pinged = one.ok("ping", v=1)
    assert pinged["version"] == 1
    assert set(pinged) == {"version", "server", "owned", "time_scale"}
    obs = one.ok("reset", v=1)  # a version-1 client plays as before
    assert len(one.ok("step", v=1, actions=[0] * len(obs))) == 4
    configured = one.ok("configure", seed=1, options={})
    assert configured["version"] == 2 and configured["arenas"] == 1
    pinged = one.ok("ping")
    assert pinged["version"] == 2 and pinged["arenas"] == 1 and isinstance(pinged["pid"], int)
    assert pinged["server"] == configured["server"]


MISTYPED: dict[str, tuple[str, dict[str, Any]]] = {
    "seed out of range": ("vstep", {"seeds": [None, -1]}),
    "seed not an int": ("vstep", {"seeds": ["1", None]}),
    "active not bools": ("vstep", {"active": [1, 0]}),
    "contexts entry not a map": ("vstep", {"contexts": [None, "VK1"]}),
    "reset seed out of range": ("vreset", {"seeds": [2**63, None]}),
    "reset contexts entry not a map": ("vreset", {"contexts": ["VK1", None]}),
}
WRONG_COUNT: dict[str, tuple[str, dict[str, Any], str]] = {
    "actions": ("vstep", {"actions": [[0, 0]] * 3}, "invalid_action"),
    "active": ("vstep", {"active": [True]}, "invalid_action"),
    "seeds": ("vstep", {"seeds": [1, 2, 3]}, "invalid_context"),
    "contexts": ("vstep", {"contexts": [None]}, "invalid_context"),
    "reset seeds": ("vreset", {"seeds": [1]}, "invalid_context"),
    "reset contexts": ("vreset", {"contexts": [None, None, None]}, "invalid_context"),
}


def test_mistyped_entries_are_malformed_and_wrong_counts_get_the_messages_code(
    two: Wire,
) -> None:
    two.ok("configure", seed=3, options={}, arenas=2)
    two.ok("vreset")
    state = two.ok("vget", what="state")
    rows = {"actions": [[0, 0], [0, 0]]}
    for name, (kind, fields) in MISTYPED.items():
        refused = two.error(kind, **({**rows, **fields} if kind == "vstep" else fields))
        assert refused.code == "malformed_message", name
        assert re.search(r"field '\w+(\[\d\])?'", refused.message), (name, refused.message)
    for name, (kind, fields, code) in WRONG_COUNT.items():
        refused = two.error(kind, **({**rows, **fields} if kind == "vstep" else fields))
        assert refused.code == code, name
        field = name.split()[-1]
        assert refused.message.startswith(field) and " 2 " in refused.message, refused.message
    assert two.ok("vget", what="state").tobytes() == state.tobytes()  # nothing moved


def identical(got: list[np.ndarray], want: list[np.ndarray]) -> bool:
    """The same arrays, bit for bit."""
    return len(got) == len(want) and all(
        np.asarray(g).tobytes() == np.asarray(w).tobytes() for g, w in zip(got, want, strict=True)
    )


def test_step_and_vstep_play_one_episode_on_a_one_arena_server(one: Wire) -> None:
    options, contexts = {"episode_steps": 40}, {"level": "easy", "coef": 1.5}
    one.ok("configure", seed=21, options=options)
    local = Arena(seed=21, **options)
    try:
        zeros = [0, 0]
        first = one.ok("reset", contexts=contexts)
        assert identical(first, local.reset(contexts))
        assert one.ok("step", actions=zeros)[2] is False
        _, _, done, _ = one.ok("step", actions=zeros)
        local.step(zeros)
        local.step(zeros)
        assert done is True  # ended at `step`: over for both kinds
        assert one.error("step", actions=zeros).code == "reset_needed"
        reply = one.ok("vstep", actions=[[9, 9]])  # autoresets: the row is ignored
        assert reply["dones"].tolist() == [False] and reply["infos"] == [{}]
        assert not reply["rewards"].any()
        again = local.reset(contexts)  # the arena's RNG, the contexts of its last reset
        assert identical(list(reply["obs"][0]), again)
        assert identical(one.ok("get", what="obs"), again)
        assert one.ok("vstep", actions=[zeros])["dones"].tolist() == [False]
        assert one.ok("vstep", actions=[zeros])["dones"].tolist() == [True]  # ended at vstep
        assert one.error("step", actions=zeros).code == "reset_needed"
        assert one.ok("vstep", actions=[zeros])["infos"] == [{}]  # autoreset again
        assert one.ok("step", actions=zeros)[2] is False  # a running episode: `step` plays
        assert one.ok("step", actions=zeros)[2] is True
        one.ok("vreset")  # either reset starts a new episode for both
        assert one.ok("step", actions=zeros)[2] is False
    finally:
        local.close()


PAGE_TYPES: dict[str, Callable[[Any], bool]] = {
    "int": lambda v: type(v) is int,
    "str": lambda v: type(v) is str,
    "bool": lambda v: type(v) is bool,
    "array of str": lambda v: type(v) is list and all(type(x) is str for x in v),
}


def env_info_table() -> dict[str, str]:
    """Key → type, from the page's table of the ``env_info`` map."""
    text = PAGE.read_text()
    section = text[text.index("##### The `env_info` map") :]
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+?) \|", section.split("\n\n#")[0], re.M)
    return dict(rows)


@pytest.mark.parametrize("episode_steps", [40, 50])
def test_env_info_is_typed_as_the_page_says(one: Wire, episode_steps: int) -> None:
    table = env_info_table()
    assert len(table) == 15 and set(table.values()) <= set(PAGE_TYPES)
    one.ok("configure", seed=2, options={"episode_steps": episode_steps})
    info = one.ok("get", what="env_info")
    assert set(info) == set(table)
    for key, kind in table.items():
        assert PAGE_TYPES[kind](info[key]), (key, kind, info[key])
    vinfo = one.ok("vget", what="env_info")
    assert vinfo == {**info, "num_envs": 1} and type(vinfo["num_envs"]) is int
    obs = one.send("reset")
    assert isinstance(obs, OkReply) and obs.snapshot is not None
    assert len(obs.value) == info["n_agents"]
    assert {o.shape for o in obs.value} == {(info["obs_shape"],)}
    assert obs.snapshot["state"].shape == (info["state_shape"],)
    assert {m.shape for m in obs.snapshot["avail_actions"]} == {(info["n_actions"],)}
    limit = math.ceil(episode_steps / info["decision_steps"])
    assert info["episode_limit"] == limit  # decisions, not physics steps or seconds
    decisions = [one.ok("step", actions=[0, 0])[2] for _ in range(limit)]
    assert decisions == [False] * (limit - 1) + [True]
