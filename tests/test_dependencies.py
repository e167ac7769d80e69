"""The dependency rule, checked on every import of the package's files.

Dependencies point one way: trainers → client → protocol ← server. Inside the trainers the
sub-packages are ordered core → play → run (each uses only those before it), and no two
files import each other, directly or around a loop. Every ``import`` and ``from ... import``
counts, at module level, inside functions and under ``TYPE_CHECKING`` alike: a loop that
only type checking walks is still a loop a reader has to follow.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"server": "server", "client": "client", "protocol": "protocol", "trainers": "trainers"}
"""Import name under ``neuronsmae.`` → its folder."""
ALLOWED = {
    "protocol": {"protocol"},
    "server": {"server", "protocol"},
    "client": {"client", "protocol"},
    "trainers": {"trainers", "client", "protocol"},
}
"""What each package may import (trainers → client → protocol ← server)."""
TRAINER_ORDER = ("core", "play", "run")
"""The trainers' sub-packages, each allowed to import only those before it."""


def modules() -> dict[str, Path]:
    """Every module of the four packages by its import name."""
    found = {}
    for package, folder in PACKAGES.items():
        for path in (ROOT / folder).rglob("*.py"):
            parts = [p for p in path.relative_to(ROOT / folder).with_suffix("").parts]
            parts = [p for p in parts if p != "__init__"]
            found[".".join(["neuronsmae", package, *parts])] = path
    return found


MODULES = modules()


def imported(name: str, path: Path) -> Iterator[str]:
    """The package modules ``name`` imports anywhere in its file (each name resolved to the
    deepest module it is, ``from a import b`` to ``a.b`` when that is a module)."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, *([base] if base else [])])
            targets = [base, *(f"{base}.{a.name}" for a in node.names)]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:
                target = target.rpartition(".")[0]
            if target and target != name:
                yield target


GRAPH = {name: set(imported(name, path)) for name, path in MODULES.items()}


def _part(name: str, depth: int) -> str:
    return name.split(".")[depth] if len(name.split(".")) > depth else ""


def test_every_import_follows_trainers_client_protocol_server() -> None:
    wrong = [
        f"{a} imports {b}"
        for a, targets in GRAPH.items()
        for b in sorted(targets)
        if _part(b, 1) not in ALLOWED[_part(a, 1)]
    ]
    assert not wrong, "\n".join(wrong)


def test_the_trainers_sub_packages_are_ordered_core_play_run() -> None:
    def rank(name: str) -> int | None:
        sub = _part(name, 2)
        return TRAINER_ORDER.index(sub) if sub in TRAINER_ORDER else None

    wrong = []
    for a, targets in GRAPH.items():
        if _part(a, 1) != "trainers" or rank(a) is None:
            continue
        for b in targets:
            if _part(b, 1) == "trainers" and rank(b) is not None and rank(b) > rank(a):  # type: ignore[operator]
                wrong.append(f"{a} imports {b}")
    assert not wrong, "\n".join(wrong)


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph)))
    try:
        for v in graph:
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return found


def test_no_two_files_import_each_other_around_a_loop() -> None:
    assert cycles(GRAPH) == []


def test_the_walker_sees_imports_inside_functions_and_loops() -> None:
    """The checks above would pass vacuously on a walker that saw nothing."""
    assert "neuronsmae.client" in GRAPH["neuronsmae.trainers.play.rollout"]  # in a function
    assert "neuronsmae.protocol.interface" in GRAPH["neuronsmae.client.source"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_trainer_file_names_the_server_package() -> None:
    """Not even by a string: the client's ``env="inprocess"`` is how trainers reach it."""
    out = subprocess.run(
        ["git", "grep", "-n", "neuronsmae.server", "--", "trainers/"],
        cwd=ROOT, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if out.returncode not in (0, 1):  # not a git checkout (an sdist): read the files instead
        pytest.skip("not a git checkout")
    assert out.stdout == ""


def test_trainers_hold_at_most_twelve_files_at_their_top_level() -> None:
    top = [p.name for p in (ROOT / "trainers").iterdir() if p.is_file()]
    assert len(top) <= 12, top
