"""SuperSuit's vector pipeline on the PettingZoo face, as its tutorials write it:
``pettingzoo_env_to_vec_env_v1`` then ``concat_vec_envs_v1`` (which copies the environment
by pickling it), with the masks in the infos (``masks="info"``: SuperSuit takes ``Box``
observations only); ``black_death_v3`` for robots removed when destroyed; SuperSuit's worker
processes (``num_cpus > 0``, forked)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from typing import Any

import numpy as np
import pytest

from neuronsmae.client import parallel_env

pytestmark = pytest.mark.interop

ss = pytest.importorskip("supersuit")

IN_PROCESS = "neuronsmae.server:Arena"
BLUE_LOSES = {"coef": 10.0, "opponent_hp": 10000.0}
"""Contexts under which red destroys blue robots one by one within a few decisions."""


def sample(vec: Any, infos: list[dict[str, Any]]) -> np.ndarray:
    """One masked random action per agent row, the mask read from the infos."""
    space = vec.action_space
    return np.array([space.sample(mask=info["action_mask"]) for info in infos])


def test_vector_pipeline_with_default_arguments() -> None:
    pz = parallel_env(masks="info", episode_steps=200)
    vec = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(pz), 2, base_class="gymnasium")
    try:
        # Two copies (a private server each) of two agents: four rows.
        assert vec.num_envs == 4 and vec.observation_space.shape == (37,)
        obs, infos = vec.reset(seed=0)
        assert obs.shape == (4, 37) and all("action_mask" in info for info in infos)
        vec.action_space.seed(0)
        ends = 0
        for _ in range(25):  # 10 decisions an episode: two resets by SuperSuit
            obs, rewards, terminated, truncated, infos = vec.step(sample(vec, infos))
            if truncated.any():
                ends += 1
                assert truncated.all() and not terminated.any()
                assert all("terminal_observation" in info for info in infos)
                assert all(info["t"] == 0 for info in infos)  # the next episode's infos
        assert ends == 2 and obs.shape == (4, 37) and rewards.dtype == np.float32
    finally:
        vec.close()
        pz.close()


def test_black_death_keeps_removed_robots_as_zeros() -> None:
    pz = parallel_env(env=IN_PROCESS, seed=5, masks="info", remove_dead=True, n_blue=3,
                      n_red=3, episode_steps=3000, contexts=BLUE_LOSES)  # fmt: skip
    vec = ss.concat_vec_envs_v1(
        ss.pettingzoo_env_to_vec_env_v1(ss.black_death_v3(pz)), 2, base_class="gymnasium"
    )
    try:
        obs, infos = vec.reset(seed=5)
        vec.action_space.seed(5)
        blacked = ends = 0
        for _ in range(60):
            actions = np.array([vec.action_space.sample(mask=info.get("action_mask"))
                                for info in infos])  # fmt: skip
            obs, rewards, terminated, _, infos = vec.step(actions)
            zero = ~obs.any(axis=1)
            blacked += int(zero.sum())
            assert (rewards[zero] == 0).all()
            if terminated.any():
                ends += 1
        assert blacked > 0 and ends > 0
    finally:
        vec.close()
        pz.close()


@pytest.mark.parametrize(("env", "works"), [(IN_PROCESS, True), (None, False)])
def test_supersuit_worker_processes(env: str | None, works: bool) -> None:
    # Its workers are forked: arenas in process work there; a served arena (its Zenoh session
    # opened in the parent) fails at once saying to spawn, and never hangs.
    code = textwrap.dedent(f"""
        import numpy as np
        import supersuit as ss
        from neuronsmae.client import parallel_env
        from neuronsmae.protocol.errors import ForkedZenohError

        pz = parallel_env(env={env!r}, masks="info", seed=0, episode_steps=200)
        vec = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(pz), 2, num_cpus=2,
                                    base_class="gymnasium")
        try:
            vec.reset(seed=0)
            for _ in range(12):
                vec.step(np.zeros(vec.num_envs, dtype=np.int64))
            print("stepped")
        except ForkedZenohError as exc:
            print("refused:", exc)
        finally:
            vec.close()
            pz.close()
    """)
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=240, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    if works:
        assert out.stdout.strip().endswith("stepped")
    else:
        assert "refused:" in out.stdout and "spawn" in out.stdout
