"""The tables of docs/benchmarks.md: speed and scaling, each a function of docs/data."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from bench.pages.common import (
    Data,
    count,
    measured,
    present,
    rate,
    span,
    table,
)


def simulation(data: Data) -> str:
    """In-process decisions per second by configuration, and the speed targets."""
    src = data.sources("simulation")[0]
    rows = {r["configuration"]: r for r in data.load(src["file"])["rows"]}
    body = [
        (
            name,
            count(r["decisions/s (median)"]),
            count(r["× real time"]),
            f"{r['% of bare drive']:.1f}",
        )
        for name, r in rows.items()
    ]
    head = ("configuration", "decisions/s (median)", "× real time", "% of bare drive")
    targets = []
    for t in data.table("simulation")["targets"]:
        r = rows[t["configuration"]]
        speed, share = r["decisions/s (median)"], r["% of bare drive"]
        met = speed >= t["decisions_per_s"] and share >= t["percent_of_bare_drive"]
        targets.append(
            f"- Target, {t['configuration']} 2 v 2: ≥ {t['decisions_per_s']} decisions/s and "
            f"≥ {t['percent_of_bare_drive']} % of bare drive: **{'met' if met else 'not met'}** "
            f"({count(speed)}, {share:.1f} %)."
        )
    return "\n".join([*table(head, body), "", *targets, "", measured(data, [src])])


def _server(result: dict[str, Any]) -> str:
    poll = result.get("busy_poll_us", 0.0)
    if not poll:
        return "sleeps between requests"
    return f"polls {poll / 1000:g} ms (`--busy-poll {poll:.0f}`)"


def transport(data: Data) -> str:
    """One query per decision against in process, with the bound the bare query allows."""
    src = data.sources("transport")[0]
    run = data.load(src["file"])
    head = (
        "config",
        "server",
        "in process decisions/s",
        "over Zenoh decisions/s",
        "ratio",
        "bound (free server and client)",
    )
    rows = [
        (
            r["config"],
            _server(r),
            count(r["in_process_decisions_per_s"]),
            count(r["zenoh_decisions_per_s"]),
            f"{r['ratio']:.3f}",
            f"{r['bound_ratio']:.3f}",
        )
        for r in run["results"]
    ]
    target = run["target_ratio"]
    best = max(r["ratio"] for r in run["results"])
    bounds = span((r["bound_ratio"] for r in run["results"]), lambda x: f"{x:.3f}")
    verdict = (
        f"- Target, {target:g} of the in-process rate: **{'met' if best >= target else 'not met'}**"
        f" (best {best:.3f}); the bound, in-process µs / (in-process µs + bare query µs), is "
        f"{bounds}."
    )
    lines = [*table(head, rows), "", verdict, *_busy_poll(run), "", *_round_trips(run)]
    return "\n".join([*lines, "", measured(data, [src])])


def _busy_poll(run: dict[str, Any]) -> list[str]:
    """What polling buys, per configuration measured both ways."""
    by = {(r["config"], bool(r.get("busy_poll_us"))): r for r in run["results"]}
    lines = []
    for config in dict.fromkeys(r["config"] for r in run["results"]):
        off, on = by.get((config, False)), by.get((config, True))
        if off and on:
            a, b = off["zenoh_decisions_per_s"], on["zenoh_decisions_per_s"]
            lines.append(
                f"- Busy polling, {config}: {count(a)} → {count(b)} decisions/s "
                f"({(b / a - 1) * 100:+.0f} %)."
            )
    return lines


FLOOR_NAMES = {
    "zenoh query": "bare Zenoh query (no NeuronsMAE code)",
    "zenoh query, server polling": "the same, the server polling",
    "zenoh publish/subscribe": "bare Zenoh publish, answered by a publish",
    "tcp socket": "bare TCP socket, Python to Python",
}


def _round_trips(run: dict[str, Any]) -> list[str]:
    """Round-trip times of the same run: the bare transports and ``RM``'s ping."""
    rows = [
        (FLOOR_NAMES.get(f["path"], f["path"]), f"{f['median_us']:.1f} µs", f"{f['p99_us']:.1f} µs")
        for f in run["floor"]
    ]
    ping = run["ping"]
    rows.append(
        (
            "`RM`'s ping (codec, envelope, session check)",
            f"{ping['median_us']:.1f} µs",
            f"{ping['p99_us']:.1f} µs",
        )
    )
    return table(("round trip", "median", "p99"), rows)


