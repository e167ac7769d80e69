"""Hostile input against a live server: every payload answered, with a typed error.

    python -m bench.fuzz [--payloads 20000] [--seed 0] [--timeout 5] [--arenas 1 3]

Runs one campaign per server size in ``--arenas`` (a one-arena server and a vector server
by default). Each sends ``--payloads`` generated requests (a seeded mix, see
:func:`payloads`: random bytes, random msgpack structures, byte-level mutations of valid
requests (one-arena and vector ones), field-level mutations of valid requests, and
hand-made edge cases: lying length prefixes, deep nesting, pickles, oversized and ext-typed
payloads) to one ``neuronsmae-server`` on loopback, each as one Zenoh query with a
timeout, in two phases:

1. nobody owns the server (so a generated ``configure`` may claim it and its ``step`` may
   run): every payload must get a reply that decodes, and that is an ``ok`` or an error
   whose code is a known typed error;
2. a client owns it and holds episodes: the payloads come from other sessions, plus those
   with the owner's session id that the protocol itself refuses; the owner's episodes must
   go on exactly as undisturbed in-process arenas (``Arena`` or ``VecArena``) with the same
   actions.

Then a fresh client's episodes must equal fresh in-process arenas bit for bit. Exits 1
when a promise breaks (no reply, an unknown code, a ``server_error``, a dead server, a
diverging episode). Writes bench/out/fuzz.json.
"""

from __future__ import annotations

import argparse
import collections
import random
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import msgpack
import numpy as np
import zenoh

from bench.common import (
    Distinct,
    arena_count,
    at_least,
    finite,
    free_port,
    machine,
    same,
    start_server,
    table,
    write_json,
)
from neuronsmae.client import RM, VecRM
from neuronsmae.protocol.errors import ERRORS, NeuronsMAEError, ServerError
from neuronsmae.protocol.messages import (
    MAX_REQUEST_BYTES,
    MESSAGES,
    NOT_CONFIGURED,
    PROTOCOL_VERSION,
    ErrorReply,
    OkReply,
    Reply,
    decode_reply,
    decode_request,
    rpc_key,
)
from neuronsmae.protocol.transport import client_config
from neuronsmae.server import Arena, VecArena

KNOWN_CODES = frozenset({*ERRORS, NOT_CONFIGURED})
OPTIONS: dict[str, Any] = {"action_space": "discrete"}


# ---- the generator -------------------------------------------------------------------------


def _scalar(rng: random.Random) -> Any:
    return rng.choice(
        [
            None, True, False, 0, -1, 1, 2**31, -(2**63), 2**64 - 1, 0.5, -0.0,
            float("nan"), float("inf"), "", "step", "é∂", b"", b"\x00\xff",
            rng.randint(-1000, 1000), rng.random() * 10 - 5,
            "".join(rng.choice("abcxyz_/") for _ in range(rng.randint(0, 12))),
        ]
    )  # fmt: skip


def _value(rng: random.Random, depth: int = 0) -> Any:
    """A random msgpack-able structure (maps may have non-string keys)."""
    kind = rng.random()
    if depth > 3 or kind < 0.45:
        return _scalar(rng)
    if kind < 0.65:
        return [_value(rng, depth + 1) for _ in range(rng.randint(0, 5))]
    if kind < 0.85:
        return {
            (_scalar(rng) if rng.random() < 0.2 else str(_scalar(rng))): _value(rng, depth + 1)
            for _ in range(rng.randint(0, 4))
        }
    return msgpack.ExtType(rng.choice([1, 2, 1, 0, 3, 127]), _ext_data(rng))


def _ext_data(rng: random.Random) -> bytes:
    """An array extension's data, more often almost valid than not."""
    dtype = rng.choice(["<f4", "<i8", "|u1", "|b1", "|O", "<U4", "V8", ">f8", "<M8", "<c16", ""])
    shape = rng.choice([[], [2], [0], [2, 3], [-1], [2**40, 2**40], ["2"], [1] * 40, None])
    n = rng.choice([0, 1, 8, 24, 48])
    if rng.random() < 0.2:
        return bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 16)))
    return msgpack.packb([dtype, shape, bytes(n)], use_bin_type=True)


