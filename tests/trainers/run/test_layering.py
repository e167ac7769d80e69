"""The trainers load no server module: they reach the simulation through the protocol."""

from __future__ import annotations

import subprocess
import sys

MODULES = (
    "neuronsmae.trainers",
    "neuronsmae.trainers.run.cli",
    "neuronsmae.trainers.run.train",
    "neuronsmae.trainers.core.features",
    "neuronsmae.trainers.core.symmetry",
    "neuronsmae.trainers.play.evaluate",
    "neuronsmae.trainers.play.match",
    "neuronsmae.trainers.play.league",
    "neuronsmae.trainers.play.policies",
    "neuronsmae.trainers.run.competition",
)


def test_importing_the_trainers_loads_no_server_module() -> None:
    code = (
        f"import sys\nfor name in {MODULES!r}:\n    __import__(name)\n"
        "print(sorted(m for m in sys.modules if m.startswith('neuronsmae.server')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "[]"
