"""24 served rollout workers on a four-node Ray cluster (``ray.cluster_utils.Cluster``).

The paper sampled with 20-25 workers. Each node offers six units of a ``sampler`` resource
and workers require one, so the 24 workers must spread six per node; each worker launches
its own vector server (``env="remote"``, the default placement) as its own child process,
so the server runs on the worker's node. Every node is bound to 127.0.0.1 and the nodes
share this machine's cores, oversubscribed: the run is tiny (a few episodes, one arena per
worker, a 16-unit GRU).
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import psutil
import pytest
import ray
from ray.cluster_utils import Cluster

from neuronsmae.trainers.run.config import make_config
from neuronsmae.trainers.run.train import Trainer
from tests.trainers.conftest import TINY_LEARNER

pytestmark = [pytest.mark.ray, pytest.mark.slow]

NODES, PER_NODE = 4, 6
NODE = {"node_ip_address": "127.0.0.1", "object_store_memory": 80 * 1024 * 1024}


@pytest.fixture(scope="module")
def cluster(loopback_ray: None) -> Iterator[list[str]]:
    """A head and three more nodes, each holding six workers; returns the node ids."""
    args = {**NODE, "num_cpus": PER_NODE // 2, "resources": {"sampler": PER_NODE}}
    c = Cluster(initialize_head=True, head_node_args={**args, "include_dashboard": False})
    try:
        for _ in range(NODES - 1):
            c.add_node(**args)
        ray.init(
            address=c.address,
            _node_ip_address="127.0.0.1",
            log_to_driver=False,
            logging_level=logging.WARNING,
        )
        yield [n["NodeID"] for n in ray.nodes() if n["Alive"]]
    finally:
        ray.shutdown()
        c.shutdown()


def _where(worker: Any) -> tuple[str, int, list[int]]:
    """A worker's node, process id and the ports of the servers its env launched."""
    return worker.__ray_call__.remote(
        lambda self: (ray.get_runtime_context().get_node_id(), os.getpid(), list(self.env.ports))
    )


def _server_children(pid: int) -> dict[int, str]:
    """The ``neuronsmae-server`` processes started by process ``pid``: port → cmdline."""
    found = {}
    for child in psutil.Process(pid).children(recursive=True):
        line = child.cmdline()
        if "--port" in line:
            found[int(line[line.index("--port") + 1])] = " ".join(line)
    return found


def test_24_workers_spread_over_four_nodes_with_their_servers_beside_them(
    cluster: list[str], tmp_path: Path
) -> None:
    assert len(cluster) == NODES
    workers = NODES * PER_NODE
    seen: dict[str, Any] = {}

    def hook(trainer: Trainer) -> None:
        if not seen:
            seen["where"] = ray.get([_where(a) for a in trainer.sampler.actors if a is not None])
            seen["servers"] = {pid: _server_children(pid) for _, pid, _ in seen["where"]}

    cfg = make_config(
        {
            "workers": workers,
            "episodes": workers + 4,
            "max_minutes": 6.0,
            "env": "remote",
            "envs_per_worker": 1,
            "worker_cpus": 0.5,
            "worker_resources": "sampler=1",
            "out": str(tmp_path),
            **TINY_LEARNER,
        }
    )
    trainer = Trainer(cfg, hook=hook)
    assert not trainer.owns_ray  # it joined the cluster
    result = trainer.run()

    where = seen["where"]
    assert Counter(node for node, _, _ in where) == dict.fromkeys(cluster, PER_NODE)
    for _, pid, ports in where:  # one private server per worker, its own child process
        assert len(ports) == 1
        assert list(seen["servers"][pid]) == ports, seen["servers"][pid]
    assert len({port for _, _, ports in where for port in ports}) == workers
    stored = result["counters"]["episodes"]
    assert stored == workers + 4 == len(set(trainer.stored_seeds))
    assert result["final"]["eval_episodes"] == 2
