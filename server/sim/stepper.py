"""The arena's physics step: chassis, PyBullet and referee with two numba calls per step.

A decision is 20 physics steps and each one must drive every robot, step PyBullet, read every
pose and let the referee fire, so the Python around the unavoidable PyBullet calls is most
of the environment's overhead. Here that Python is cut to the minimum: one fused kernel
turns the commands into world-frame velocities (:func:`~.chassis.step_kernel` then
:func:`~.world.world_velocity`), :meth:`~.world.World.advance` makes the PyBullet calls, and a
second fused kernel turns the readout into poses and fires (:func:`~.world.settle_poses` then
:func:`~.shots.fire`). The pieces are the same functions the stand-alone ``Chassis.step``,
``World.step`` and ``Referee.physics_step`` use, so both paths give identical results.

numba's on-disk cache keys a kernel on its own file only: after editing chassis.py, world.py
or shots.py, delete ``server/sim/__pycache__/stepper.*.nb[ic]`` or these kernels keep the old
code.
"""

from __future__ import annotations

import numba
import numpy as np

from neuronsmae.server.sim.chassis import Chassis, step_kernel
from neuronsmae.server.sim.referee import Referee, StepTally
from neuronsmae.server.sim.shots import fire
from neuronsmae.server.sim.world import World, settle_poses, world_velocity


@numba.njit(cache=True)
def _drive(cmd, state, head, n_sub, sub_dt, poses, alive, vel) -> None:
    """Chassis model for one physics step, then its mean body velocity in the world frame."""
    body = np.empty((cmd.shape[0], 3))
    step_kernel(cmd, state, head, n_sub, sub_dt, body)
    world_velocity(body, poses, alive, vel)


@numba.njit(cache=True)
def _settle_and_fire(
    raw, poses, alive, fix, fl, it, targets, boxes, n_static, draws, tally_damage, tally_kills
) -> tuple[int, int]:
    """Poses from the readout (flagging robots to re-place), then the referee's shots.

    Returns (robots flagged in ``fix``, robots destroyed). The robots destroyed by this
    step's shots were alive while their poses were read, as in the unfused order.
    """
    n_fix = settle_poses(raw, poses, alive, fix)
    destroyed = fire(
        poses, alive, fl, it, targets, boxes, n_static, draws, tally_damage, tally_kills
    )
    return n_fix, destroyed


class Stepper:
    """Advances a world, its robots' chassis and the referee together, one physics step."""

    def __init__(self, world: World, chassis: Chassis, referee: Referee) -> None:
        self.world, self.chassis, self.referee = world, chassis, referee
        n = world.n_robots
        self._vel = np.zeros((2, n, 3))
        self._fix = np.zeros(n, dtype=np.bool_)

    def step(
        self, poses: np.ndarray, cmd: np.ndarray, targets: np.ndarray, tally: StepTally
    ) -> int:
        """One physics step under body-frame commands ``cmd`` (N, 3); robots fire at
        ``targets`` (N,) (−1: hold fire). ``poses`` (N, 3) is updated in place and the
        referee's tallies and ``tally`` are updated. Returns how many robots were destroyed.
        """
        ref = self.referee
        state, head, n_sub, sub_dt = self.chassis.tick()
        _drive(cmd, state, head, n_sub, sub_dt, poses, ref.alive, self._vel)
        raw = self.world.advance(self._vel)
        n_fix, destroyed = _settle_and_fire(
            raw, poses, ref.alive, self._fix, ref.fl, ref.it, targets, ref.boxes,
            ref.n_static, ref.draws(), tally.damage, tally.kills,
        )  # fmt: skip
        if n_fix:
            self.world.fix(self._fix, poses)
        if destroyed:
            ref.after_kills()
        return destroyed
