"""What the page tables share: docs/data and its index, and the formatting of figures and of
where they were measured."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from functools import cached_property
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
"""The repository's root."""
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


def when(data: Data, source: dict[str, Any]) -> str:
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
        runs = "; ".join(files(data, command, group) for command, group in by_command.items())
        parts.append(f"on {machine}{f', {note}' if note else ''}: {runs}")
    return "*Measured " + "; ".join(parts) + ".*"


def files(data: Data, command: str, sources: Sequence[dict[str, Any]]) -> str:
    """``command`` → each file, with the date and commit once where all files share them (a
    source whose table gives each row's command says so with ``"in_rows": true``)."""
    cmd = command if sources[0].get("in_rows") else f"`{command}`"
    whens = [when(data, s) for s in sources]
    links = [f"[`{s['file']}`](data/{s['file']})" for s in sources]
    if len(set(whens)) == 1:
        tail = f" ({whens[0]})" if whens[0] else ""
        return f"{cmd} → {', '.join(links)}{tail}"
    each = [f"{link} ({when})" if when else link for link, when in zip(links, whens, strict=True)]
    return f"{cmd} → {', '.join(each)}"


def win_of(run: dict[str, Any], which: str) -> float:
    """A ``neuronsmae-train`` run's test win rate with its ``"latest"`` or ``"best"`` weights."""
    return run["test"][which]["win_rate"]


def machines(records: Sequence[dict[str, Any]]) -> str:
    """The machines the records name, each with its count of runs."""
    seen: dict[str, int] = {}
    for r in records:
        m = r.get("machine") or {}
        key = (
            m if isinstance(m, str) else f"{m.get('cpus', '?')} CPUs, Python {m.get('python', '?')}"
        )
        seen[key] = seen.get(key, 0) + 1
    return "; ".join(f"{k} ({n} run{'s' * (n != 1)})" for k, n in seen.items()) or "none yet"


def iqm(values: Sequence[float]) -> float:
    """The interquartile mean: the mean of the middle half (rliable's 25 % trimmed mean)."""
    from scipy import stats

    return float(stats.trim_mean(values, 0.25))


def present(data: Data, name: str) -> list[dict[str, Any]]:
    """The sources of table ``name`` whose files exist (none yet: not measured)."""
    return [src for src in data.sources(name) if (data.dir / src["file"]).exists()]
