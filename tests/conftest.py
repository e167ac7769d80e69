"""Test tiers: tests that start servers, routers, Ray or a training run are marked ``slow``.

``python -m pytest -q -m "not slow"`` is the quick tier for the edit–test loop; CI runs
everything. A test is marked here by the fixtures it uses (:data:`SLOW_FIXTURES`, directly
or through other fixtures) or by the ``ray`` mark; tests that launch processes on their own
carry ``@pytest.mark.slow`` where they are written. Tests that run another framework on
NeuronsMAE are marked ``interop`` (``-m interop`` runs just them); they need the ``interop``
extra and are skipped without it.

Torch runs every test's networks on one intra-op thread, as the trainer's learner and
workers do (``TrainConfig.torch_threads``): the tests' networks are tiny, and two spinning
OpenMP threads on a 2-core machine with anything else running make a 1-second test take a
minute.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")  # read by torch when a test first imports it

SLOW_FIXTURES = frozenset({"start_server", "spawn", "routed", "local_ray", "loopback_ray"})
"""Fixtures that start server or router processes, or Ray."""
SLOW_MARKS = ("ray", "interop")
"""Marks that imply ``slow``: a local Ray, another framework run on NeuronsMAE."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        fixtures = set(getattr(item, "fixturenames", ()))
        marked = any(item.get_closest_marker(m) is not None for m in SLOW_MARKS)
        if fixtures & SLOW_FIXTURES or marked:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="module")
def local_ray() -> Iterator[None]:
    """A local Ray of 2 CPUs for one test module (``pytest.mark.usefixtures("local_ray")``)."""
    import ray  # the train extra: imported only by the modules that use it

    ray.init(
        num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING
    )
    yield
    ray.shutdown()
