"""numba's kernel cache follows every source a kernel depends on, not only its own file."""

from __future__ import annotations

import ast
import getpass
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numba
import pytest

import neuronsmae
from neuronsmae.protocol import errors
from neuronsmae.server.sim import kernel_cache

PACKAGE_DIRS = {
    "neuronsmae": Path(neuronsmae.__file__).parent,
    "neuronsmae/server": kernel_cache.SIM.parent,
    "neuronsmae/protocol": Path(errors.__file__).parent,
}
"""Where each part of the installed package lives (the repository maps folders to them)."""


def _imported_modules(path: Path, package: str) -> set[str]:
    """Names of the ``neuronsmae`` modules ``path`` imports (``from X import y`` counts ``X.y``
    when that is a module), with relative imports resolved against ``package``."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}".rstrip(".")
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)
    return {n for n in names if n.startswith("neuronsmae.") and _is_module(n)}


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:  # ``X.y`` where y is a name inside module X
        return False


def test_every_module_a_kernel_module_imports_is_hashed() -> None:
    hashed = {p.resolve() for p in kernel_cache.kernel_sources()}
    for path in sorted(hashed):
        if path.parent.name not in ("sim", "task"):
            continue
        package = f"neuronsmae.server.{path.parent.name}"
        for name in _imported_modules(path, package):
            spec = importlib.util.find_spec(name)
            assert spec is not None and spec.origin is not None
            origin = Path(spec.origin).resolve()
            if origin.name != "__init__.py":
                assert origin in hashed, f"{path.name} imports {name}, which the hash misses"


def test_every_cached_kernel_lives_in_a_hashed_file() -> None:
    hashed = {p.resolve() for p in kernel_cache.kernel_sources()}
    for root in {*PACKAGE_DIRS.values(), Path(neuronsmae.__file__).parents[1] / "trainers"}:
        for path in root.rglob("*.py"):
            if "cache=True" in path.read_text():
                assert path.resolve() in hashed, path


def test_numba_caches_under_the_hash_of_this_source_tree() -> None:
    directory = kernel_cache.configure()
    assert str(directory) == numba.config.CACHE_DIR
    assert directory.name == kernel_cache.source_hash()
    fallback = Path(tempfile.gettempdir()) / f"neuronsmae-numba-{getpass.getuser()}"
    assert directory.parent in (kernel_cache.cache_root(), fallback)  # fallback: not writable


PROBE = """
import json, numba, numpy as np
import neuronsmae
from neuronsmae.server.task.observations import vector_obs_kernel
out = np.empty((1, 11))
poses = np.array([[4.04, 2.24, 0.0], [4.04, 2.24, 0.0]])
vector_obs_kernel(
    np.array([[0, 1]]), 1, poses, np.array([0]), np.zeros((0, 1, 1, 2)), 0.0,
    np.full(2, 600.0), np.full(2, 600.0), np.full(2, 185.0), np.full(2, 370.0),
    np.ones((1, 1), bool), -1.0, out,
)
print(json.dumps({
    "package": neuronsmae.__file__,
    "cache": numba.config.CACHE_DIR,
    "hits": sum(vector_obs_kernel.stats.cache_hits.values()),
    "x": float(out[0, 0]),
}))
"""
"""Runs ``vector_obs_kernel``, whose position columns are centred on ``HALF_X``, half of
``FIELD_X``, a constant of another file (``sim/field.py``): x = 4.04 reads 0.0 on the
8.08 m field."""


@pytest.mark.slow
def test_editing_a_dependency_recompiles_the_kernel(tmp_path: Path) -> None:
    tree = tmp_path / "tree"
    for part, source in PACKAGE_DIRS.items():
        target = tree / part
        if part == "neuronsmae":
            target.mkdir(parents=True)
            shutil.copy(source / "__init__.py", target / "__init__.py")
        else:
            shutil.copytree(source, target, ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def probe() -> dict:
        done = subprocess.run(
            [sys.executable, "-c", PROBE], env=env, cwd=tmp_path, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
        return json.loads(done.stdout)

    first, again = probe(), probe()
    assert first["package"].startswith(str(tree))  # the copy ran, not the installed package
    assert first["x"] == 0.0 and again["x"] == 0.0
    assert first["hits"] == 0 and again["hits"] == 1  # compiled once, then read from the cache
    assert first["cache"] == again["cache"]
    field = tree / "neuronsmae/server/sim/field.py"
    text = field.read_text()
    assert "FIELD_X = 8.08\n" in text
    field.write_text(text.replace("FIELD_X = 8.08\n", "FIELD_X = 4.04\n"))
    edited = probe()
    assert edited["x"] == 1.0  # the new constant, not the cached kernel's
    assert edited["hits"] == 0 and edited["cache"] != first["cache"]


def _appender(path: Path, pause: float = 0.0) -> list[str]:
    """A command that waits ``pause`` seconds, then appends one line to ``path``."""
    code = f"import time; time.sleep({pause}); open({str(path)!r}, 'a').write('ran\\n')"
    return [sys.executable, "-c", code]


def test_compile_aside_runs_once_per_marker(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    marker, log = tmp_path / "compiled-x", tmp_path / "log"
    monkeypatch.setattr(kernel_cache, "compiled_marker", lambda: marker)
    assert kernel_cache.compile_aside(_appender(log)) is True
    assert kernel_cache.compile_aside(_appender(log)) is False
    assert log.read_text() == "ran\n" and marker.exists()


def test_compile_aside_compiles_once_when_many_start_together(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    marker, log = tmp_path / "compiled-x", tmp_path / "log"
    monkeypatch.setattr(kernel_cache, "compiled_marker", lambda: marker)
    with ThreadPoolExecutor(4) as pool:
        ran = list(pool.map(lambda _: kernel_cache.compile_aside(_appender(log, 0.5)), range(4)))
    assert sorted(ran) == [False, False, False, True]
    assert log.read_text() == "ran\n"


def test_a_failed_compile_leaves_no_marker(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    marker = tmp_path / "compiled-x"
    monkeypatch.setattr(kernel_cache, "compiled_marker", lambda: marker)
    with pytest.raises(subprocess.CalledProcessError):
        kernel_cache.compile_aside([sys.executable, "-c", "raise SystemExit(3)"])
    assert not marker.exists()


def test_the_marker_changes_when_a_kernel_source_is_touched(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = tmp_path / "stepper.py"
    source.write_text("x = 1\n")
    monkeypatch.setattr(kernel_cache, "kernel_sources", lambda: [source])
    before = kernel_cache.compiled_marker()
    assert before == kernel_cache.compiled_marker()
    stat = source.stat()
    os.utime(source, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    assert kernel_cache.compiled_marker() != before
