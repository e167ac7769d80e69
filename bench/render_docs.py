"""docs/results.md and docs/benchmarks.md, rendered from the JSON in docs/data.

    python -m bench.render_docs            # write the pages
    python -m bench.render_docs --check    # exit 1 naming each page that differs

Each page is its template, ``docs/templates/<page>.md``: the prose, with a line
``{{name}}`` wherever a table goes. The script replaces each such line by ``TABLES[name]``
applied to the data: one small function per table, reading the files that
``docs/data/tables.json`` lists for it and saying the command that wrote them and the machine
it ran on. The paper's table is ``bench.paper_report.report`` of ``docs/data/paper_table.json``.
A new run is added by listing its file under its table in ``tables.json`` (or, for the paper
table, by ``bench.paper_table`` adding its record) and rendering again.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
from collections.abc import Callable, Iterable, Sequence
from functools import cached_property
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PAGES = ("results.md", "benchmarks.md")
PLACEHOLDER = re.compile(r"^\{\{\s*(\w+)\s*\}\}$", re.MULTILINE)
TEST_EPISODES = 200
"""Held-out test episodes behind every win rate on the pages."""


class Data:
    """docs/data under ``root``: its files, and what tables.json says of each table."""

    def __init__(self, root: Path) -> None:
        self.dir = root / "docs" / "data"

    @cached_property
    def index(self) -> dict[str, Any]:
        return json.loads((self.dir / "tables.json").read_text())

    def table(self, name: str) -> dict[str, Any]:
        return self.index["tables"][name]

    def load(self, file: str) -> Any:
        """A JSON file, or a JSON-lines file as its list of records."""
        text = (self.dir / file).read_text()
        if file.endswith(".jsonl"):
            return [json.loads(line) for line in text.splitlines() if line.strip()]
        return json.loads(text)

    def sources(self, name: str, role: str | None = None) -> list[dict[str, Any]]:
        found = self.table(name)["sources"]
        return [s for s in found if role is None or s.get("role") == role]

    def machine(self, source: dict[str, Any]) -> str:
        """The machine a source ran on, in words, with its speed where known."""
        m = self.index["machines"][source["machine"]]
        speed = source.get("decision_us", m.get("decision_us"))
        per = f"; {speed} µs per in-process abstract decision" if speed else ""
        return f"{m['name']} ({m['description']}{per})"


# --- formatting ------------------------------------------------------------------------


def rate(x: float) -> str:
    """A win rate or ratio as measured over 200 episodes: 0.88, 0.915, 0.90."""
    text = f"{x:.3f}"
    return text[:-1] if text.endswith("0") else text


def span(values: Iterable[float], fmt: Callable[[float], str] = rate) -> str:
    """``lo–hi`` of the values, or the one value."""
    values = sorted(values)
    lo, hi = fmt(values[0]), fmt(values[-1])
    return lo if lo == hi else f"{lo}–{hi}"


def count(n: float) -> str:
    return f"{round(n):,}"


def table(head: Sequence[str], rows: Iterable[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _when(data: Data, source: dict[str, Any]) -> str:
    """The source's date and commit: from tables.json, else from the file."""
    raw = data.load(source["file"])
    raw = raw if isinstance(raw, dict) else {}
    date = source.get("date") or str(raw.get("written") or raw.get("time") or "")[:10]
    commit = source.get("commit") or str(raw.get("commit") or "")[:7]
    return ", ".join(p for p in (date, f"commit {commit}" if commit else "") if p)


def measured(data: Data, sources: Sequence[dict[str, Any]]) -> str:
    """Where a table comes from: per machine, each command with its files, their dates and
    commits."""
    machines: dict[tuple[str, str], dict[str, list[dict[str, Any]]]] = {}
    for s in sources:
        by_command = machines.setdefault((data.machine(s), s.get("note", "")), {})
        by_command.setdefault(s["command"], []).append(s)
    parts = []
    for (machine, note), by_command in machines.items():
        runs = "; ".join(_files(data, command, group) for command, group in by_command.items())
        parts.append(f"on {machine}{f', {note}' if note else ''}: {runs}")
    return "*Measured " + "; ".join(parts) + ".*"


def _files(data: Data, command: str, sources: Sequence[dict[str, Any]]) -> str:
    """``command`` → each file, with the date and commit once where all files share them (a
    source whose table gives each row's command says so with ``"in_rows": true``)."""
    cmd = command if sources[0].get("in_rows") else f"`{command}`"
    whens = [_when(data, s) for s in sources]
    links = [f"[`{s['file']}`](data/{s['file']})" for s in sources]
    if len(set(whens)) == 1:
        tail = f" ({whens[0]})" if whens[0] else ""
        return f"{cmd} → {', '.join(links)}{tail}"
    each = [f"{link} ({when})" if when else link for link, when in zip(links, whens, strict=True)]
    return f"{cmd} → {', '.join(each)}"


