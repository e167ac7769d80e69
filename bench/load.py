"""Load: eight clients at once against one server, and many servers against the cores.

    python -m bench.load [--clients 8] [--decisions 2000] [--counts 1 2 4 8] [--seconds 8]

Part 1, contention. One unpaced server; ``--clients`` client processes start together and
each tries to claim it (``RM(...)``). The policy (protocol/README.md, "Ownership") says
exactly one succeeds and the others get ``BusyError``. The owner then plays ``--decisions``
random allowed decisions while every other client keeps sending configure, reset, step,
get, render and ping with its own session. Checked: one owner; every foreign arena request
answered ``busy`` and every ping ``ok``; the owner's trajectory (a digest of each
reset/step reply) equals an in-process ``Arena`` with the same seed and actions, and equals
the same owner playing alone first; and what contention costs the owner's latency.

Part 2, scaling. Aggregate decisions/s with 1, 2, 4, 8 servers (one client process each),
measured by ``bench/bench_scaling.py``'s ``measure``: this script reuses it rather than
repeating it (``--counts`` empty skips it). Writes bench/out/load.json.
"""

from __future__ import annotations

import argparse
import hashlib
import multiprocessing as mp
import sys
import time
from collections import Counter
from multiprocessing.synchronize import Barrier, Event
from typing import Any

import numpy as np
import zenoh

from bench.bench_scaling import check_ports, measure
from bench.common import (
    Distinct,
    arena_count,
    at_least,
    free_port,
    machine,
    positive,
    start_server,
    table,
    tcp_port,
    write_json,
)
from neuronsmae.client import RM
from neuronsmae.protocol.codec import encode
from neuronsmae.protocol.errors import BusyError
from neuronsmae.protocol.messages import (
    Configure,
    ErrorReply,
    Get,
    Message,
    OkReply,
    Ping,
    Render,
    Reset,
    Step,
    decode_reply,
    encode_request,
    rpc_key,
)
from neuronsmae.protocol.transport import client_config
from neuronsmae.server.arena import Arena

SEED = 5
OPTIONS: dict[str, Any] = {"action_space": "discrete"}
HAMMER: list[Message] = [
    Configure(seed=99),
    Reset(),
    Step(actions=[0, 0]),
    Get(what="state"),
    Render(),
    Ping(),
]
HAMMER_LIMIT_S = 600.0
"""A foreign client stops after this long even if the owner never finishes."""


def digest(value: Any) -> str:
    """A fingerprint of a reply value, equal only for bit-identical values."""
    return hashlib.sha256(encode(value)).hexdigest()[:16]


def play(env: Any, decisions: int) -> dict[str, Any]:
    """Random allowed decisions from a fixed seed; the digests and latencies of each."""
    rng = np.random.default_rng(SEED)
    digests, actions, latency = [digest(env.reset())], [], []
    for _ in range(decisions):
        chosen = [int(rng.choice(np.flatnonzero(m))) for m in env.get_avail_actions()]
        t0 = time.perf_counter()
        result = env.step(chosen)
        latency.append(time.perf_counter() - t0)
        actions.append(chosen)
        digests.append(digest(list(result)))
        if result[2]:
            digests.append(digest(env.reset()))
    return {"digests": digests, "actions": actions, "latency": latency}


def hammer(port: int, session: str, stop: Event) -> dict[str, Any]:
    """A foreign client: every request type in turn until the owner is done."""
    zsession = zenoh.open(client_config("127.0.0.1", port))
    codes: Counter[str] = Counter()
    worst, t_end = 0.0, time.monotonic() + HAMMER_LIMIT_S
    try:
        k = 0
        while not stop.is_set() and time.monotonic() < t_end:
            body = HAMMER[k % len(HAMMER)]
            t0 = time.perf_counter()
            replies = list(zsession.get(rpc_key(port), payload=encode_request(body, session),
                                        timeout=10.0))  # fmt: skip
            worst = max(worst, time.perf_counter() - t0)
            ok = [r.ok for r in replies if r.ok is not None]
            reply = decode_reply(ok[0].payload.to_bytes()) if ok else None
            code = (
                reply.code if isinstance(reply, ErrorReply)
                else "ok" if isinstance(reply, OkReply) else "no-reply"
            )  # fmt: skip
            codes[f"{body.TYPE}:{code}"] += 1
            k += 1
    finally:
        zsession.close()
    return {"codes": dict(codes), "max_latency_s": worst}


def contender(i: int, port: int, decisions: int, barrier: Barrier, stop: Event, out: Any) -> None:
    """One client process: claim the server; play if it is ours, else hammer it."""
    barrier.wait()
    try:
        env = RM(seed=SEED, port=port, launch=False, timeout=30.0, **OPTIONS)
    except BusyError as exc:
        out.put({"client": i, "role": "refused", "error": str(exc), **hammer(port, f"c{i}", stop)})
        return
    try:
        result = play(env, decisions)
    finally:
        stop.set()
        env.close()
    out.put({"client": i, "role": "owner", **result})