def vector(data: Data) -> str:
    """Served against in process at K arenas per request, CPU and memory, and the targets."""
    srcs = data.sources("vector")
    runs = [(i, data.load(s["file"])) for i, s in enumerate(srcs, 1)]
    lines = sorted((r["envs"], i, r) for i, run in runs for r in run["rows"])
    head = (
        "K",
        "run",
        "in process decisions/s",
        "served decisions/s",
        "CPU µs per decision, in process / served",
        "CPU ratio (IQR)",
        "server memory per arena, idle / after play",
    )
    body = [
        (
            str(k),
            str(i),
            count(r["in_process_decisions_per_s"]),
            count(r["served_decisions_per_s"]),
            f"{r['in_process_cpu_us']:.0f} / {r['served_cpu_us']:.0f}",
            f"{r['cpu_ratio']:.3f} ({r['cpu_ratio_iqr'][0]:.2f}–{r['cpu_ratio_iqr'][1]:.2f})",
            f"{r['server_rss_mb_per_arena_idle']:.0f} / "
            f"{r['server_rss_mb_per_arena_played']:.0f} MB",
        )
        for k, i, r in lines
    ]
    targets = runs[0][1]["targets"]
    at8 = [r for _, _, r in lines if r["envs"] == 8]
    rss = max(r["server_rss_mb_per_arena_played"] for r in at8)
    cpu = [r["cpu_ratio"] for r in at8]
    checks = [
        f"- Target, memory at K = 8: ≤ {targets['rss_mb_per_arena_at_8']:g} MB per arena: "
        f"**{'met' if rss <= targets['rss_mb_per_arena_at_8'] else 'not met'}** "
        f"({rss:.0f} MB after play).",
        f"- Target, CPU ratio at K = 8: ≥ {targets['cpu_ratio_at_8']:g}: "
        f"**{'met' if min(cpu) >= targets['cpu_ratio_at_8'] else 'not met'}** "
        f"({span(cpu, lambda x: f'{x:.3f}')}).",
    ]
    return "\n".join([*table(head, body), "", *checks, "", measured(data, srcs)])


def vector_by_k(data: Data) -> str:
    """Every K in one run: CPU ratio and server memory per arena."""
    src = data.sources("vector_by_k")[0]
    rows = data.load(src["file"])["rows"]
    head = ("K", *(str(r["envs"]) for r in rows))
    body = [
        ("CPU ratio, in process / served", *(f"{r['cpu_ratio']:.3f}" for r in rows)),
        (
            "server memory per arena after play",
            *(f"{r['server_rss_mb_per_arena_played']:.0f} MB" for r in rows),
        ),
    ]
    return "\n".join([*table(head, body), "", measured(data, [src])])