def _test(run: dict[str, Any], which: str) -> float:
    return run["test"][which]["win_rate"]


# --- results.md --------------------------------------------------------------------------


def _main_job_runs(data: Data) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """(file, run) for each run of the main job in tables.json, in the order listed."""
    return [
        (f, run)
        for s in data.sources("main_job")
        for f in [data.load(s["file"])]
        for run in f["runs"]
    ]


def main_job(data: Data) -> str:
    """The README's main job: one row per run, and whether each meets the target."""
    runs = _main_job_runs(data)
    rows = [
        (
            str(i),
            str(f.get("commit", ""))[:7],
            count(r["episodes"]),
            count(r["updates"]),
            rate(_test(r, "latest")),
            rate(_test(r, "best")),
        )
        for i, (f, r) in enumerate(runs, 1)
    ]
    head = (
        "run",
        "commit",
        "training episodes",
        "learner updates",
        f"final (test, {TEST_EPISODES})",
        f"best-validated (test, {TEST_EPISODES})",
    )
    target = data.table("main_job")["target"]
    met = sum(_test(r, "latest") >= target for _, r in runs)
    verdict = (
        f"Target, a final test win rate of at least {rate(target)}: met in {met} of "
        f"{len(runs)} runs."
    )
    return "\n".join(
        [*table(head, rows), "", verdict, "", measured(data, data.sources("main_job"))]
    )


def headline(root: Path = ROOT) -> str:
    """The README's headline figure: the main job's final test win rates."""
    runs = _main_job_runs(Data(root))
    return f"{span(_test(r, 'latest') for _, r in runs)} ({len(runs)} runs)"


def variants(data: Data) -> str:
    """Task variants beside the default task, same machine and budget."""
    entry = data.table("variants")
    base = entry["baseline"]
    base_run = next(r for r in data.load(base["file"])["runs"] if r["name"] == base["run"])
    rows = [(base["task"], f"`{base['command']}`", base_run)]
    for src in data.sources("variants"):
        for run in data.load(src["file"])["runs"]:
            if run["name"] in entry["runs"]:
                what = entry["runs"][run["name"]]
                rows.append((what["task"], f"`{what['command']}`", run))
    head = (
        "task",
        "command",
        "training episodes",
        f"final (test, {TEST_EPISODES})",
        f"best-validated (test, {TEST_EPISODES})",
    )
    body = [
        (task, cmd, count(r["episodes"]), rate(_test(r, "latest")), rate(_test(r, "best")))
        for task, cmd, r in rows
    ]
    return "\n".join([*table(head, body), "", measured(data, data.sources("variants"))])


def selfplay(data: Data) -> str:
    """The self-play run: its episodes and its test against the evaluation bot."""
    lines = []
    for src in data.sources("selfplay"):
        for run in data.load(src["file"])["runs"]:
            opponents = run["config"]["opponent"]
            level = run["config"]["level"]
            lines.append(
                f"Trained against `{opponents}`: {count(run['episodes'])} training episodes; "
                f"tested against `{level}`: {rate(_test(run, 'latest'))} final, "
                f"{rate(_test(run, 'best'))} best-validated."
            )
    return "\n".join([*lines, "", measured(data, data.sources("selfplay"))])


def _player(name: str) -> str:
    """``run/self_00004504`` → snapshot 4,504; ``run/checkpoint`` → final; ``bot:x`` → bot x."""
    if name.startswith("bot:"):
        return f"bot `{name[4:]}`"
    leaf = name.rsplit("/", 1)[-1]
    return f"snapshot {int(leaf.split('_')[-1]):,}" if leaf.startswith("self_") else "final"


def league(data: Data) -> str:
    """OpenSkill ratings, best first, with each player's score against each bot."""
    src = data.sources("league")[0]
    lg = data.load(src["file"])
    bots = [p for p in lg["players"] if p.startswith("bot:")]
    where = {p: i for i, p in enumerate(lg["players"])}

    def score(player: str, bot: str) -> str:
        value = lg["matrix"][where[player]][where[bot]]
        return "—" if value is None else f"{value:.2f}"

    head = ("player", "μ", "σ", *(f"score against {_player(b)}" for b in bots))
    rows = [
        (
            _player(r["player"]),
            f"{r['mu']:.2f}",
            f"{r['sigma']:.2f}",
            *(score(r["player"], b) for b in bots),
        )
        for r in sorted(lg["ratings"], key=lambda r: -r["mu"])
    ]
    about = (
        f"{lg['games']} games a pair, both colours, seed {lg['seed']}; {lg['model']}. "
        "A score is the fraction of games won, draws counting half."
    )
    return "\n".join([*table(head, rows), "", about, "", measured(data, [src])])