def contention(clients: int, decisions: int) -> dict[str, Any]:
    port = free_port()
    server = start_server(port)
    try:
        with RM(seed=SEED, port=port, launch=False, timeout=30.0, **OPTIONS) as alone_env:
            alone = play(alone_env, decisions)
        ctx = mp.get_context("spawn")  # never fork a process that holds Zenoh sessions
        barrier, stop, out = ctx.Barrier(clients), ctx.Event(), ctx.Queue()
        procs = [
            ctx.Process(target=contender, args=(i, port, decisions, barrier, stop, out))
            for i in range(clients)
        ]
        for p in procs:
            p.start()
        results = [out.get(timeout=HAMMER_LIMIT_S + 120) for _ in procs]
        for p in procs:
            p.join(30)
        alive = server.proc.poll() is None
    finally:
        server.stop()
    local = Arena(seed=SEED, **OPTIONS)
    reference = replay(local, alone["actions"])
    local.close()
    owners = [r for r in results if r["role"] == "owner"]
    refused = [r for r in results if r["role"] == "refused"]
    codes: Counter[str] = Counter()
    for r in refused:
        codes.update(r["codes"])
    owner = owners[0] if len(owners) == 1 else {"digests": [], "latency": [0.0]}
    return {
        "owners": len(owners),
        "refused": len(refused),
        "foreign_replies": dict(codes),
        "foreign_unexpected": {
            k: n for k, n in codes.items() if not (k.endswith(":busy") or k == "ping:ok")
        },
        "owner_equals_in_process": owner["digests"] == reference,
        "owner_equals_alone": owner["digests"] == alone["digests"],
        "alone_equals_in_process": alone["digests"] == reference,
        "latency_ms": {
            "alone": _percentiles(alone["latency"]),
            "contended": _percentiles(owner["latency"]),
        },
        "server_alive": alive,
    }


def replay(arena: Arena, actions: list[list[int]]) -> list[str]:
    """The digests an in-process arena produces for the same actions."""
    digests = [digest(arena.reset())]
    for chosen in actions:
        result = arena.step(chosen)
        digests.append(digest(list(result)))
        if result[2]:
            digests.append(digest(arena.reset()))
    return digests


def _percentiles(latency: list[float]) -> dict[str, float]:
    ms = np.asarray(latency) * 1000
    return {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)),
            "mean": float(ms.mean()), "decisions_per_s": float(1000 / ms.mean())}  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clients", type=at_least(1), default=8)
    parser.add_argument("--decisions", type=at_least(1), default=2000)
    parser.add_argument(
        "--counts", type=at_least(1), nargs="*", action=Distinct, default=[1, 2, 4, 8]
    )
    parser.add_argument("--envs", type=arena_count, default=1, help="arenas per server in part 2")
    parser.add_argument("--seconds", type=positive, default=8.0)
    parser.add_argument("--repeats", type=at_least(1), default=1)
    parser.add_argument("--base-port", type=tcp_port, default=18100)
    args = parser.parse_args()
    check_ports(parser, args.base_port, args.counts)
    t0 = time.perf_counter()
    part1 = contention(args.clients, args.decisions)
    print(f"{args.clients} clients: {part1['owners']} owner, {part1['refused']} refused (busy)")
    print(f"foreign replies: {part1['foreign_replies']}")
    print(f"owner's trajectory == in-process Arena: {part1['owner_equals_in_process']}; "
          f"== owner alone: {part1['owner_equals_alone']}")  # fmt: skip
    lat = part1["latency_ms"]
    print(table([{"run": k, **v} for k, v in lat.items()],
                ["run", "p50", "p99", "mean", "decisions_per_s"]))  # fmt: skip
    scaling = []
    if args.counts:
        scaling = measure(
            sorted(args.counts), args.envs, args.seconds, args.repeats, args.base_port
        )
        columns = ["servers", "decisions_per_s", "per_server", "cpu_ms_per_decision", "load1"]
        print(table(scaling, columns))
    ok = (
        part1["owners"] == 1
        and part1["refused"] == args.clients - 1
        and not part1["foreign_unexpected"]
        and part1["owner_equals_in_process"]
        and part1["owner_equals_alone"]
        and part1["server_alive"]
    )
    report = {"clients": args.clients, "decisions": args.decisions, "contention": part1,
              "scaling": scaling, "ok": ok, "elapsed_s": time.perf_counter() - t0,
              "machine": machine(), "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}  # fmt: skip
    print(f"wrote {write_json('load', report)}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
