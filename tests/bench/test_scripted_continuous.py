"""scripted_continuous: the aiming rule on known poses, and a few episodes end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from bench.scripted_continuous import aim, aim_close, main, still
from neuronsmae.protocol import EnvInfo
from neuronsmae.protocol.env_info import FIELD_HALF

INFO = EnvInfo(
    n_agents=2, n_enemies=2, n_actions=2, obs_shape=21, state_shape=21, episode_limit=50,
    action_space="continuous", agents=("blue_0", "blue_1"), decision_steps=20,
    mode="cooperative", team_size=2, k=4, candidate_obs=False, vector_obs=True, lidar_beams=0,
)  # fmt: skip


def observation(poses: list[tuple[float, float, float]], hp: list[float]) -> np.ndarray:
    """A continuous-action observation with robots (self, ally, enemy 0, enemy 1) at
    ``poses`` (m, m, rad) and ``hp`` (of 600)."""
    obs = np.zeros(INFO.obs_shape, np.float32)
    hx, hy = FIELD_HALF
    for robot, (x, y, yaw) in enumerate(poses):
        cx, cy, cyaw = INFO.obs.pose(robot)
        obs[cx], obs[cy], obs[cyaw] = (x - hx) / hx, (y - hy) / hy, yaw / math.pi
        obs[INFO.obs.hp_of(robot)] = 2 * hp[robot] / 600 - 1
    return obs


def test_aim_turns_toward_the_nearest_living_enemy_within_the_bound() -> None:
    rng = np.random.default_rng(0)
    # self at (2, 2) facing +x; enemy 0 dead 1 m ahead, enemy 1 alive 3 m to the left (+y)
    obs = observation([(2, 2, 0), (1, 1, 0), (3, 2, 0), (2, 5, 0)], [600, 600, 0, 600])
    vx, vy, omega, target = aim(obs, INFO, rng)
    assert (vx, vy, target) == (0.0, 0.0, 1.0)
    assert omega == pytest.approx(1.75)  # π/2 in one 0.4 s decision is past the 1.75 rad/s bound
    assert still(obs, INFO, rng)[3] == 1.0
    # both alive: the nearer (enemy 0, straight ahead) is aimed at; no turn needed
    obs = observation([(2, 2, 0), (1, 1, 0), (3, 2.1, 0), (2, 5, 0)], [600] * 4)
    _, _, omega, target = aim(obs, INFO, rng)
    assert target == 0.0 and omega == pytest.approx(math.atan2(0.1, 1) / 0.4, rel=1e-3)
    # aim_close backs away from an enemy nearer than 2.5 m straight ahead
    forward = aim_close(obs, INFO, rng)[0]
    assert forward == pytest.approx((math.hypot(1, 0.1) - 2.5) * math.cos(math.atan2(0.1, 1)))


def test_a_few_episodes_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "s.json"
    assert main(["--episodes", "3", "--teams", "still", "aim", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [r["team"] for r in doc["rows"]] == ["still", "aim"]
    for r in doc["rows"]:
        assert r["episodes"] == 3
        assert r["win_rate"] + r["draw_rate"] + r["loss_rate"] == pytest.approx(1.0)
        assert r["win_ci95"][0] <= r["win_rate"] <= r["win_ci95"][1]
    assert doc["first_seed"] == 1_010_000_000
    with pytest.raises(SystemExit):  # an existing --out is refused before any episode
        main(["--episodes", "1", "--out", str(out)])
