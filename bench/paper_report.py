"""The paper table's report: the records of ``bench.paper_table`` as Markdown tables.

One table for ``--preset paper`` (the released learner; the paper's figure beside each
cell), one for this project's learner, the shape of the results (does easy > middle > hard
hold, and VDN ≥ QMIX > IQL, at the released test context and, for runs re-tested there, at
the training context), the compute the runs took, and any tests added later with
``--test-at``. Every cell is the mean over seeds ± the half-width of its 95 % Student-t
interval, then each seed's figure.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from typing import Any

from scipy import stats

from neuronsmae.trainers.run.plot import PAPER_WIN_RATE as PAPER

ALGS = ("iql", "vdn", "qmix")
LEVELS = ("easy", "middle", "hard")
RELEASED = ("0", "1")
"""The released build's levels, the rows of run_dr.sh (VDN only)."""
LEARNERS = ("paper", "defaults", "defaults_released", "paper_dr")
"""``paper``: ``--preset paper``; ``defaults``: this project's learner at its own contexts;
``defaults_released``: the same learner trained and tested at the released contexts;
``paper_dr``: ``--preset paper`` trained with the released ``--dr_coef`` (coef drawn per
episode from {0.5, 0.7, 1, 1.4, 1.7, 2}; run_dr.sh), tested as ``paper``."""
PROJECT = ("defaults", "defaults_released")
"""The learners of the project's table."""
LIKE_FOR_LIKE_SEEDS = 1
"""Seeds the like-for-like row (``defaults_released``) expects per level: one each (#42);
more where more are recorded."""
TEST_FIELDS = ("win_rate", "draw_rate", "loss_rate", "released_win_rate", "mean_return")
"""What a record keeps of each test, beside its episode count."""
RELEASED_TEST = "main"
"""The paper preset's main test: coef 1.5 (the released ``coef_ts``)."""
TRAINED_TEST = "coef=0.5"
"""The re-test at the paper preset's training context (``--test-at coef=0.5``)."""


def interval(rates: Sequence[float]) -> tuple[float, float | None]:
    """The mean of ``rates`` and the half-width of its 95 % Student-t interval over the
    seeds (None for fewer than two)."""
    mean = statistics.fmean(rates)
    if len(rates) < 2:
        return mean, None
    sem = statistics.stdev(rates) / math.sqrt(len(rates))
    return mean, float(stats.t.ppf(0.975, len(rates) - 1)) * sem


def _rated(runs: Sequence[dict[str, Any]], test: str, field: str) -> list[dict[str, Any]]:
    return [r for r in runs if field in r["test"].get(test, {})]


def cell(runs: Sequence[dict[str, Any]], test: str, seeds: int, field: str = "win_rate") -> str:
    """One table cell: mean ± 95 % interval over seeds, then each seed's figure; ``—`` with
    no run, and the count of seeds when some are missing."""
    runs = _rated(runs, test, field)
    if not runs:
        return "—"
    rates = [r["test"][test][field] for r in runs]
    mean, half = interval(rates)
    head = f"{mean:.3f}" if half is None else f"{mean:.3f} ± {half:.3f}"
    each = ", ".join(f"s{r['seed']} {r['test'][test][field]:.3f}" for r in runs)
    missing = f"; {len(runs)} of {seeds} seeds" if len(runs) < seeds else ""
    return f"{head} ({each}{missing})"


def outcomes(runs: Sequence[dict[str, Any]], test: str) -> str:
    """The referee's win / draw / loss rates, each the mean over seeds."""
    runs = _rated(runs, test, "win_rate")
    if not runs:
        return "—"
    means = [statistics.fmean(r["test"][test][k] for r in runs)
             for k in ("win_rate", "draw_rate", "loss_rate")]  # fmt: skip
    return " / ".join(f"{m:.3f}" for m in means)


def runs_of(records: list[dict[str, Any]], alg: str, level: str, learner: str) -> list[dict]:
    """The records of one cell and learner, by seed."""
    mine = [r for r in records if (r["alg"], r["level"], r["learner"]) == (alg, level, learner)]
    return sorted(mine, key=lambda r: r["seed"])


def _cells() -> list[tuple[str, str]]:
    """The paper preset's rows: the paper's nine, then the released levels (VDN)."""
    return [(level, alg) for level in LEVELS for alg in ALGS] + [(lv, "vdn") for lv in RELEASED]


def paper_table(records: list[dict[str, Any]], seeds: int) -> list[str]:
    """``--preset paper``: the released rule at coef 1.5, the referee's outcomes beside it,
    the released rule at coef 1.0; the paper's figure first."""
    lines = [
        "| level | alg | paper | released rule, coef 1.5 | referee win / draw / loss, "
        "coef 1.5 | released rule, coef 1.0 |",
        "|---|---|---|---|---|---|",
    ]
    for level, alg in _cells():
        runs = runs_of(records, alg, level, "paper")
        paper = PAPER.get(level, {}).get(alg)
        lines.append(
            f"| {level} | {alg.upper()} | {'—' if paper is None else f'{paper:.2f}'} | "
            f"{cell(runs, RELEASED_TEST, seeds, 'released_win_rate')} | "
            f"{outcomes(runs, RELEASED_TEST)} | "
            f"{cell(runs, 'coef=1.0', seeds, 'released_win_rate')} |"
        )
    return lines