def valid_requests(session: str, arenas: int = 1) -> list[dict[str, Any]]:
    """One well-formed request of each type (as wire maps) from ``session``, for a server
    holding ``arenas`` arenas (one-arena requests are then refused, which is tested too)."""
    env = {"v": PROTOCOL_VERSION, "session": session}
    rows = [[0, 0]] * arenas
    return [
        {**env, "type": "configure", "seed": 7, "options": dict(OPTIONS), "arenas": arenas},
        {**env, "type": "vreset", "contexts": {"level": 1}, "seeds": [3] * arenas},
        {**env, "type": "vreset", "contexts": [{"coef": 0.5}] * arenas, "seeds": None},
        {**env, "type": "vstep", "actions": rows},
        {**env, "type": "vstep", "actions": rows, "seeds": [9] * arenas, "active": [True] * arenas},
        {**env, "type": "vstep", "actions": rows, "contexts": [{"level": "hard"}] * arenas},
        *(
            {**env, "type": "vget", "what": w}
            for w in ("obs", "state", "avail_actions", "env_info")
        ),
        {**env, "type": "reset", "contexts": {"level": 1}, "seed": None},
        {**env, "type": "step", "actions": [0, 0]},
        {**env, "type": "get", "what": "obs"},
        {**env, "type": "get", "what": "state"},
        {**env, "type": "get", "what": "avail_actions"},
        {**env, "type": "get", "what": "env_info"},
        {**env, "type": "render"},
        {**env, "type": "ping"},
        {**env, "type": "contexts"},
        {**env, "type": "close"},
    ]


def _pack(wire: Any) -> bytes:
    return msgpack.packb(wire, use_bin_type=True)


def _mutate_bytes(rng: random.Random, data: bytes) -> bytes:
    """Flip, insert, delete, truncate, duplicate or splice bytes of a valid request."""
    buf = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(6)
        i = rng.randrange(len(buf) + 1)
        if op == 0 and buf:
            buf[min(i, len(buf) - 1)] ^= 1 << rng.randrange(8)
        elif op == 1:
            buf[i:i] = bytes([rng.choice([0xC0, 0xC1, 0xDD, 0xDF, 0xC6, 0xD9, 0xFF, 0x00])])
        elif op == 2 and buf:
            del buf[min(i, len(buf) - 1)]
        elif op == 3:
            buf = buf[:i]
        elif op == 4:
            buf += buf[: rng.randint(1, 8)]
        else:
            buf[i:i] = bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 8)))
    return bytes(buf)


def _mutate_fields(rng: random.Random, wire: dict[str, Any]) -> dict[Any, Any]:
    """Replace, add, drop or retype fields of a valid request."""
    out: dict[Any, Any] = dict(wire)
    for _ in range(rng.randint(1, 3)):
        op = rng.randrange(5)
        key = rng.choice(list(out) or ["v"])
        if op == 0:
            out[key] = _value(rng)
        elif op == 1:
            names = [
                "junk",
                "sudo",
                "actions",
                "seed",
                "seeds",
                "what",
                "active",
                "arenas",
                1,
                None,
            ]
            out[rng.choice(names)] = _value(rng)
        elif op == 2:
            out.pop(key, None)
        elif op == 3:
            out["type"] = rng.choice([*MESSAGES, "teleport", "", "STEP", None, 1])
        else:
            out["session"] = rng.choice(["", "x" * 129, 5, None, "fuzz", b"fuzz"])
    return out


