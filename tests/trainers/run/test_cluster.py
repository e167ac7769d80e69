"""Training on a two-node Ray cluster (``ray.cluster_utils.Cluster``, both nodes local).

Each node offers one unit of a custom ``sampler`` resource and workers require it, so the
two workers must land one per node: the custom-resource placement a real cluster uses
(``ray start --resources '{"sampler": N}'``). The second run puts the servers in Ray actors
on the node with the ``sim`` resource, and workers on both nodes reach them by node IP.
Every node is bound to 127.0.0.1; the runs are tiny (a few episodes, a 16-unit GRU).
"""

from __future__ import annotations

import logging
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import ray
from ray.cluster_utils import Cluster

from neuronsmae.trainers.run.config import ConfigError, make_config, parse_resources
from neuronsmae.trainers.run.train import Trainer
from tests.ports import free_ports

pytestmark = [pytest.mark.ray, pytest.mark.slow]

TINY = {
    "workers": 2,
    "episodes": 4,
    "eval_every": 0,
    "eval_episodes": 2,
    "final_eval_episodes": 2,
    "batch_size": 2,
    "learning_starts": 2,
    "train_every": 2,
    "agent_hidden": 16,
    "hypernet_hidden": 8,
    "mixer_embed": 8,
    "worker_cpus": 0.5,
    "worker_resources": "sampler=1",
    "progress": False,
}
NODE = {"node_ip_address": "127.0.0.1", "object_store_memory": 80 * 1024 * 1024}


@pytest.fixture(scope="module")
def cluster(loopback_ray: None) -> Iterator[dict[str, str]]:
    """A head and a worker node; returns the node ids by role."""
    c = Cluster(
        initialize_head=True,
        head_node_args={
            **NODE,
            "num_cpus": 2,
            "resources": {"sampler": 1},
            "include_dashboard": False,
        },
    )
    try:
        c.add_node(**NODE, num_cpus=2, resources={"sampler": 1, "sim": 2})
        ray.init(
            address=c.address,
            _node_ip_address="127.0.0.1",
            log_to_driver=False,
            logging_level=logging.WARNING,
        )
        nodes = {n["NodeID"]: n["Resources"] for n in ray.nodes() if n["Alive"]}
        yield {("sim" if "sim" in r else "head"): node for node, r in nodes.items()}
    finally:
        ray.shutdown()
        c.shutdown()


def _listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _node_of(actor: Any) -> str:
    return ray.get(actor.__ray_call__.remote(lambda self: ray.get_runtime_context().get_node_id()))


def _run(cfg_values: dict[str, Any], tmp_path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Train; return the result and what the first hook call saw about placement."""
    seen: dict[str, Any] = {}

    def hook(trainer: Trainer) -> None:
        if not seen:
            sampler = trainer.sampler
            seen["workers"] = [_node_of(a) for a in sampler.actors if a is not None]
            if sampler.servers is not None:
                actors = list(sampler.servers.actors.values())
                seen["servers"] = ray.get([a.node_id.remote() for a in actors])
                seen["addresses"] = dict(sampler.servers.addresses)

    cfg = make_config({**TINY, "out": str(tmp_path / "run"), **cfg_values})
    trainer = Trainer(cfg, hook=hook)
    assert not trainer.owns_ray  # it joined the cluster instead of starting a Ray
    return trainer.run(), seen


def test_workers_spread_over_both_nodes(cluster: dict[str, str], tmp_path: Path) -> None:
    result, seen = _run({"alg": "vdn", "env": "inprocess"}, tmp_path)
    assert sorted(seen["workers"]) == sorted(cluster.values())
    assert result["counters"]["episodes"] == 4
    assert result["final"]["eval_episodes"] == 2


def test_server_actors_on_the_sim_node(cluster: dict[str, str], tmp_path: Path) -> None:
    base = free_ports(2)  # both workers' ports, outside the range Ray's connections use
    result, seen = _run(
        {
            "alg": "qmix",
            "env": "remote",
            "servers": "actors",
            "server_resources": "sim=1",
            "base_port": base,
        },
        tmp_path,
    )
    assert seen["servers"] == [cluster["sim"], cluster["sim"]]
    assert sorted(seen["workers"]) == sorted(cluster.values())
    assert seen["addresses"] == {0: ("127.0.0.1", base), 1: ("127.0.0.1", base + 1)}
    assert result["counters"]["episodes"] == 4
    assert not _listening(base) and not _listening(base + 1)  # the servers were stopped


def test_resource_strings() -> None:
    assert parse_resources("sampler=1, sim=0.5,gpu_box") == {
        "sampler": 1.0,
        "sim": 0.5,
        "gpu_box": 1.0,
    }
    assert parse_resources("") == {}
    for bad in ("CPU=1", "x=0", "=2", "x=two"):
        with pytest.raises(ConfigError, match=f"resource '{bad}': expected"):
            parse_resources(bad)
    with pytest.raises(ConfigError, match="servers='cloud' is not valid; valid: local, actors"):
        make_config({"servers": "cloud"})
