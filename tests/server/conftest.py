"""Shared helpers for the server tests: building arenas and constructed scenes."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from neuronsmae.server import Arena

FAR = [(0.6, 0.6, 0.0), (7.5, 0.6, np.pi)]
"""Out-of-the-way corner poses for robots a scene does not use."""


@pytest.fixture
def arena() -> Iterator[Arena]:
    """A continuous-action 2 v 2 arena where the test drives every robot (no bot moves)."""
    a = Arena(seed=7, action_space="continuous", mode="competitive")
    a.reset()
    yield a
    a.close()


def still(n: int = 4, target: int = 0) -> list[np.ndarray]:
    """Continuous actions that stand still and aim at ``target``."""
    return [np.array([0.0, 0.0, 0.0, target]) for _ in range(n)]


def duel(
    arena: Arena,
    shooter: tuple,
    victim: tuple,
    shooter_bullets: float = 370,
    victim_is_red: bool = True,
) -> tuple[np.ndarray, dict]:
    """Put blue_0 at ``shooter`` and red_0 at ``victim``; everyone else far and unarmed.

    Returns the HP lost by every robot over one decision (20 physics steps) and info.
    """
    poses = np.array([shooter, (0.6, 3.9, 0.0), victim, (7.5, 0.6, np.pi)])
    bullets = [shooter_bullets, 0, 0, 0]
    if not victim_is_red:  # red_0 shoots blue_0
        poses = np.array([victim, (0.6, 3.9, 0.0), shooter, (7.5, 0.6, np.pi)])
        bullets = [0, 0, shooter_bullets, 0]
    arena.place(poses, bullets=bullets)
    hp0 = arena.referee.hp.copy()
    _, _, _, info = arena.step(still())
    return hp0 - arena.referee.hp, info
