"""A run's evaluations in marl-eval's JSON format, for the ecosystem's standard reporting.

marl-eval (InstaDeep's ``marl_eval``, the format BenchMARL's JSON logger also writes) reads
one nested object: environment → task → algorithm → run → ``step_<i>`` entries of the
periodic evaluations (``step_count`` and each metric as a list of values) and
``absolute_metrics`` (the final figures)::

    {"neuronsmae": {"coop_abstract_easy": {"vdn": {"seed_1": {
        "step_0": {"step_count": 24817, "win_rate": [0.62], "return": [11.3]}, ...,
        "absolute_metrics": {"win_rate": [0.91], "return": [24.0]}}}}}}

:func:`run_json` builds it from a run's ``config.json`` and ``eval.csv``: the validation
evaluations are the steps, the final test of the final weights (at the main evaluation
contexts) the absolute metrics; the win rate is the run's headline rule (``eval.win_rule``).
A run writes it to ``marl_eval.json`` in its directory at the end (:data:`FILE`);
:func:`merge` joins several files into one.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from neuronsmae.trainers.run.config_groups import WIN_RULES
from neuronsmae.trainers.run.records import read_records

FILE = "marl_eval.json"
"""The file a run writes its marl-eval JSON to, in its directory."""
ENVIRONMENT = "neuronsmae"
"""The environment's name in the JSON (BenchMARL's name for the family)."""


def task_name(config: Mapping[str, Any]) -> str:
    """The run's task as the BenchMARL task family names it, with the bot: ``coop_abstract``,
    ``coop_discrete``, ``coop_continuous`` or ``coop_3v3`` (3 v 3 abstract), then
    ``_<level>``; other team sizes say theirs (``coop_abstract_1v1``)."""
    arena = config.get("arena", {})
    blue, red = arena.get("n_blue", 2), arena.get("n_red", 2)
    space = arena.get("action_space", "abstract")
    if (blue, red) == (3, 3) and space == "abstract":
        name = "coop_3v3"
    else:
        name = f"coop_{space}" + ("" if (blue, red) == (2, 2) else f"_{blue}v{red}")
    return f"{name}_{config.get('level', 'easy')}"


def run_json(run_dir: str | Path, algorithm: str | None = None) -> dict[str, Any]:
    """The marl-eval JSON of the run in ``run_dir`` (see the module docstring); its
    algorithm is named ``algorithm`` (default: the run's ``alg``)."""
    run_dir = Path(run_dir)
    config = json.loads((run_dir / "config.json").read_text())
    figure = WIN_RULES[config.get("eval", {}).get("win_rule", "referee")]
    needs = ("episodes", "env_steps", "split", "weights", "contexts", "mean_return", figure)
    rows = [r for r in read_records(run_dir / "eval.csv", needs) if r["contexts"] == "main"]
    run: dict[str, Any] = {}
    steps = [r for r in rows if r["split"] == "validation"]
    for i, row in enumerate(steps):
        run[f"step_{i}"] = {
            "step_count": int(float(row["env_steps"])),
            "win_rate": [float(row[figure])],
            "return": [float(row["mean_return"])],
        }
    tests = [r for r in rows if (r["split"], r["weights"]) == ("test", "latest")]
    if tests:
        final = tests[-1]
        run["absolute_metrics"] = {
            "win_rate": [float(final[figure])],
            "return": [float(final["mean_return"])],
        }
    name = algorithm or str(config["alg"])
    seed = f"seed_{config['seed']}"
    return {ENVIRONMENT: {task_name(config): {name: {seed: run}}}}


def merge(documents: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """One marl-eval JSON holding every run of ``documents`` (a run named twice keeps the
    last)."""
    out: dict[str, Any] = {}
    for doc in documents:
        for env, tasks in doc.items():
            for task, algorithms in tasks.items():
                for alg, runs in algorithms.items():
                    out.setdefault(env, {}).setdefault(task, {}).setdefault(alg, {}).update(runs)
    return out


def write(run_dir: str | Path) -> Path:
    """Write the run's marl-eval JSON to ``run_dir / FILE`` and return the path."""
    path = Path(run_dir) / FILE
    path.write_text(json.dumps(run_json(run_dir), indent=1))
    return path


class MarlEvalFormatError(ValueError):
    """A document that is not in marl-eval's JSON format (the message says where)."""


def check_format(document: Mapping[str, Any]) -> None:
    """Raise :class:`MarlEvalFormatError` unless ``document`` is what marl-eval's loader
    takes: environment → task → algorithm → run objects; a run's keys ``step_<i>`` (each
    with an integer ``step_count``) and ``absolute_metrics``; every metric a list of
    numbers, and one set of metrics in every step and in the absolute metrics of a run."""

    def fail(where: str, what: str) -> None:
        raise MarlEvalFormatError(f"{where}: {what}")

    for env, tasks in document.items():
        for task, algorithms in _objects(tasks, env, fail):
            for alg, runs in _objects(algorithms, f"{env}/{task}", fail):
                for run, entries in _objects(runs, f"{env}/{task}/{alg}", fail):
                    where = f"{env}/{task}/{alg}/{run}"
                    metrics: set[str] | None = None
                    for key, entry in _objects(entries, where, fail):
                        if key != "absolute_metrics" and not (
                            key.startswith("step_") and key[5:].isdigit()
                        ):
                            fail(f"{where}/{key}", "a run holds step_<i> and absolute_metrics")
                        if key != "absolute_metrics" and type(entry.get("step_count")) is not int:
                            fail(f"{where}/{key}", "a step needs an integer step_count")
                        names = set(entry) - {"step_count"}
                        for name in names:
                            values = entry[name]
                            if not isinstance(values, list) or not all(
                                isinstance(v, (int, float)) and not isinstance(v, bool)
                                for v in values
                            ):
                                fail(f"{where}/{key}/{name}", "a metric is a list of numbers")
                        if metrics is not None and names != metrics:
                            fail(f"{where}/{key}", f"metrics {sorted(names)} != {sorted(metrics)}")
                        metrics = names


def _objects(value: Any, where: str, fail: Any) -> list[tuple[str, Any]]:
    if not isinstance(value, Mapping) or not value:
        fail(where, "expected a non-empty object")
    return list(value.items())