def _edge_cases() -> list[bytes]:
    """Hand-made payloads for the decoder's limits and for pickle."""
    import pickle  # only to produce hostile payloads; the wire never unpickles

    class Boom:
        def __reduce__(self) -> tuple[Callable[..., Any], tuple[str]]:
            return (print, ("unpickled!",))

    step = {"v": PROTOCOL_VERSION, "type": "step", "session": "fuzz"}
    vstep = {"v": PROTOCOL_VERSION, "type": "vstep", "session": "fuzz"}
    return [
        b"",
        b"\xc1",
        b"\x91" * 200_000 + b"\xc0",  # deep arrays
        b"\x81\xa1a" * 100_000 + b"\xc0",  # deep maps
        b"\xdd\xff\xff\xff\xff",  # array32 claiming 4 G entries
        b"\xdf\xff\xff\xff\xff",  # map32 claiming 4 G pairs
        b"\xc6\xff\xff\xff\xff\x00",  # bin32 claiming 4 GB
        b"\xdb\xff\xff\xff\xff\x00",  # str32 claiming 4 GB
        b"\xc9\xff\xff\xff\xff\x01",  # ext32 claiming 4 GB
        b"\x84" + _pack(step)[1:] + b"\xa7actions\x91\xd6\xff\x00\x00\x00\x00",  # timestamp
        b"\x00" * (MAX_REQUEST_BYTES + 1),
        _pack({**step, "actions": [0] * (MAX_REQUEST_BYTES // 2)}),
        _pack({**step, "actions": [None] * (MAX_REQUEST_BYTES - 100)}),
        _pack({**step, "actions": [[[[[]]]]] * 100_000}),
        _pack({**step, "actions": msgpack.ExtType(1, _pack(["<f8", [2**40, 2**40], b""]))}),
        _pack({**step, "actions": msgpack.ExtType(1, _pack(["|O", [1], b"\x00" * 8]))}),
        _pack({**step, "actions": [pickle.dumps(Boom())]}),
        pickle.dumps({"v": 1, "type": "ping", "session": "fuzz"}),
        pickle.dumps(Boom()),
        pickle.dumps(Boom(), protocol=0),
        _pack({"v": PROTOCOL_VERSION, "type": "configure", "session": "fuzz",
               "options": {str(i): i for i in range(50_000)}}),
        _pack({"v": PROTOCOL_VERSION, "type": "configure", "session": "fuzz",
               "options": {"n_blue": 10**9}}),
        _pack({"v": PROTOCOL_VERSION, "type": "configure", "session": "fuzz",
               "options": {"n_blue": 2**64 - 1, "lidar": "yes"}}),
        _pack({"v": PROTOCOL_VERSION, "type": "reset", "session": "fuzz",
               "contexts": {"level": float("nan"), "coef": float("inf")}}),
        _pack({**step, "actions": [[float("nan")] * 4, [1e308, -1e308, 0, 2**63]]}),
        _pack({**vstep, "actions": [[0, 0]] * 100_000}),
        _pack({**vstep, "actions": [[0, 0], [0, 99]], "active": [True, "yes"]}),
        _pack({**vstep, "actions": [[0, 0]], "seeds": [2**64 - 1, -1], "contexts": [{"VK1": -5}]}),
        _pack({**vstep, "actions": msgpack.ExtType(1, _pack(["<i8", [2**31, 2**31], b""]))}),
        _pack({"v": PROTOCOL_VERSION, "type": "vreset", "session": "fuzz",
               "contexts": [{"level": float("nan")}] * 70, "seeds": [None] * 70}),
        _pack({"v": PROTOCOL_VERSION, "type": "configure", "session": "fuzz", "arenas": 10**9}),
    ]  # fmt: skip


def payloads(seed: int, count: int, session: str = "fuzz", arenas: int = 1) -> Iterator[bytes]:
    """``count`` hostile payloads, the same ones for the same seed; the edge cases first."""
    rng = random.Random(seed)
    templates = valid_requests(session, arenas)
    edge = _edge_cases()
    for n in range(count):
        if n < len(edge):
            yield edge[n]
            continue
        kind = rng.random()
        if kind < 0.15:
            yield bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 300)))
        elif kind < 0.35:
            yield _pack(_value(rng))
        elif kind < 0.60:
            yield _mutate_bytes(rng, _pack(rng.choice(templates)))
        elif kind < 0.95:
            yield _pack(_mutate_fields(rng, rng.choice(templates)))
        else:
            yield _pack(rng.choice(templates))  # valid: keeps the arena moving