def project_table(records: list[dict[str, Any]], seeds: int, like_seeds: int) -> list[str]:
    """This project's learner (VDN by default): at its own contexts (μ 0.1) tested at coef
    1.0 and 1.5 by the referee, and like for like with the released experiment."""
    lines = [
        "| level | alg | paper | own contexts (μ 0.1), coef 1.0 | own contexts, coef 1.5 | "
        "trained at μ 0.5, coef 0.5; released rule, coef 1.5 |",
        "|---|---|---|---|---|---|",
    ]
    algs = [a for a in ALGS if any(r["alg"] == a and r["learner"] in PROJECT for r in records)]
    for level in LEVELS:
        for alg in algs:
            own = runs_of(records, alg, level, "defaults")
            like = runs_of(records, alg, level, "defaults_released")
            lines.append(
                f"| {level} | {alg.upper()} | {PAPER[level][alg]:.2f} | "
                f"{cell(own, 'main', seeds)} | {cell(own, 'coef=1.5', seeds)} | "
                f"{cell(like, RELEASED_TEST, like_seeds, 'released_win_rate')} |"
            )
    return lines


def _like_for_like_seeds(records: list[dict[str, Any]]) -> int:
    """Seeds expected per cell of the like-for-like row: :data:`LIKE_FOR_LIKE_SEEDS`, or as
    many as are recorded for it."""
    recorded = {r["seed"] for r in records if r["learner"] == "defaults_released"}
    return max(LIKE_FOR_LIKE_SEEDS, len(recorded))


def _mean(
    records: list[dict[str, Any]], alg: str, level: str, test: str = RELEASED_TEST
) -> float | None:
    runs = _rated(runs_of(records, alg, level, "paper"), test, "released_win_rate")
    if not runs:
        return None
    return statistics.fmean(r["test"][test]["released_win_rate"] for r in runs)


def dr_table(records: list[dict[str, Any]], seeds: int) -> list[str]:
    """``--preset paper`` trained with ``--dr_coef`` beside the same cell trained at coef 0.5
    (its rows: the cells with a ``paper_dr`` run), both tested as released."""
    lines = [
        "| level | alg | trained at coef 0.5: released rule, coef 1.5 | trained at coef 0.5–2 "
        "(`--dr_coef`): released rule, coef 1.5 | `--dr_coef`: referee win / draw / loss, "
        "coef 1.5 | `--dr_coef`: released rule, coef 1.0 |",
        "|---|---|---|---|---|---|",
    ]
    for level, alg in _cells():
        dr = runs_of(records, alg, level, "paper_dr")
        if not dr:
            continue
        fixed = runs_of(records, alg, level, "paper")
        lines.append(
            f"| {level} | {alg.upper()} | "
            f"{cell(fixed, RELEASED_TEST, seeds, 'released_win_rate')} | "
            f"{cell(dr, RELEASED_TEST, seeds, 'released_win_rate')} | "
            f"{outcomes(dr, RELEASED_TEST)} | {cell(dr, 'coef=1.0', seeds, 'released_win_rate')} |"
        )
    return lines


def shape(records: list[dict[str, Any]], test: str = RELEASED_TEST) -> list[str]:
    """Whether the paper's orderings hold in the paper preset's means of one test (released
    rule; by default the main test, coef 1.5): easy > middle > hard for each algorithm, VDN
    ≥ QMIX > IQL at each level."""
    lines = []
    for alg in ALGS:
        means = [_mean(records, alg, level, test) for level in LEVELS]
        if None not in means:
            holds = means[0] > means[1] > means[2]  # type: ignore[operator]
            said = ", ".join(f"{m:.3f}" for m in means)  # type: ignore[str-format]
            verdict = "holds" if holds else "does not hold"
            lines.append(
                f"- {alg.upper()}: easy, middle, hard {said}: easy > middle > hard {verdict}"
            )
    for level in LEVELS:
        iql, vdn, qmix = (_mean(records, alg, level, test) for alg in ALGS)
        if None not in (iql, vdn, qmix):
            verdict = "holds" if vdn >= qmix > iql else "does not hold"  # type: ignore[operator]
            lines.append(
                f"- {level}: VDN {vdn:.3f}, QMIX {qmix:.3f}, IQL {iql:.3f}: "
                f"VDN ≥ QMIX > IQL {verdict}"
            )
    return lines