def _machines(records: Sequence[dict[str, Any]]) -> str:
    """The machines the records name, each with its count of runs."""
    seen: dict[str, int] = {}
    for r in records:
        m = r.get("machine") or {}
        key = (
            m if isinstance(m, str) else f"{m.get('cpus', '?')} CPUs, Python {m.get('python', '?')}"
        )
        seen[key] = seen.get(key, 0) + 1
    return "; ".join(f"{k} ({n} run{'s' * (n != 1)})" for k, n in seen.items()) or "none yet"


def paper_table(data: Data) -> str:
    """``bench.paper_report.report`` of the recorded table, with its commands and machines."""
    from bench.paper_report import report
    from bench.paper_table import load

    entry = data.table("paper_table")
    recorded = load(data.dir / entry["file"])
    commits = sorted({str(r.get("commit", ""))[:7] for r in recorded["records"]} - {""})
    source = (
        f"*Measured by `{entry['command']}` (the project's learner: "
        f"`{entry['defaults_command']}`), resumable, one record per finished run in "
        f"[`{entry['file']}`](data/{entry['file']}); this section is "
        f"`{entry['report_command']}`. Machines: {_machines(recorded['records'])}"
        + (f"; commits {', '.join(commits)}" if commits else "")
        + ".*"
    )
    return "\n".join([report(recorded), "", source])


def _iqm(values: Sequence[float]) -> float:
    """The interquartile mean: the mean of the middle half (rliable's 25 % trimmed mean)."""
    from scipy import stats

    return float(stats.trim_mean(values, 0.25))


def _win_rate(record: dict[str, Any]) -> float:
    test = record.get("test")
    return test["win_rate"] if isinstance(test, dict) else record["test_win_rate"]


def benchmarl_table(records: Sequence[dict[str, Any]]) -> list[str]:
    """Per task, red's bot and algorithm, over seeds: the test win rate's mean ± 95 %
    Student-t interval, its IQM and each seed's figure (a record without ``level`` played
    easy, the baselines' default)."""
    from bench.paper_report import interval

    cells: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for r in records:
        cells.setdefault((r["task"], str(r.get("level", "easy")), r["algorithm"]), []).append(r)
    rows = []
    for (task, level, alg), runs in sorted(cells.items()):
        runs = sorted(runs, key=lambda r: r["seed"])
        rates = [_win_rate(r) for r in runs]
        mean, half = interval(rates)
        both = f"{mean:.3f}" if half is None else f"{mean:.3f} ± {half:.3f}"
        each = ", ".join(f"s{r['seed']} {_win_rate(r):.3f}" for r in runs)
        frames = [r["frames"] for r in runs if "frames" in r]
        trained = count(round(statistics.fmean(frames))) if frames else "—"
        rows.append((task, level, alg, str(len(runs)), both, f"{_iqm(rates):.3f}", each, trained))
    head = ("task", "bot", "algorithm", "seeds", "test win rate, mean ± 95 %", "IQM", "each seed",
            "frames trained (mean)")  # fmt: skip
    return table(head, rows)


PATTERN_FLAGS = {"--algorithms": "ALG", "--tasks": "TASK", "--seeds": "SEED"}
"""A run's command as the page shows it: these flags' values become a placeholder (one
pattern for a table of runs); ``--runs`` and ``--out``, the machine's own paths, are left
out."""


def _command_pattern(command: str) -> str:
    out: list[str] = []
    hidden = False  # the words after a flag whose values are not shown
    for word in command.split():
        if word.startswith("--"):
            hidden = word in ("--runs", "--out") or word in PATTERN_FLAGS
            if word not in ("--runs", "--out"):
                out += [word, PATTERN_FLAGS[word]] if word in PATTERN_FLAGS else [word]
        elif not hidden:
            out.append(word)
    return " ".join(out)


def benchmarl(data: Data) -> str:
    """BenchMARL's baselines, or that they are not measured yet. The file is a list of
    records or ``{"command", "machine", "records"}``; a record may carry its own command and
    machine."""
    file = data.table("benchmarl")["file"]
    raw = data.load(file) if (data.dir / file).exists() else []
    meta = raw if isinstance(raw, dict) else {"records": raw}
    records = meta["records"]
    if not records:
        return "Not measured yet."
    commands = (
        [meta["command"]]
        if "command" in meta
        else sorted({_command_pattern(r["command"]) for r in records if "command" in r})
    )
    said = ", ".join(f"`{c}`" for c in commands) or "an unrecorded command"
    machine = meta.get("machine")
    machine = machine if isinstance(machine, str) else _machines([meta] if machine else records)
    source = f"*Measured by {said} on {machine}: [`{file}`](data/{file}).*"
    return "\n".join([*benchmarl_table(records), "", source])