def not_from(owner: str) -> Callable[[bytes], bool]:
    """A filter keeping the payloads that must leave ``owner``'s episode untouched: those the
    protocol layer refuses (whoever they claim to come from) and those of other sessions."""

    def keep(payload: bytes) -> bool:
        try:
            request = decode_request(payload)
        except NeuronsMAEError:
            return True
        return request.session != owner

    return keep


# ---- the runner ----------------------------------------------------------------------------


class Raw:
    """A Zenoh session sending raw bytes to one server's queryable, as a hostile client."""

    def __init__(self, port: int) -> None:
        self.key = rpc_key(port)
        self.session = zenoh.open(client_config("127.0.0.1", port))

    def send(self, payload: bytes, timeout: float) -> Reply | None:
        """The decoded reply, or None when none came within ``timeout``."""
        for reply in self.session.get(self.key, payload=payload, timeout=timeout):
            if reply.ok is None:
                return None
            return decode_reply(reply.ok.payload.to_bytes())
        return None

    def close(self) -> None:
        self.session.close()


def judge(reply: Reply | None) -> str:
    """A reply's class for the tally: ``ok``, an error code, or a broken promise."""
    if reply is None:
        return "NO_REPLY"
    if isinstance(reply, OkReply):
        return "ok"
    assert isinstance(reply, ErrorReply)
    if reply.code not in KNOWN_CODES:
        return f"UNKNOWN:{reply.code}"
    return reply.code


def fire(
    raw: Raw,
    stream: Iterator[bytes],
    timeout: float,
    keep: Callable[[bytes], bool] = lambda payload: True,
) -> dict[str, Any]:
    """Send every payload of ``stream`` that ``keep`` accepts; tally codes and latencies."""
    tally: collections.Counter[str] = collections.Counter()
    worst, sent = 0.0, 0
    for payload in stream:
        if not keep(payload):
            continue
        t0 = time.perf_counter()
        tally[judge(raw.send(payload, timeout))] += 1
        worst = max(worst, time.perf_counter() - t0)
        sent += 1
    return {"sent": sent, "codes": dict(tally), "max_latency_s": worst}


def broken(tally: dict[str, int]) -> int:
    """Payloads whose reply broke a promise (none, unknown code, or an internal error)."""
    return sum(n for code, n in tally.items() if code.isupper() or code == ServerError.code)


def clients(port: int, arenas: int, seed: int, timeout: float) -> tuple[Any, Any]:
    """A client of the server on ``port`` and its in-process twin (``RM`` and ``Arena`` for
    one arena, ``VecRM`` and ``VecArena`` for several)."""
    if arenas == 1:
        return RM(seed, port=port, launch=False, timeout=timeout, **OPTIONS), Arena(seed, **OPTIONS)
    remote = VecRM(seed, port=port, num_envs=arenas, launch=False, timeout=timeout, **OPTIONS)
    return remote, VecArena(seed, arenas, **OPTIONS)


def advance(remote: Any, local: Any, rng: np.random.Generator) -> bool:
    """One decision (in every arena) on both with the same random available actions; True
    when the results agree bit for bit (a finished one-arena episode is reset on both)."""
    if isinstance(local, Arena):
        actions = [int(rng.choice(np.flatnonzero(m))) for m in local.get_avail_actions()]
        ok = same(remote.step(actions), local.step(actions))
        ok &= same(remote.get_state(), local.get_state())
        if local.done:
            ok &= same(remote.reset(), local.reset())
        return ok
    avail = local.get_avail_actions()
    actions = (avail * rng.random(avail.shape)).argmax(-1)
    got, want = remote.step(actions), local.step(actions)
    return same(list(got), list(want)) and same(remote.get_state(), local.get_state())


