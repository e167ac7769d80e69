"""Why requests stay Zenoh queries: query/reply against publish/subscribe, same arena service.

    python -m bench.bench_rpc_styles [--decisions 200] [--rounds 7]

Serves the real :class:`~neuronsmae.server.serving.service.ArenaService` (abstract 2 v 2) from two
server processes, one answering Zenoh queries (what ``neuronsmae-server`` does) and one
answering requests published on a key with replies published on another (the alternative
the transport issue proposed), and drives both with the same trainer-like loop as
``bench_transport``, interleaved with the in-process arena round by round. Both servers use
the project's own session settings (``protocol.transport``), so the only difference is the
message pattern. Also reports each server's CPU per decision by thread: the Python main
thread (decode, ``Arena.step``, state and masks, encode) against Zenoh's own threads.

Prints a Markdown table and writes ``bench/out/rpc_styles.json``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np
import psutil
import zenoh

from bench.bench_transport import play
from bench.common import (
    at_least,
    cpu_by_thread,
    cpu_snapshot,
    free_port,
    machine,
    table,
    write_json,
)
from neuronsmae.protocol.messages import (
    Configure,
    OkReply,
    Reset,
    Step,
    decode_reply,
    encode_request,
)
from neuronsmae.protocol.transport import client_config, server_config

OPTIONS = {"action_space": "abstract", "n_blue": 2, "n_red": 2}
STYLES = ("query", "pubsub")
SESSION = "bench-rpc-styles-0000000000000000"


def serve(port: int, style: str) -> None:
    """Answer requests on ``port`` in ``style`` until killed (runs in its own process)."""
    from neuronsmae.server.arena import Arena
    from neuronsmae.server.serving.service import ArenaService

    with ArenaService(Arena, seed=1) as service:
        session = zenoh.open(server_config("127.0.0.1", port))
        try:
            if style == "query":
                queryable = session.declare_queryable("bench/rpc")
                while True:
                    with queryable.recv() as query:
                        reply = service.handle(query.payload.to_bytes())
                        query.reply("bench/rpc", reply, express=True)
            else:
                replies = session.declare_publisher("bench/rep", express=True)
                requests = session.declare_subscriber("bench/req")
                while True:
                    replies.put(service.handle(requests.recv().payload.to_bytes()))
        finally:
            session.close()


class StyleClient:
    """Sends encoded requests in one style and decodes the replies."""

    def __init__(self, port: int, style: str) -> None:
        self.session = zenoh.open(client_config("127.0.0.1", port))
        self.call: Callable[[bytes], bytes]
        if style == "query":
            querier = self.session.declare_querier(
                "bench/rpc", timeout=10.0, consolidation=zenoh.ConsolidationMode.NONE, express=True
            )
            self.call = lambda data: querier.get(payload=data).recv().ok.payload.to_bytes()
        else:
            publisher = self.session.declare_publisher("bench/req", express=True)
            subscriber = self.session.declare_subscriber("bench/rep")

            def call(data: bytes) -> bytes:
                publisher.put(data)
                return subscriber.recv().payload.to_bytes()

            self.call = call

    def request(self, body: object) -> OkReply:
        reply = decode_reply(self.call(encode_request(body, SESSION)))
        assert isinstance(reply, OkReply), reply
        return reply

    def close(self) -> None:
        self.session.close()


def remote_round(client: StyleClient, decisions: int, rng: np.random.Generator) -> float:
    """Decisions/s of the trainer-like loop, masks read from the replies' snapshots."""
    masks = client.request(Reset()).snapshot["avail_actions"]
    start = time.perf_counter()
    for _ in range(decisions):
        actions = [int(rng.choice(np.flatnonzero(m))) for m in masks]
        reply = client.request(Step(actions=actions))
        if reply.value[2]:
            reply = client.request(Reset())
        masks = reply.snapshot["avail_actions"]
    return decisions / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--decisions", type=at_least(1), default=200)
    parser.add_argument("--rounds", type=at_least(1), default=7)
    parser.add_argument("--serve", nargs=2, metavar=("PORT", "STYLE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(int(args.serve[0]), args.serve[1])
        return
    from neuronsmae.server.arena import Arena

    me = psutil.Process()
    servers, clients = {}, {}
    try:
        for style in STYLES:
            port = free_port()
            servers[style] = subprocess.Popen(
                [sys.executable, "-m", "bench.bench_rpc_styles", "--serve", str(port), style],
                stderr=subprocess.DEVNULL,
            )
            clients[style] = _connect(port, style)
            clients[style].request(Configure(seed=1, options=OPTIONS))
        arena = Arena(seed=1, **OPTIONS)
        rates: dict[str, list[float]] = {"in_process": [], **{s: [] for s in STYLES}}
        cpu: dict[str, dict[str, float]] = {s: {} for s in STYLES}
        for r in range(args.rounds):
            rng = np.random.default_rng(r)
            rates["in_process"].append(play(arena, args.decisions, rng, False, [me])[0])
            for style in STYLES:
                server = psutil.Process(servers[style].pid)
                before = cpu_snapshot([server])
                rng = np.random.default_rng(r)
                rates[style].append(remote_round(clients[style], args.decisions, rng))
                split = cpu_by_thread(before, cpu_snapshot([server]), [server.pid])[0]
                for kind, seconds in zip(("main (Python)", "Zenoh threads"), split, strict=True):
                    spent = seconds / args.decisions / args.rounds
                    cpu[style][kind] = cpu[style].get(kind, 0.0) + spent
    finally:
        for client in clients.values():
            client.close()
        for proc in servers.values():
            proc.kill()
            proc.wait()
    rows = []
    local = statistics.median(rates["in_process"])
    for style in STYLES:
        paired = [r / p for p, r in zip(rates["in_process"], rates[style], strict=True)]
        rows.append(
            {
                "style": style,
                "decisions/s": statistics.median(rates[style]),
                "in process decisions/s": local,
                "ratio (paired median)": round(statistics.median(paired), 3),
                **{f"server {k} µs/decision": 1e6 * v for k, v in sorted(cpu[style].items())},
            }
        )
    print(table(rows, list(rows[0])))
    payload = {"rows": rows, "rates": rates, "decisions": args.decisions, "machine": machine()}
    print(f"\nwrote {write_json('rpc_styles', payload)}")


def _connect(port: int, style: str, wait: float = 120.0) -> StyleClient:
    """A client once the server answers (it warms the simulation up first)."""
    deadline = time.monotonic() + wait
    while True:
        try:
            client = StyleClient(port, style)
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)
            continue
        time.sleep(0.5)  # let the subscriptions reach the server before the first request
        return client


if __name__ == "__main__":
    main()
