"""Top-down rendering of an arena to an RGB array.

Drawn with Pillow so rendering needs no display and no OpenGL: the field, tall obstacles
(dark) and low ones (light), zones, robots with heading, gimbal, team colour and name, HP
and bullet bars, the shots fired in the last physics step, candidate points of the
controlled agents, their LiDAR beams when the ``lidar`` option is on, and the clock and
score. A frame costs a few milliseconds (about 7 ms on a loaded 2-core machine, LiDAR
included), so rendering every decision of an episode (51 frames) takes well under a second.
"""

from __future__ import annotations

import functools
import math
from typing import Any, Protocol

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from neuronsmae.server.sim import field as F
from neuronsmae.server.task import perception as P


class Arena(Protocol):
    """What rendering reads of an arena (:class:`neuronsmae.server.arena.Arena` is one; the
    arena imports this module, so this one names its shape instead of importing it)."""

    config: Any
    referee: Any
    poses: np.ndarray
    agents: Any
    team: np.ndarray
    targets: np.ndarray
    cands: np.ndarray
    valid: np.ndarray
    n: int
    n_blue: int
    t: int

    def agent_name(self, i: int) -> str: ...


SCALE = 100
"""Pixels per metre."""
MARGIN = 20
TOP = 28
"""Extra rows above the field for the clock and score."""
TEAM_RGB = {0: (40, 110, 230), 1: (220, 50, 50)}
DEAD_RGB = (120, 120, 120)
FLOOR = (235, 232, 222)
TALL_RGB = (70, 70, 80)
LOW_RGB = (170, 170, 175)
ZONE_RGB = (250, 215, 120)
SHOT_RGB = (255, 140, 0)
LIDAR_RGB = {0: (170, 200, 245), 1: (245, 185, 185)}
"""Pale team colours: beams sit under everything else and must not hide it."""
ZONE_EFFECTS = {
    "hp_blue": ((190, 215, 250), "+HP"),
    "hp_red": ((250, 200, 200), "+HP"),
    "ammo_blue": ((190, 215, 250), "+AMMO"),
    "ammo_red": ((250, 200, 200), "+AMMO"),
    "no_shoot": ((215, 215, 215), "NO SHOOT"),
    "no_move": ((215, 215, 215), "NO MOVE"),
}
"""Fill and label of a zone whose effect (``zones`` option) is still to be triggered; a
spent zone shows only its outline."""


@functools.cache
def _font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's bitmap font, loaded once: FreeType text (Pillow ≥ 10's default) costs about
    a millisecond per label, more than the rest of a frame."""
    bitmap = getattr(ImageFont, "load_default_imagefont", ImageFont.load_default)
    return bitmap()


def size() -> tuple[int, int]:
    """(width, height) of a frame in pixels."""
    return round(F.FIELD_X * SCALE) + 2 * MARGIN, round(F.FIELD_Y * SCALE) + 2 * MARGIN + TOP


HEIGHT = size()[1]


def to_px(x: float, y: float) -> tuple[float, float]:
    """World (x, y) → pixel (column, row); y grows upward in the world, downward in images."""
    return MARGIN + x * SCALE, HEIGHT - MARGIN - y * SCALE


def _box_corners(cx: float, cy: float, hx: float, hy: float, yaw: float) -> list[tuple]:
    c, s = math.cos(yaw), math.sin(yaw)
    pts = [(hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy)]
    return [to_px(cx + c * a - s * b, cy + s * a + c * b) for a, b in pts]


@functools.cache
def _background() -> Image.Image:
    """The field, zones and obstacles: the same in every frame, so drawn once and copied."""
    img = Image.new("RGB", size(), (255, 255, 255))
    _field(ImageDraw.Draw(img))
    return img


def _field(draw: ImageDraw.ImageDraw) -> None:
    draw.rectangle([to_px(0, F.FIELD_Y), to_px(F.FIELD_X, 0)], fill=FLOOR, outline=(0, 0, 0))
    zx, zy = F.ZONE_SIZE_RMUA
    for cx, cy in F.ZONES.values():
        draw.polygon(_box_corners(cx, cy, zx / 2, zy / 2, 0.0), outline=ZONE_RGB, width=2)
    for o in F.OBSTACLES:
        draw.polygon(
            _box_corners(o.cx, o.cy, o.sx / 2, o.sy / 2, o.yaw),
            fill=TALL_RGB if o.tall else LOW_RGB,
        )


def _robot(
    draw: ImageDraw.ImageDraw,
    pose: np.ndarray,
    rgb: tuple,
    target: np.ndarray,
    hp_frac: float,
    bullet_frac: float,
) -> None:
    x, y, yaw = pose
    draw.polygon(
        _box_corners(x, y, F.ROBOT_LENGTH / 2, F.ROBOT_WIDTH / 2, yaw), fill=rgb, outline=(0, 0, 0)
    )
    nose = to_px(x + 0.3 * math.cos(yaw), y + 0.3 * math.sin(yaw))
    draw.line([to_px(x, y), nose], fill=(255, 255, 255), width=3)
    aim = math.atan2(target[1] - y, target[0] - x)
    rel = math.atan2(math.sin(aim - yaw), math.cos(aim - yaw))
    g = yaw + min(max(rel, -F.GIMBAL_YAW_LIMIT), F.GIMBAL_YAW_LIMIT)
    draw.line(
        [to_px(x, y), to_px(x + 0.25 * math.cos(g), y + 0.25 * math.sin(g))],
        fill=(255, 230, 0),
        width=2,
    )
    px, py = to_px(x, y)
    for row, frac, color in ((-42, hp_frac, (40, 190, 60)), (-36, bullet_frac, (230, 160, 30))):
        draw.rectangle([px - 30, py + row, px + 30, py + row + 4], fill=(60, 60, 60))
        draw.rectangle([px - 30, py + row, px - 30 + 60 * max(frac, 0.0), py + row + 4], fill=color)


def _lidar(draw: ImageDraw.ImageDraw, arena: Arena) -> None:
    """Each controlled agent's beams, exactly the scan its observation carries."""
    rng = arena.config.lidar_range
    for i in arena.agents:
        if not arena.referee.alive[i]:
            continue
        x, y, yaw = arena.poses[i]
        d = (P.lidar(arena.poses, int(i), rng) + 1.0) * (rng / 2.0)
        a = yaw + np.linspace(-F.LIDAR_SPAN / 2, F.LIDAR_SPAN / 2, F.LIDAR_BEAMS)
        ends = np.stack(
            [MARGIN + (x + d * np.cos(a)) * SCALE, HEIGHT - MARGIN - (y + d * np.sin(a)) * SCALE],
            axis=1,
        )
        # One zig-zag polyline (centre, end, centre, end, ...) draws every beam in one call.
        pts = np.empty((2 * len(ends) + 1, 2))
        pts[0::2] = to_px(x, y)
        pts[1::2] = ends
        draw.line(pts.ravel().tolist(), fill=LIDAR_RGB[int(arena.team[i])])