def vector_overhead(data: Data) -> str:
    """Where a K-arena request's CPU goes beyond its K decisions, piece by piece."""
    k = data.table("vector_overhead")["arenas"]
    served = [
        r["served_cpu_us"] - r["in_process_cpu_us"]
        for s in data.sources("vector_overhead", "vector")
        for r in data.load(s["file"])["rows"]
        if r["envs"] == k
    ]
    floors = [data.load(s["file"]) for s in data.sources("vector_overhead", "floor")]
    costs = [data.load(s["file"]) for s in data.sources("vector_overhead", "request_cost")]
    whole = [next(r for r in c["rows"] if r["piece"].startswith("both wholes")) for c in costs]

    def us(values: Iterable[float]) -> str:
        return span(values, lambda x: f"{x:.0f}")

    def bound(key: str) -> str:
        return span((f[key]["cpu_ratio_bound"] for f in floors), lambda x: f"{x:.3f}")

    def floor(key: str, per: str) -> str:
        return us(f[key][per] for f in floors)

    rows = [
        ("served beyond in process (`bench_vector`)", us(d * k for d in served), us(served), "—"),
        (
            f"a bare Zenoh query, 6 KB reply, to a server that spins {k} decisions' time "
            "(`zenoh_floor`, hold `spin`)",
            floor("vector_floor", "floor_us_per_query"),
            floor("vector_floor", "floor_us_per_decision"),
            bound("vector_floor"),
        ),
        (
            f"the same, to a server that steps {k} real arenas (hold `arenas`, their own CPU "
            "subtracted)",
            floor("vector_floor_arenas", "floor_us_per_query"),
            floor("vector_floor_arenas", "floor_us_per_decision"),
            bound("vector_floor_arenas"),
        ),
        (
            "NeuronsMAE's own request code, both sides, timed alone: warm / right after an arena "
            "step (`request_cost`)",
            f"{us(w['warm_us'] for w in whole)} / {us(w['after_step_us'] for w in whole)}",
            f"{us(w['warm_us'] / k for w in whole)} / {us(w['after_step_us'] / k for w in whole)}",
            "—",
        ),
    ]
    head = (f"per K = {k} request", "µs of CPU", "µs per decision", "ratio it alone allows")
    return "\n".join([*table(head, rows), "", measured(data, data.sources("vector_overhead"))])


def _sampling_rows(run: dict[str, Any]) -> dict[tuple, dict[str, Any]]:
    return {
        (r["sampling"], r["workers"], r["envs"], r["env"], r.get("servers", 1)): r
        for r in run["rows"]
    }


def sampling(data: Data) -> str:
    """Env steps per second per worker, policy included, against the bare arena."""
    src = data.sources("sampling")[0]
    run = data.load(src["file"])
    rows = _sampling_rows(run)
    out = []
    for (kind, workers, envs, env, _), r in rows.items():
        if env == "remote":
            continue
        twin = rows.get((kind, workers, envs, "remote", 1))
        speed = count(r["steps_per_s_per_worker"])
        ratio = f"{r['ratio']:.3f}"
        if twin:
            speed += f" / {count(twin['steps_per_s_per_worker'])}"
            ratio += f" / {twin['ratio']:.3f}"
        arenas = "in process / served" if twin else "in process"
        out.append((kind, str(workers), str(envs), arenas, speed, ratio))
    head = (
        "sampling",
        "workers",
        "E",
        "arenas",
        "env steps/s per worker",
        "ratio to the bare arena",
    )
    target = run["target"]
    at = [
        r for k, r in rows.items() if k[0] == "Ray sampler" and k[2] == target["envs"] and k[1] == 1
    ]
    verdicts = ", ".join(
        f"{'in process' if r['env'] == 'inprocess' else 'served'} {r['ratio']:.3f} "
        f"({'met' if r['ratio'] >= target['ratio'] else 'not met'})"
        for r in at
    )
    check = (
        f"- Target, one Ray worker at E = {target['envs']}: ≥ {target['ratio']:g} of the bare "
        f"rate: {verdicts}."
    )
    return "\n".join([*table(head, out), "", check, "", measured(data, [src])])


SAMPLING_LAYOUTS = (
    ("in process", "inprocess", 1, 1),
    ("served, 1 server", "remote", 1, 1),
    ("served, 2 groups", "remote", 1, 2),
    ("served, 2 servers", "remote", 2, 1),
)
"""Columns of the layouts table: label, env, servers per worker, groups."""


def _layout_cell(rows: list[dict[str, Any]], env: str, servers: int, groups: int) -> str:
    for r in rows:
        if (r["env"], r.get("servers", 1), r.get("groups", 1)) == (env, servers, groups):
            return f"{r['ratio']:.3f} ({count(r['steps_per_s_per_worker'])})"
    return "—"