# --- benchmarks.md -----------------------------------------------------------------------


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


def _present(data: Data, name: str) -> list[dict[str, Any]]:
    """The sources of table ``name`` whose files exist (none yet: not measured)."""
    return [src for src in data.sources(name) if (data.dir / src["file"]).exists()]


def baselines_iqm(data: Data) -> str:
    """Every learner on one scale: per task, the IQM of its runs' test win rates with a 95 %
    bootstrap interval, and the probability of improvement between pairs."""
    srcs = _present(data, "baselines_iqm")
    if not srcs:
        return "Not measured yet."
    result = data.load(srcs[0]["file"])
    head = ("learner", "task", "runs", "IQM of the test win rate", "95 % interval")
    body = [
        (r["learner"], r["task"], str(r["runs"]), rate(r["iqm"]),
         f"{rate(r['ci95'][0])}–{rate(r['ci95'][1])}")
        for r in result["iqm"]
    ]  # fmt: skip
    pairs = [p for p in result["improvement"] if p["x"] < p["y"]]
    head2 = ("X", "Y", "P(X > Y)", "95 % interval")
    body2 = [(p["x"], p["y"], rate(p["p"]), f"{rate(p['ci95'][0])}–{rate(p['ci95'][1])}")
             for p in pairs]  # fmt: skip
    return "\n".join([*table(head, body), "", *table(head2, body2), "", measured(data, srcs)])


def learner(data: Data) -> str:
    """Each learner's updates/s and sampled transitions/s, and the faster step's gain over
    the step before it, per device and thread count."""
    srcs = _present(data, "learner")
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


def scripted_continuous(data: Data) -> str:
    """Scripted continuous-action teams against a bot on the held-out test episodes: win
    rate with its Wilson interval, draws and losses."""
    srcs = _present(data, "scripted_continuous")
    if not srcs:
        return "Not measured yet."
    head = ("team", "bot", "episodes", "win rate (95 %)", "draws", "losses")
    body = [
        (r["team"], r["level"], str(r["episodes"]),
         f"{rate(r['win_rate'])} ({rate(r['win_ci95'][0])}–{rate(r['win_ci95'][1])})",
         rate(r["draw_rate"]), rate(r["loss_rate"]))
        for src in srcs for r in data.load(src["file"])["rows"]
    ]  # fmt: skip
    return "\n".join([*table(head, body), "", measured(data, srcs)])


def training_scaling(data: Data) -> str:
    """Training episodes and updates per minute against the worker count."""
    srcs = _present(data, "training_scaling")
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
    srcs = _present(data, "decoupled")
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
    "main_job": main_job,
    "variants": variants,
    "selfplay": selfplay,
    "league": league,
    "paper_table": paper_table,
    "benchmarl": benchmarl,
    "simulation": simulation,
    "transport": transport,
    "vector": vector,
    "vector_by_k": vector_by_k,
    "vector_overhead": vector_overhead,
    "sampling": sampling,
    "sampling_layouts": sampling_layouts,
    "scaling": scaling,
    "bots": bots,
    "baselines_iqm": baselines_iqm,
    "scripted_continuous": scripted_continuous,
    "learner": learner,
    "training_scaling": training_scaling,
    "decoupled": decoupled,
}
"""Each placeholder's function: docs/data → the Markdown that replaces the placeholder."""


# --- pages -------------------------------------------------------------------------------


def banner(page: str) -> str:
    return (
        f"<!-- Generated by `python -m bench.render_docs` from docs/templates/{page} and "
        "docs/data/: edit those, not this page. -->"
    )


def render(page: str, root: Path = ROOT) -> str:
    """The page as its template and the data make it."""
    data = Data(root)
    template = (root / "docs" / "templates" / page).read_text()

    def fill(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in TABLES:
            raise KeyError(f"docs/templates/{page}: no table function for {{{{{name}}}}}")
        return TABLES[name](data)

    body = PLACEHOLDER.sub(fill, template)
    return f"{banner(page)}\n{body}"


def stale(root: Path = ROOT, pages: Sequence[str] = PAGES) -> list[str]:
    """The pages whose committed text differs from what the data renders."""
    out = []
    for page in pages:
        path = root / "docs" / page
        if not path.exists() or path.read_text() != render(page, root):
            out.append(f"docs/{page}")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.render_docs",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 naming each page that differs"
    )
    parser.add_argument("--root", type=Path, default=ROOT, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.check:
        old = stale(args.root, PAGES)
        for page in old:
            print(f"{page} is stale: run python -m bench.render_docs", file=sys.stderr)
        return 1 if old else 0
    for page in PAGES:
        path = args.root / "docs" / page
        text = render(page, args.root)
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
            print(f"wrote docs/{page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