def compute(records: list[dict[str, Any]], learner: str, cells: int) -> str:
    """What the recorded runs of ``learner`` took."""
    done = [r for r in records if r["learner"] == learner]
    hours = sum(r["wall_minutes"] for r in done) / 60
    # Records written before the runs counted their sampled transitions say nothing of them.
    samples = (
        f" on {sum(r['samples'] for r in done) / 1e6:,.0f} million sampled transitions"
        if done and all("samples" in r for r in done)
        else ""
    )
    return (
        f"{learner}: {len(done)} of {cells} runs recorded, {sum(r['episodes'] for r in done):,} "
        f"training episodes ({sum(r['env_steps'] for r in done) / 1e6:.1f} million decisions), "
        f"{sum(r['updates'] for r in done):,} gradient updates{samples}, "
        f"{hours:.1f} h of wall time (training and tests)."
    )


def report(table: dict[str, Any], seeds: int = 3) -> str:
    """The whole report as Markdown (see the module docstring)."""
    records = table["records"]
    like = _like_for_like_seeds(records)
    lines = ["`--preset paper` (the released learner), 200 held-out episodes per test:", ""]
    lines += paper_table(records, seeds)
    order = shape(records)
    if order:
        lines += ["", "The paper's orderings in these means (released rule, coef 1.5):", ""]
        lines += order
    trained = shape(records, TRAINED_TEST)
    if trained:
        lines += ["", "The same orderings at the training context (released rule, coef 0.5; "
                  "the re-tests, `--test-at coef=0.5`):", ""]  # fmt: skip
        lines += trained
    if any(r["learner"] == "paper_dr" for r in records):
        lines += ["", "`--preset paper` trained with the released `--dr_coef` (coef drawn per "
                  "episode from {0.5, 0.7, 1, 1.4, 1.7, 2}), 30,000 episodes:", ""]  # fmt: skip
        lines += dr_table(records, seeds)
    if any(r["learner"] in PROJECT for r in records):
        lines += ["", "This project's learner, 30 minutes a run:", ""]
        lines += project_table(records, seeds, like)
    lines += ["", "Compute:", ""]
    # the paper's nine cells per seed, and the released levels once each (the issue's
    # one seed; bench.paper_table runs them only when asked, --levels 0 1)
    cells = len(LEVELS) * len(ALGS) * seeds + len(RELEASED)
    lines.append("- " + compute(records, "paper", cells))
    for learner, per_cell in (("defaults", seeds), ("defaults_released", like)):
        if any(r["learner"] == learner for r in records):
            lines.append("- " + compute(records, learner, len(LEVELS) * per_cell))
    dr_runs = {(r["alg"], r["level"], r["seed"]) for r in records if r["learner"] == "paper_dr"}
    if dr_runs:
        lines.append("- " + compute(records, "paper_dr", len(dr_runs)))
    return "\n".join(lines + retests(records))


def _contexts(key: str) -> str:
    """A ``--test-at`` key as a header: ``coef=0.5;Friction_coeff=0.3`` → ``coef 0.5,
    Friction_coeff 0.3``; a bot as whom the runs play: ``level=1`` → ``against 1``."""
    parts = (p.split("=", 1) for p in key.split(";"))
    return ", ".join(f"against {v}" if k == "level" else f"{k} {v}" for k, v in parts)


def _column_order(key: str) -> tuple[int, int]:
    """Where a ``--test-at`` column stands: contexts first, in the order tested (a stable
    sort), then the bots from the weakest, ``0``, ``1``, ``easy``, ``middle``, ``hard``,
    whatever order their re-tests ran in; other bots last."""
    if not key.startswith("level="):
        return (0, 0)
    bots = (*RELEASED, *LEVELS)
    bot = key.removeprefix("level=")
    return (1, bots.index(bot) if bot in bots else len(bots))


def retests(records: list[dict[str, Any]]) -> list[str]:
    """A table for the tests added by ``--test-at`` (none: no lines)."""
    done = [r for r in records if r["learner"] == "paper"]
    tested = dict.fromkeys(k for r in done for k in r["test"])  # in the order tested
    extra = sorted((k for k in tested if k not in ("main", "coef=1.0")), key=_column_order)
    if not extra:
        return []
    head = " | ".join(f"released rule, {_contexts(k)}" for k in extra)
    lines = [
        "",
        "The recorded runs' final weights tested again on the same 200 held-out episodes at "
        "other contexts or against other bots (`python -m bench.paper_table --test-at "
        "KEY=VALUE`): each column changes only what it names in the run's test (coef 1.5, "
        "its own bot); coef 0.5 is where they trained:",
        "",
        f"| level | alg | released rule, coef 1.5 | {head} |",
    ]
    lines.append("|---|---|---|" + "---|" * len(extra))
    for level, alg in _cells():
        runs = runs_of(done, alg, level, "paper")
        n = max(len(runs), 1)
        cells = " | ".join(cell(runs, k, n, "released_win_rate") for k in ("main", *extra))
        lines.append(f"| {level} | {alg.upper()} | {cells} |")
    return lines