def sampling_layouts(data: Data) -> str:
    """One Ray worker's 8 arenas in process, or served on one server, in two groups or on two
    servers: a row per run, its machine named."""
    srcs = data.sources("sampling_layouts")
    body = []
    for src in srcs:
        run = data.load(src["file"])
        ray = [r for r in run["rows"] if r["sampling"] == "Ray sampler" and r["envs"] == 8]
        bare = next(r for r in run["rows"] if r["sampling"].startswith("bare"))
        name = data.index["machines"][src["machine"]]["name"]
        cells = [_layout_cell(ray, env, n, g) for _, env, n, g in SAMPLING_LAYOUTS]
        label = f"{name} (`{src['file']}`)"
        body.append((label, count(bare["steps_per_s_per_worker"]), *cells))
    head = ("run", "bare arena, env steps/s", *(c for c, *_ in SAMPLING_LAYOUTS))
    about = "Each cell: the ratio to the bare arena (env steps/s per worker); —: not measured."
    return "\n".join([*table(head, body), "", about, "", measured(data, srcs)])


def scaling(data: Data) -> str:
    """Aggregate decisions per second with N servers on one machine."""
    batched_src = data.sources("scaling", "batched")[0]
    one_src = data.sources("scaling", "one")[0]
    batched = data.load(batched_src["file"])
    one = {r["servers"]: r for r in data.load(one_src["file"])["results"]}
    envs = batched["results"][0]["envs_per_server"]
    head = (
        "servers",
        f"{envs} arenas per request: decisions/s",
        "CPU ms per decision",
        "one arena per request: decisions/s",
    )
    body = [
        (
            str(r["servers"]),
            count(r["decisions_per_s"]),
            f"{r['cpu_ms_per_decision']:.2f}",
            count(one[r["servers"]]["decisions_per_s"]) if r["servers"] in one else "—",
        )
        for r in batched["results"]
    ]
    projection = "; ".join(
        f"{p['workers']} pairs about {count(round(p['cpu_bound_decisions_per_s'], -2))} decisions/s"
        for p in batched["projection"]
    )
    note = (
        "The script's projection from the measured CPU per decision (not a measurement), "
        f"with a core per worker-and-server pair on a cluster: {projection}."
    )
    return "\n".join([*table(head, body), "", note, "", measured(data, [batched_src, one_src])])


def bots(data: Data) -> str:
    """Every pair of bots the script plays: blue's win rate at each seed."""
    src = data.sources("bots")[0]
    pairs: dict[tuple[str, str], dict[int, dict[str, Any]]] = {}
    for r in data.load(src["file"]):
        pairs.setdefault((r["blue"], r["red"]), {})[r["seed"]] = r
    seeds = sorted({s for by in pairs.values() for s in by})
    head = ("blue", "red", f"blue's win rate, seeds {' / '.join(map(str, seeds))}", "draws")
    body = [
        (
            f"`{b}`",
            f"`{r}`",
            " / ".join(f"{by[s]['blue_win_rate']:.3f}" if s in by else "—" for s in seeds),
            span((x["draw_rate"] for x in by.values()), lambda x: f"{x:.3f}"),
        )
        for (b, r), by in pairs.items()
    ]
    episodes = span((x["episodes"] for by in pairs.values() for x in by.values()), count)
    about = f"{episodes} episodes per pair and seed."
    return "\n".join([*table(head, body), "", about, "", measured(data, [src])])


