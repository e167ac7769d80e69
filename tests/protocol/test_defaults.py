"""The shared defaults are written once (protocol/defaults.py) and read everywhere."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

from neuronsmae.client import RM, VecRM
from neuronsmae.protocol import defaults
from neuronsmae.protocol.launch import ServerCommand
from neuronsmae.server import Arena, VecArena
from neuronsmae.server.serving.cli import _parser as server_parser
from neuronsmae.server.serving.service import ArenaService

ROOT = Path(__file__).resolve().parents[2]


SHARED = (defaults.DEFAULT_PORT, defaults.DEFAULT_SEED, defaults.DEFAULT_HOST)
NAMES = {"port", "base_port", "seed", "host"}
"""Settings that take a shared default: parameters, fields and options of these names."""


def _default_literals(path: Path) -> list[str]:
    """Where a file writes a literal default for a setting of :data:`NAMES`: a parameter's,
    a dataclass field's or an argparse option's (``--port``, ``--base-port``, ...)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        pairs: list[tuple[str, ast.expr]] = []
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            args = node.args
            positional = [*args.posonlyargs, *args.args]
            named = positional[len(positional) - len(args.defaults) :]
            pairs += zip([a.arg for a in named], args.defaults, strict=True)
            pairs += [
                (a.arg, d) for a, d in zip(args.kwonlyargs, args.kw_defaults, strict=True) if d
            ]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value:
            pairs.append((node.target.id, node.value))
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            flag = str(node.args[0].value).lstrip("-").replace("-", "_")
            pairs += [(flag, k.value) for k in node.keywords if k.arg == "default"]
        for name, value in pairs:
            if name in NAMES and isinstance(value, ast.Constant) and value.value in SHARED:
                found.append(f"{path.relative_to(ROOT)}:{value.lineno}: {name}={value.value!r}")
    return found


def test_no_file_spells_a_shared_default_again() -> None:
    files = [
        p for d in ("server", "client", "protocol", "trainers") for p in (ROOT / d).rglob("*.py")
    ]
    found = [hit for p in files if p.name != "defaults.py" for hit in _default_literals(p)]
    assert found == []


def test_the_entry_points_take_the_shared_defaults() -> None:
    def default(fn: object, name: str) -> object:
        return inspect.signature(fn).parameters[name].default  # type: ignore[arg-type]

    for cls in (RM, VecRM, Arena, VecArena, ArenaService):
        assert default(cls, "seed") == defaults.DEFAULT_SEED, cls
    assert default(RM, "port") is None  # None: a private server; RM(port=10000) as released
    assert default(RM, "time_scale") == defaults.RELEASED_TIME_SCALE == 100.0
    assert default(VecRM, "time_scale") == default(ArenaService, "time_scale") == 0.0
    assert ServerCommand(port=1).time_scale == defaults.UNPACED
    args = server_parser().parse_args([])
    assert (args.port, args.seed, args.time_scale) == (10000, 1234, 100.0)
