"""A client reaches a server through a Zenoh router only (deploy/run_router.py).

All on loopback with distinct ports: the server listens on port A and connects to the
router on port R; the client connects to R alone. Stopping the router cuts the client off
while the server still answers on A directly, which shows the queries went through R.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from neuronsmae.client import RM
from neuronsmae.protocol.errors import ServerUnavailableError
from neuronsmae.server.serving.fleet import status
from neuronsmae.server.serving.probe import Probe
from neuronsmae.server.serving.supervisor import FleetSpec

from .conftest import (
    ROUTER_SCRIPT,
    free_ports,
    listening,
    server_cmd,
    stop,
    wait_for,
)

pytestmark = pytest.mark.slow

Spawn = Callable[..., subprocess.Popen[bytes]]


def _router(spawn: Spawn, port: int) -> subprocess.Popen[bytes]:
    proc = spawn(str(ROUTER_SCRIPT), "--listen", f"tcp/127.0.0.1:{port}", name="router")
    wait_for(lambda: listening(port) or proc.poll() is not None, 30, "the router")
    assert proc.poll() is None, "the router exited"
    return proc


def _allowed(env: RM) -> list[int]:
    return [int(np.flatnonzero(mask)[0]) for mask in env.get_avail_actions()]


def test_client_reaches_server_only_through_router(spawn: Spawn) -> None:
    r_port = free_ports(2)  # one block: two picks could meet
    a_port = r_port + 1
    router_ep = f"tcp/127.0.0.1:{r_port}"
    router = _router(spawn, r_port)
    server = spawn(*server_cmd(a_port, "--router", router_ep), name="server")
    via_router = Probe("127.0.0.1", a_port, router=router_ep, timeout=1.0)
    try:
        wait_for(lambda: via_router.ping().up, 180, "the server through the router")
    finally:
        via_router.close()
    rows = status(FleetSpec(base_port=a_port, count=1, routers=(router_ep,)))
    assert rows[0]["state"] == "up"

    env = RM(seed=3, port=a_port, router=router_ep, launch=False, timeout=20.0)
    try:
        assert env.host == "127.0.0.1" and env.router == router_ep
        env.reset(seed=5)
        env.step(_allowed(env))

        assert stop(router) == 0  # the router goes away; the server stays
        with pytest.raises(ServerUnavailableError):
            env.step(_allowed(env))
        assert server.poll() is None
        with Probe("127.0.0.1", a_port) as direct:
            assert direct.ping().up  # still answering on A: only the route is gone

        _router(spawn, r_port)  # back: the server and the client both reconnect by themselves
        wait_for(lambda: _answers(env), 60, "the route through the new router")
        env.step(_allowed(env))
    finally:
        env.close()


def _answers(env: RM) -> bool:
    try:
        env.reset(seed=6)
    except ServerUnavailableError:
        return False
    return True


def test_rm_with_unreachable_router_never_launches() -> None:
    port = free_ports(2)
    with pytest.raises(ServerUnavailableError, match="router"):
        RM(port=port, router=f"tcp/127.0.0.1:{port + 1}", timeout=2.0)
    assert not listening(port)


def test_training_samples_through_the_router(spawn: Spawn, tmp_path: Path) -> None:
    """``cluster.router``: every worker reaches its server ``base_port + i`` through the
    router alone (the trainer used to fail at start with a TypeError for any router)."""
    pytest.importorskip("ray")
    from neuronsmae.trainers.run.config import make_config
    from neuronsmae.trainers.run.placement import sampler_placement
    from neuronsmae.trainers.run.train import train

    r_port = free_ports(3)  # one block: two picks could meet
    base = r_port + 1
    router_ep = f"tcp/127.0.0.1:{r_port}"
    values = {"env": "remote", "base_port": base, "router": router_ep, "envs_per_worker": 2}
    placed = sampler_placement(make_config(values), 2, 0, {"n_blue": 2})
    assert placed["env_options"] == {"n_blue": 2, "router": router_ep}

    _router(spawn, r_port)
    for i in range(2):
        spawn(*server_cmd(base + i, "--router", router_ep, "--arenas", "2", "--seed",
                          str(10 * i)), name=f"server{i}")  # fmt: skip
    for i in range(2):
        probe = Probe("127.0.0.1", base + i, router=router_ep, timeout=1.0)
        try:
            wait_for(lambda p=probe: p.ping().up, 180, f"server {i} through the router")
        finally:
            probe.close()
    cfg = make_config(
        values,
        {"workers": 2, "episodes": 4, "eval_every": 0, "eval_episodes": 2,
         "final_eval_episodes": 2, "batch_size": 2, "learning_starts": 2, "agent_hidden": 16,
         "worker_cpus": 0.5, "progress": False, "out": str(tmp_path / "run")},
    )  # fmt: skip
    result = train(cfg)
    assert result["counters"]["episodes"] >= 4
    assert result["final"]["eval_episodes"] == 2