def _zones(draw: ImageDraw.ImageDraw, arena: Arena) -> None:
    """The zone effects still waiting to be triggered, filled in their team's pale colour."""
    zones = getattr(arena, "zones", None)
    if zones is None:
        return
    zx, zy = F.ZONE_SIZE_RMUA
    for name, effect in zones.state.effects.items():
        rgb, label = ZONE_EFFECTS.get(effect, ((215, 215, 215), effect))
        cx, cy = F.ZONES[name]
        draw.polygon(_box_corners(cx, cy, zx / 2, zy / 2, 0.0), fill=rgb, outline=ZONE_RGB)
        px, py = to_px(cx, cy)
        w = draw.textlength(label, font=_font())
        draw.text((px - w / 2, py - 5), label, fill=(0, 0, 0), font=_font())


def _penalties(arena: Arena, i: int) -> str:
    """ " [no shoot]" / " [no move]" while robot ``i`` serves a zone penalty, else ""."""
    zones = getattr(arena, "zones", None)
    if zones is None:
        return ""
    marks = (("no shoot", zones.silenced(arena.t)), ("no move", zones.frozen(arena.t)))
    return "".join(f" [{name}]" for name, now in marks if now[i])


def _scoreboard(arena: Arena) -> str:
    """Clock, decision and each team's HP, damage dealt and kills (the RMUA score)."""
    ref, nb = arena.referee, arena.n_blue
    period = arena.config.period
    clock = (
        f"t = {arena.t * F.PHYSICS_DT:5.2f} / {arena.config.episode_steps * F.PHYSICS_DT:g} s"
        f"  decision {-(-arena.t // period):2d}"
    )
    teams = []
    for name, sl in (("blue", slice(0, nb)), ("red", slice(nb, None))):
        teams.append(
            f"{name}: HP {ref.hp[sl].sum():4.0f}  dmg {ref.damage_dealt[sl].sum():4.0f}"
            f"  kills {int(ref.kills[sl].sum())}"
        )
    text = "   ".join([clock, *teams])
    if ref.winner:
        text += f"   winner: {ref.winner}"
    return text


def render_scene(arena: Arena) -> np.ndarray:
    """The arena's current scene as an (H, W, 3) uint8 array."""
    img = _background().copy()
    draw = ImageDraw.Draw(img)
    _zones(draw, arena)
    if arena.config.lidar:
        _lidar(draw, arena)
    ref = arena.referee
    poses = arena.poses
    for i in arena.agents:
        for pt in arena.cands[i][arena.valid[i]]:  # "stay" sentinels are not points
            cx, cy = to_px(*pt)
            draw.ellipse([cx - 4, cy - 4, cx + 4, cy + 4], outline=TEAM_RGB[arena.team[i]])
    for s, plate in enumerate(ref.last_plate):
        if plate >= 0:
            tgt = poses[arena.targets[s]]
            draw.line([to_px(*poses[s, :2]), to_px(*tgt[:2])], fill=SHOT_RGB, width=2)
    for i in range(arena.n):
        rgb = TEAM_RGB[int(arena.team[i])] if ref.alive[i] else DEAD_RGB
        _robot(
            draw,
            poses[i],
            rgb,
            poses[arena.targets[i], :2],
            ref.hp[i] / ref.max_hp[i],
            ref.bullets[i] / ref.max_bullets[i],
        )
        px, py = to_px(*poses[i, :2])
        label = arena.agent_name(i) + _penalties(arena, i)
        draw.text((px + 32, py - 44), label, fill=(0, 0, 0), font=_font())
    draw.text((MARGIN, 8), _scoreboard(arena), fill=(0, 0, 0), font=_font())
    return np.asarray(img, dtype=np.uint8)
