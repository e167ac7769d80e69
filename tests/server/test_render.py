"""The top-down renderer: team colours where the robots are, obstacle kinds, LiDAR, speed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neuronsmae.server import Arena
from neuronsmae.server import render as R
from neuronsmae.server.sim import field as F

SCENE = np.array([(1.0, 1.2, 0.5), (2.6, 3.0, -1.0), (6.0, 1.4, np.pi), (7.0, 3.3, 2.0)])
"""Four robots in the open, away from obstacles and from each other's labels and bars."""


def _scene(**options: object) -> Arena:
    a = Arena(seed=1, mode="competitive", action_space="continuous", **options)
    a.reset()
    a.place(SCENE, bullets=[370, 200, 100, 0])
    return a


def _pixel(frame: np.ndarray, x: float, y: float) -> tuple[int, ...]:
    col, row = R.to_px(x, y)
    return tuple(int(v) for v in frame[round(row), round(col)])


def _behind(pose: np.ndarray, d: float = 0.15) -> tuple[float, float]:
    """A point on the robot's rear half: its body colour, clear of the heading and gimbal
    lines that start at the centre and point forward/at the target."""
    x, y, yaw = pose
    return x - d * math.cos(yaw), y - d * math.sin(yaw)


def test_frame_is_rgb_uint8_of_the_documented_size() -> None:
    a = _scene()
    frame = a.render()
    w, h = R.size()
    assert frame.shape == (h, w, 3) and frame.dtype == np.uint8
    a.close()


def test_each_robot_is_drawn_in_its_team_colour_at_its_position() -> None:
    a = _scene()
    frame = a.render()
    for i, pose in enumerate(SCENE):
        want = R.TEAM_RGB[int(a.team[i])]
        assert _pixel(frame, *_behind(pose)) == want, a.agent_name(i)
    # Move the robots: the colours follow them, and the old spots show the floor again.
    moved = SCENE.copy()
    moved[:, 1] = 4.48 - moved[:, 1]
    a.place(moved)
    frame = a.render()
    for i, (old, new) in enumerate(zip(SCENE, moved, strict=True)):
        assert _pixel(frame, *_behind(new)) == R.TEAM_RGB[int(a.team[i])]
        assert _pixel(frame, *_behind(old)) != R.TEAM_RGB[int(a.team[i])]
    a.close()


def test_destroyed_robot_is_grey() -> None:
    a = _scene()
    a.referee.alive[2] = False
    a.referee.hp[2] = 0.0
    assert _pixel(a.render(), *_behind(SCENE[2])) == R.DEAD_RGB
    a.close()


def test_tall_and_low_obstacles_have_their_own_colours() -> None:
    a = _scene()
    frame = a.render()
    assert R.TALL_RGB != R.LOW_RGB
    kinds = {o.tall for o in F.OBSTACLES}
    assert kinds == {True, False}  # the field has both, so both colours are checked
    for o in F.OBSTACLES:
        assert _pixel(frame, o.cx, o.cy) == (R.TALL_RGB if o.tall else R.LOW_RGB), o.name
    a.close()


def test_lidar_beams_are_drawn_only_when_the_option_is_on() -> None:
    def beam_pixels(frame: np.ndarray) -> int:
        return int(sum((frame == rgb).all(-1).sum() for rgb in R.LIDAR_RGB.values()))

    plain, lidar = _scene(), _scene(lidar=True)
    assert beam_pixels(plain.render()) == 0
    assert beam_pixels(lidar.render()) > 1000
    plain.close()
    lidar.close()


def test_render_before_reset_is_refused() -> None:
    from neuronsmae.protocol.errors import ResetNeededError

    a = Arena(seed=0, mode="bots")
    with pytest.raises(ResetNeededError):
        a.render()
    a.reset()
    assert a.render().ndim == 3  # "bots" mode has no agents, and still renders
    a.close()


def test_zone_effects_waiting_to_be_triggered_are_filled() -> None:
    a = _scene(zones=True)
    a.step([np.array([0.0, 0.0, 0.0, 0.0])] * 4)  # effects are dealt at t = 0
    effects = a.zones.state.effects
    assert len(effects) == 6  # nobody stands on a zone in this scene
    frame = a.render()
    zx, zy = F.ZONE_SIZE_RMUA
    for name, effect in effects.items():
        cx, cy = F.ZONES[name]
        inside = (cx - zx / 2 + 0.06, cy - zy / 2 + 0.06)  # clear of the label in the middle
        assert _pixel(frame, *inside) == R.ZONE_EFFECTS[effect][0], (name, effect)
    a.close()