def learner(data: Data) -> str:
    """Each learner's updates/s and sampled transitions/s, and the faster step's gain over
    the step before it, per device and thread count."""
    srcs = present(data, "learner")
    if not srcs:
        return "Not measured yet."
    rows = [row for src in srcs for row in data.load(src["file"])["rows"]]
    threads = sorted({r["threads"] or 0 for r in rows})
    cells: dict[tuple[str, str, int, str], dict[int, dict[str, Any]]] = {}
    for r in rows:  # one line per learner, batch and device; a column per thread count
        cells.setdefault((r["learner"], r["alg"], r["batch"], r["device"]), {})[
            r["threads"] or 0
        ] = r

    def ms(r: dict[str, Any] | None) -> str:
        if r is None:
            return "—"
        gain = f" ({r['speedup']:.2f}×)" if "speedup" in r else ""
        return f"{r['new']['ms_per_update']:.1f}{gain}"

    head = ("learner", "alg", "batch", "device",
            *(f"ms per update, {t or '—'} thread{'s' if t != 1 else ''} (speedup)"
              for t in threads),
            "transitions/s, most threads")  # fmt: skip
    body = [
        (learner_, alg.upper(), count(batch), device, *(ms(by.get(t)) for t in threads),
         count(by[max(by)]["new"]["transitions_per_s"]))
        for (learner_, alg, batch, device), by in cells.items()
    ]  # fmt: skip
    about = ("Batch: episodes for the defaults' learner, transitions for the released one. "
             "Medians of the repeats; the speedup is over the step as it was before the "
             "faster learner (the λ-returns by a loop over time steps, the points head's first "
             "form, batches drawn inline), timed in the same repeats. Run with "
             "`OMP_WAIT_POLICY=PASSIVE`, the setting for a learner that shares its cores with "
             "workers (OpenMP's default policy: docs/lab/benchmarks-log.md).")  # fmt: skip
    return "\n".join([*table(head, body), "", about, "", measured(data, srcs)])


def training_scaling(data: Data) -> str:
    """Training episodes and updates per minute against the worker count."""
    srcs = present(data, "training_scaling")
    if not srcs:
        return "Not measured yet."
    run = data.load(srcs[0]["file"])
    head = ("learner", "workers", "episodes/min", "env steps/min", "updates/min",
            "learner's share of the wall time")  # fmt: skip
    body = [
        (r["learner"], str(r["workers"]), count(r["episodes_per_min"]),
         count(r["env_steps_per_min"]), count(r["updates_per_min"]), f"{r['learner_share']:.2f}")
        for r in run["rows"]
    ]  # fmt: skip
    about = (f"{run['minutes']:g} minutes of training per row, arenas {run['env']}; "
             f"{run['cores']} cores for every worker count, so the larger counts are "
             "oversubscribed: the shape of the curve, not a cluster's speed.")  # fmt: skip
    return "\n".join([*table(head, body), "", about, "", measured(data, srcs)])


def decoupled(data: Data) -> str:
    """The main job with the learner inline and decoupled: episodes, updates and the test
    win rate in its 30 minutes, run by run in the order they ran."""
    srcs = present(data, "decoupled")
    if not srcs:
        return "Not measured yet."
    head = ("loop", "seed", "commit", "training episodes", "updates",
            "learner's share of the wall time", "test win rate (final weights)")  # fmt: skip
    body = []
    for src in srcs:
        run = data.load(src["file"])
        c = run["counters"]
        ratio = run["config"]["learner"].get("replay_ratio", 0.0)
        loop = f"decoupled (replay ratio {ratio:g})" if ratio > 0 else "inline (2 per episode)"
        body.append((loop, str(run["seed"]), src.get("commit", "—")[:7],
                     count(c["episodes"]), count(c["updates"]),
                     f"{c.get('learn_seconds', 0.0) / c['wall_seconds']:.2f}",
                     rate(run["final"]["win_rate"])))  # fmt: skip
    return "\n".join([*table(head, body), "", measured(data, srcs)])


TABLES: dict[str, Callable[[Data], str]] = {
    "simulation": simulation,
    "transport": transport,
    "vector": vector,
    "vector_by_k": vector_by_k,
    "vector_overhead": vector_overhead,
    "sampling": sampling,
    "sampling_layouts": sampling_layouts,
    "scaling": scaling,
    "bots": bots,
    "learner": learner,
    "training_scaling": training_scaling,
    "decoupled": decoupled,
}
"""docs/benchmarks.md's placeholders and their functions."""