def owner_phase(
    port: int, raw: Raw, seed: int, count: int, timeout: float, arenas: int = 1
) -> dict[str, Any]:
    """Fire hostile payloads between the owner's decisions (half claiming to come from the
    owner, sent only when the protocol refuses them); its episodes must not notice."""
    remote, local = clients(port, arenas, 11, timeout)
    try:
        rng = np.random.default_rng(11)
        agree = same(remote.reset(), local.reset())
        owner = remote.session_id if arenas == 1 else remote._conns[0].session_id
        mine = payloads(seed, count // 2, session=owner, arenas=arenas)
        theirs = payloads(seed + 1, count // 2, session="intruder", arenas=arenas)
        stream = [p for pair in zip(mine, theirs, strict=True) for p in pair]
        keep = not_from(owner)
        tally: collections.Counter[str] = collections.Counter()
        worst, sent = 0.0, 0
        for start in range(0, len(stream), 50):
            result = fire(raw, iter(stream[start : start + 50]), timeout, keep)
            tally.update(result["codes"])
            worst, sent = max(worst, result["max_latency_s"]), sent + result["sent"]
            agree &= advance(remote, local, rng)
    finally:
        remote.close()
        local.close()
    return {"sent": sent, "codes": dict(tally), "max_latency_s": worst, "owner_intact": agree}


def fresh_episode_matches(port: int, seed: int = 12, decisions: int = 40, arenas: int = 1) -> bool:
    """A new client's episodes equal fresh in-process arenas', bit for bit."""
    remote, local = clients(port, arenas, seed, 10.0)
    try:
        rng = np.random.default_rng(seed)
        ok = same(remote.reset(), local.reset())
        for _ in range(decisions):
            ok &= advance(remote, local, rng)
    finally:
        remote.close()
        local.close()
    return ok


def campaign(arenas: int, count: int, seed: int, timeout: float) -> dict[str, Any]:
    """Both phases and the fresh-episode check against one server holding ``arenas``."""
    port = free_port()
    server = start_server(port, arenas=arenas)
    raw = Raw(port)
    try:
        open_phase = fire(raw, payloads(seed, count, arenas=arenas), timeout)
        owned = owner_phase(port, raw, seed + 1, count // 4, timeout, arenas)
        raw.send(msgpack.packb({"v": 1, "type": "close", "session": "fuzz"}), 1.0)
        fresh = fresh_episode_matches(port, arenas=arenas)
        alive = server.proc.poll() is None
    finally:
        raw.close()
        server.stop()
    rows = [
        {"arenas": arenas, "phase": "no owner", **open_phase,
         "broken": broken(open_phase["codes"])},
        {"arenas": arenas, "phase": "owner holds episodes", **owned,
         "broken": broken(owned["codes"])},
    ]  # fmt: skip
    ok = alive and fresh and owned["owner_intact"] and not any(r["broken"] for r in rows)
    return {"rows": rows, "fresh_identical": fresh, "server_alive": alive, "ok": ok}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--payloads", type=at_least(1), default=20_000, help="per phase 1; phase 2: /4"
    )
    parser.add_argument("--seed", type=at_least(0), default=0)
    parser.add_argument(
        "--timeout", type=finite(0.5), default=5.0,
        help="seconds per query, ≥ 0.5 (the slowest hostile payload takes about 0.5 s)",
    )  # fmt: skip
    parser.add_argument(
        "--arenas",
        type=arena_count,
        nargs="+",
        action=Distinct,
        default=[1, 3],
        help="one campaign per server size",
    )
    args = parser.parse_args()
    t0 = time.perf_counter()
    runs = [campaign(k, args.payloads, args.seed + 10 * k, args.timeout) for k in args.arenas]
    elapsed = time.perf_counter() - t0
    rows = [row for run in runs for row in run["rows"]]
    for row in rows:
        print(f"{row['arenas']} arena(s), {row['phase']}: {row['codes']}")
    print(table(rows, ["arenas", "phase", "sent", "broken", "max_latency_s"]))
    for k, run in zip(args.arenas, runs, strict=True):
        print(f"{k} arena(s): owner's episodes intact: {run['rows'][1]['owner_intact']}; "
              f"fresh episodes identical: {run['fresh_identical']}; "
              f"server alive: {run['server_alive']}")  # fmt: skip
    ok = all(run["ok"] for run in runs)
    print(f"{'all promises kept' if ok else 'A PROMISE BROKE'}; {elapsed:.0f} s")
    report = {"seed": args.seed, "timeout_s": args.timeout, "campaigns": runs, "ok": ok,
              "elapsed_s": elapsed, "machine": machine(),
              "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}  # fmt: skip
    print(f"wrote {write_json('fuzz', report)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
