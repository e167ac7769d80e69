"""The RMUA arena as constants: walls, obstacles, zones, birth areas, robot geometry.

Every other module reads the field from here, so the arena is described exactly once.
Frame: x along the long side (0 → 8.08 m), y along the short side (0 → 4.48 m), z up, yaw
counter-clockwise from +x. Figures are from ``docs/reference.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FIELD_X = 8.08
"""Interior length along x (m)."""
FIELD_Y = 4.48
"""Interior width along y (m)."""
CENTER = (FIELD_X / 2.0, FIELD_Y / 2.0)
"""Centre of central symmetry of the layout."""
WALL_THICKNESS = 0.156
WALL_HEIGHT = 0.472


@dataclass(frozen=True)
class Obstacle:
    """An axis-aligned (or turned) box obstacle standing on the floor."""

    name: str
    cx: float
    cy: float
    sx: float
    """Size along x before turning (m)."""
    sy: float
    """Size along y before turning (m)."""
    height: float
    yaw: float = 0.0
    """Rotation about z (rad); only B8 is turned (45°)."""

    @property
    def tall(self) -> bool:
        """Tall obstacles block shots and sight; low ones (below the armour plates) do not."""
        return self.height > ARMOR_HEIGHT


OBSTACLES: tuple[Obstacle, ...] = (
    Obstacle("B1", 6.476, 3.970, 0.184, 0.985, 0.374),
    Obstacle("B2", 0.500, 3.377, 0.985, 0.183, 0.374),
    Obstacle("B3", 7.580, 1.098, 0.985, 0.183, 0.374),
    Obstacle("B4", 4.040, 1.037, 0.985, 0.183, 0.374),
    Obstacle("B5", 4.040, 3.445, 0.985, 0.183, 0.374),
    Obstacle("B6", 1.900, 2.240, 0.788, 0.183, 0.145),
    Obstacle("B7", 6.180, 2.240, 0.788, 0.183, 0.145),
    Obstacle("B8", 4.041, 2.240, 0.245, 0.245, 0.140, np.pi / 4),
    Obstacle("B9", 1.600, 0.500, 0.193, 0.988, 0.399),
)

ZONE_SIZE_RMUA = (0.54, 0.48)
ZONE_SIZE_RELEASED = (0.40, 0.40)
ZONES: dict[str, tuple[float, float]] = {
    "F1": (0.50, 2.79),
    "F2": (1.90, 1.65),
    "F3": (4.04, 4.035),
    "F4": (7.58, 1.69),
    "F5": (6.18, 2.83),
    "F6": (4.04, 0.445),
}
ZONE_PAIRS: tuple[tuple[str, str], ...] = (("F1", "F4"), ("F2", "F5"), ("F3", "F6"))
"""Centrally symmetric zone pairs; each pair shares one effect pair under the RMUA rules."""

BIRTH_AREAS: tuple[tuple[float, float], ...] = ((0.5, 0.5), (0.5, 3.98), (7.58, 0.5), (7.58, 3.98))
"""Centres of the 1 × 1 m corner birth areas (paper, RMUA)."""
BIRTH_SIZE = 1.0

# --- robot -----------------------------------------------------------------------------
ROBOT_LENGTH = 0.60
ROBOT_WIDTH = 0.46
ROBOT_HEIGHT = 0.44
ROBOT_MASS = 16.0
ARMOR_HEIGHT = 0.195
SHOOTER_HEIGHT = 0.374
SHOOTER_OFFSET = 0.18
"""Muzzle distance ahead of the gimbal axis (m)."""
ARMOR_FRONT = 0.27
ARMOR_SIDE = 0.185
ARMORS: tuple[tuple[str, float, float, float, float], ...] = (
    # name, offset along heading, offset across, outward normal angle (rel. heading), multiplier
    ("front", ARMOR_FRONT, 0.0, 0.0, 1.0),
    ("left", 0.0, ARMOR_SIDE, np.pi / 2, 2.0),
    ("rear", -ARMOR_FRONT, 0.0, np.pi, 3.0),
    ("right", 0.0, -ARMOR_SIDE, -np.pi / 2, 2.0),
)
ARMOR_TABLE = np.array([a[1:] for a in ARMORS], dtype=np.float64)
"""(4, 4): along, across, normal angle, damage multiplier for each plate."""

GIMBAL_YAW_LIMIT = np.pi / 2
CAMERA_VFOV = np.deg2rad(27.0)
LIDAR_BEAMS = 61
LIDAR_SPAN = np.deg2rad(270.0)

START_HP = 600
START_BULLETS = 370

# --- timing ----------------------------------------------------------------------------
PHYSICS_DT = 0.02
EPISODE_STEPS = 1000

# --- spawns ----------------------------------------------------------------------------
SPAWN_X = (0.40, 7.80)
SPAWN_Y = (0.40, 4.00)
SPAWN_OBSTACLE_MARGIN = 0.30
SPAWN_MIN_SEPARATION = 0.80


def obstacle_array(tall_only: bool = False) -> np.ndarray:
    """Obstacles as an ``(n, 6)`` float array ``cx, cy, half_x, half_y, yaw, height``.

    This is the form the numba kernels take; walls are not included (the field bounds are).
    """
    rows = [
        (o.cx, o.cy, o.sx / 2, o.sy / 2, o.yaw, o.height)
        for o in OBSTACLES
        if o.tall or not tall_only
    ]
    return np.array(rows, dtype=np.float64)
