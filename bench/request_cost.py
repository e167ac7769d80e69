"""What one vector request costs in NeuronsMAE's own Python, with warm and with cold caches.

    python -m bench.request_cost [--arenas 8] [--samples 300]

Why: ``bench_vector`` measures a served decision's CPU beyond the in-process one, and
``zenoh_floor`` how much of that the transport alone takes. The rest is this project's
Python per request (encode, decode, the service around the arenas), and what that costs
depends less on how much it does than on where it runs: right after the server's arenas
stepped (or, in the client, right after the wait for the server), the caches hold the
simulation's data and every line of the request's code and objects is fetched again.

Each piece of a ``vstep`` request and its reply, for K arenas, is timed in this thread's
CPU (``time.thread_time_ns``), median over samples, in three states:

* ``warm``: samples back to back (what a microbenchmark of the code alone would say);
* ``after_step``: K in-process arenas step once before every sample (what a served
  request meets);
* ``swept``: a 32 MiB array is summed before every sample (caches emptied).

The pieces: the client encodes the request, the server decodes it, the server's whole
``ArenaService.handle`` around the arenas (their ``step`` replaced by a copy of a recorded
result, so only the service's own work is timed), the server encodes the reply, the client
decodes it, and the client's whole ``VecRM.step`` around the transport (a ``VecRM`` of a
real server whose link then answers at once with the recorded reply). The last row adds
the two wholes: the Python a served request costs beyond the arenas and Zenoh. Also
printed: the CPU of K in-process decisions with random valid actions, so each cost reads
as a share of what the request carries. Prints a Markdown table and writes
bench/out/request_cost.json.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bench.common import arena_count, at_least, machine, table, write_json
from neuronsmae.client.vec_rm import VecRM
from neuronsmae.protocol import messages as wire
from neuronsmae.server.arena import Arena
from neuronsmae.server.serving.service import ArenaService
from neuronsmae.server.vec import VecArena

SWEEP_BYTES = 32 << 20
STATES = ("warm", "after_step", "swept")
SESSION = "b" * 32


def cpu_us(fn: Callable[[], Any], before: Callable[[], Any], samples: int) -> float:
    """Median CPU µs of ``fn`` in this thread, ``before`` run (untimed) ahead of each call."""
    times = []
    for _ in range(samples):
        before()
        start = time.thread_time_ns()
        fn()
        times.append(time.thread_time_ns() - start)
    return statistics.median(times) / 1e3


class AnsweringLink:
    """A link whose every request is answered at once with one recorded reply."""

    def __init__(self, reply: bytes) -> None:
        self.reply = reply

    def send(self, payload: bytes, timeout: float) -> AnsweringLink:
        return self

    def result(self) -> bytes:
        return self.reply


def run(k: int, samples: int) -> tuple[list[dict[str, Any]], float]:
    """One row per piece (µs in each state) and the CPU µs of K in-process decisions."""
    local = VecArena(seed=1, num_envs=k)
    service = ArenaService(Arena, seed=1, arenas=k)
    remote = VecRM(seed=1, num_envs=k)
    rng = np.random.default_rng(1)
    try:
        service._build(1, {})
        service.handle(wire.encode_request(wire.Configure(seed=1, arenas=k), SESSION))
        service.handle(wire.encode_request(wire.VReset(), SESSION))
        local.reset()
        remote.reset()
        vec = service._vec
        actions = np.zeros((k, vec.get_env_info()["n_agents"]), dtype=np.int64)
        obs, rewards, dones, infos = vec.step(actions)
        vec.step = lambda *a, **kw: (  # type: ignore[method-assign]
            obs.copy(),
            rewards.copy(),
            dones.copy(),
            [dict(i) for i in infos],
        )
        request = wire.encode_request(wire.VStep(actions=actions), SESSION)
        value = {"obs": obs, "state": vec.get_state(), "avail_actions": vec.get_avail_actions(),
                 "rewards": rewards, "dones": dones, "infos": infos}  # fmt: skip
        reply = wire.encode_reply(wire.OkReply(value))
        remote._conns[0].link = AnsweringLink(reply)  # type: ignore[assignment]

        def local_step() -> None:
            avail = local.get_avail_actions()
            local.step((avail * rng.random(avail.shape)).argmax(-1))

        pieces: dict[str, Callable[[], Any]] = {
            "client: encode request": lambda: wire.encode_request(wire.VStep(actions), SESSION),
            "server: decode request": lambda: wire.decode_request(request),
            "server: handle, arenas aside": lambda: service.handle(request),
            "server: encode reply": lambda: wire.encode_reply(wire.OkReply(value)),
            "client: decode reply": lambda: wire.decode_reply(reply),
            "client: VecRM.step, transport aside": lambda: remote.step(actions),
        }
        sweep = np.ones(SWEEP_BYTES // 8)
        befores: dict[str, Callable[[], Any]] = {
            "warm": lambda: None,
            "after_step": local_step,
            "swept": sweep.sum,
        }
        rows = []
        for name, fn in pieces.items():
            row: dict[str, Any] = {"piece": name}
            for state in STATES:
                row[f"{state}_us"] = round(cpu_us(fn, befores[state], samples), 1)
            rows.append(row)
        decisions_us = cpu_us(local_step, lambda: None, samples)
    finally:
        remote.close()
        local.close()
        service.close()
    total: dict[str, Any] = {"piece": "both wholes: handle + VecRM.step"}
    for state in STATES:
        key = f"{state}_us"
        total[key] = round(rows[2][key] + rows[5][key], 1)
    return [*rows, total], decisions_us


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--arenas", type=arena_count, default=8, help="K arenas per request")
    parser.add_argument(
        "--samples", type=at_least(1), default=300, help="timed calls per piece/state"
    )
    args = parser.parse_args()
    rows, decisions_us = run(args.arenas, args.samples)
    print(f"CPU µs per request of {args.arenas} arenas (median of {args.samples}):")
    print(table(rows, ["piece", *(f"{s}_us" for s in STATES)]))
    print(f"{args.arenas} in-process decisions: {decisions_us:,.0f} µs of CPU")
    report = {
        "arenas": args.arenas,
        "samples": args.samples,
        "rows": rows,
        "in_process_decisions_us": round(decisions_us, 1),
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('request_cost', report)}")


if __name__ == "__main__":
    main()
