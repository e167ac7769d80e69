"""The tables of docs/results.md: learning results, each a function of docs/data."""

from __future__ import annotations

import statistics
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bench.pages.common import (
    ROOT,
    TEST_EPISODES,
    Data,
    count,
    iqm,
    machines,
    measured,
    present,
    rate,
    span,
    table,
    win_of,
)


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
            rate(win_of(r, "latest")),
            rate(win_of(r, "best")),
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
    met = sum(win_of(r, "latest") >= target for _, r in runs)
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
    return f"{span(win_of(r, 'latest') for _, r in runs)} ({len(runs)} runs)"


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
        (task, cmd, count(r["episodes"]), rate(win_of(r, "latest")), rate(win_of(r, "best")))
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
                f"tested against `{level}`: {rate(win_of(run, 'latest'))} final, "
                f"{rate(win_of(run, 'best'))} best-validated."
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
        f"`{entry['report_command']}`. Machines: {machines(recorded['records'])}"
        + (f"; commits {', '.join(commits)}" if commits else "")
        + ".*"
    )
    return "\n".join([report(recorded), "", source])


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
        rows.append((task, level, alg, str(len(runs)), both, f"{iqm(rates):.3f}", each, trained))
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
        else list(dict.fromkeys(_command_pattern(r["command"]) for r in records if "command" in r))
    )
    said = ", ".join(f"`{c}`" for c in commands) or "an unrecorded command"
    machine = meta.get("machine")
    machine = machine if isinstance(machine, str) else machines([meta] if machine else records)
    source = f"*Measured by {said} on {machine}: [`{file}`](data/{file}).*"
    return "\n".join([*benchmarl_table(records), "", source])


def baselines_iqm(data: Data) -> str:
    """Every learner on one scale: per task, the IQM of its runs' test win rates with a 95 %
    bootstrap interval, and the probability of improvement between pairs."""
    srcs = present(data, "baselines_iqm")
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


def scripted_continuous(data: Data) -> str:
    """Scripted continuous-action teams against a bot on the held-out test episodes: win
    rate with its Wilson interval, draws and losses."""
    srcs = present(data, "scripted_continuous")
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


TABLES: dict[str, Callable[[Data], str]] = {
    "main_job": main_job,
    "variants": variants,
    "selfplay": selfplay,
    "league": league,
    "paper_table": paper_table,
    "benchmarl": benchmarl,
    "baselines_iqm": baselines_iqm,
    "scripted_continuous": scripted_continuous,
}
"""docs/results.md's placeholders and their functions."""
