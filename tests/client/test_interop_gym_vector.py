"""Gymnasium's ``AsyncVectorEnv`` over the remote client: with the ``spawn`` context every
worker launches its own private server and plays exactly like the vector face; with the
default ``fork`` context (the parent used Zenoh to read the spaces) it fails at once with
an error that says to use ``context="spawn"``, and never hangs."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import gymnasium
import numpy as np
import pytest

from neuronsmae.client.gym_env import ENV_ID

pytestmark = pytest.mark.interop

SHORT = {"episode_steps": 200}
"""10 abstract decisions an episode: a few dozen steps pass autoresets."""


def test_async_spawn_plays_like_the_vector_face() -> None:
    spawned = gymnasium.make_vec(
        ENV_ID, num_envs=2, vectorization_mode="async", vector_kwargs={"context": "spawn"},
        **SHORT,
    )  # fmt: skip
    served = gymnasium.make_vec(ENV_ID, num_envs=2, **SHORT)  # one vector server
    try:
        assert isinstance(spawned, gymnasium.vector.AsyncVectorEnv)
        a, a_info = spawned.reset(seed=11)
        b, b_info = served.reset(seed=11)
        np.testing.assert_array_equal(a, b)
        space = served.single_action_space
        space.seed(0)
        resets = 0
        for _ in range(24):
            actions = np.stack([space.sample() for _ in range(2)])
            *one, a_info = spawned.step(actions)
            *two, b_info = served.step(actions)
            for x, y in zip(one, two, strict=True):
                np.testing.assert_array_equal(x, y)
            np.testing.assert_array_equal(a_info["t"], b_info["t"])
            np.testing.assert_array_equal(a_info["action_mask"], b_info["action_mask"])
            resets += int((b_info["t"] == 0).sum())
        assert resets >= 4  # both arenas autoreset twice
    finally:
        spawned.close()
        served.close()


@pytest.mark.parametrize("how", ["make_vec", "AsyncVectorEnv"])
def test_async_fork_fails_at_once_saying_to_spawn(how: str) -> None:
    build = {
        "make_vec": f"gymnasium.make_vec({ENV_ID!r}, num_envs=2, vectorization_mode='async')",
        "AsyncVectorEnv": (
            f"gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make({ENV_ID!r})] * 2)"
        ),
    }[how]
    code = textwrap.dedent(f"""
        import gymnasium, neuronsmae.client
        from neuronsmae.protocol.errors import ForkedZenohError
        vec = {build}
        try:
            vec.reset(seed=0)
            print("reset")
        except ForkedZenohError as exc:
            print("refused:", exc)
        finally:
            vec.close()
    """)
    # The time limit only catches a hang; the refusal comes within seconds.
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=240, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "refused:" in out.stdout and "context='spawn'" in out.stdout
