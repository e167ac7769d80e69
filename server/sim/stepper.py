"""The arena's physics steps: chassis, PyBullet and referee with one numba call per step.

A decision is 20 physics steps and each one must drive every robot, step PyBullet, read every
pose and let the referee fire, so the Python around the unavoidable PyBullet calls is most
of the environment's overhead. Here that Python is cut to the minimum.

:meth:`Stepper.run` plays a whole decision. Between two PyBullet steps there is one call,
:func:`_finish`: it turns PyBullet's readout into poses and fires
(:func:`~.world.settle_readout` then :func:`~.shots.fire`), stops destroyed robots, decides
whether the episode goes on, and prepares the next step's velocities (the controller,
:func:`~neuronsmae.server.task.control.control_kernel`, when due, then
:func:`~.chassis.step_kernel` and :func:`~.world.world_velocity`). Its arrays are handed
over once per decision as a table of addresses (:func:`_bind`) and the call goes straight
to the compiled code (:func:`_compiled`), because numba's per-call argument handling would
otherwise cost as much as the kernel's own work.

:meth:`Stepper.step` is one physics step on its own (two calls: :func:`_drive`, then
:meth:`~.world.World.advance`'s PyBullet calls, then :func:`_settle_and_fire`), for the
arena's zones option, whose effects change commands and targets between steps. The pieces
are the same functions the stand-alone ``Chassis.step``, ``World.step`` and
``Referee.physics_step`` use, so all paths give identical results.

These kernels compile in the functions of chassis.py, world.py, shots.py and task/control.py;
numba's cache is keyed on all of those sources (:mod:`.kernel_cache`), so editing any of them
recompiles these too.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np
import pybullet as pb
from numba.core import types
from numba.extending import intrinsic

from neuronsmae.server.sim.chassis import Chassis, step_kernel, stop_row
from neuronsmae.server.sim.referee import _NO_DRAWS, Referee, StepTally
from neuronsmae.server.sim.shots import fire
from neuronsmae.server.sim.world import (
    World,
    _drain,
    settle_poses,
    settle_readout,
    world_velocity,
)
from neuronsmae.server.task.control import Orders, control_kernel

C_HEAD, C_LEN, C_NSUB, C_NSTATIC, C_T, C_LIMIT, C_NBLUE, C_K, C_PERIOD, C_EVERY = range(10)
"""Slots of :meth:`Stepper.run`'s integer control row: chassis delay-line head and length,
chassis sub-steps, static ray blockers, physics steps so far, the episode's limit, blue
robots, the step within the decision, steps per decision, steps between controller updates."""
DESTROYED, ENDED, FIX_SHIFT = 1, 2, 2
""":func:`_finish`'s result: bits for robots destroyed and for the episode's end, and above
``FIX_SHIFT`` one bit per robot to put back on the plane (robot ``i`` at ``1 << FIX_SHIFT + i``)."""


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


@numba.njit(cache=True)
def _control_and_drive(ctl, sub_dt, intent, pts, off, poses, alive, cmd, state, vel) -> None:
    """Step ``ctl[C_K]`` of a decision: the controller when it is due, then :func:`_drive`
    (advancing the chassis delay lines' head as ``Chassis.tick`` does)."""
    if ctl[C_K] % ctl[C_EVERY] == 0:
        control_kernel(poses, alive, intent, pts, off, cmd)
    head = (ctl[C_HEAD] + 1) % ctl[C_LEN]
    ctl[C_HEAD] = head
    _drive(cmd, state, head, ctl[C_NSUB], sub_dt, poses, alive, vel)


# Slots of Stepper.run's table (_bind): the address of each array the per-step kernel uses,
# then the sizes that are not the number of robots.
(
    T_POSES, T_ALIVE, T_FIX, T_FL, T_IT, T_TARGETS, T_BOXES, T_DAMAGE, T_KILLS, T_STATE, T_CMD,
    T_VEL, T_INTENT, T_PTS, T_OFF, T_CTL, T_N, T_N_BOXES, T_STATE_WIDTH, T_N_PTS, T_N_CTL,
) = range(21)  # fmt: skip
TABLE_SIZE = 21


def _pointer(dtype: Any) -> Any:
    """An intrinsic turning an address (int64) into a pointer to ``dtype`` for ``carray``."""

    @intrinsic
    def pointer(typingctx: Any, address: Any) -> Any:
        sig = types.CPointer(dtype)(types.int64)

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            return builder.inttoptr(args[0], context.get_value_type(types.CPointer(dtype)))

        return sig, codegen

    return pointer


_f64_at, _i64_at, _bool_at = _pointer(types.float64), _pointer(types.int64), _pointer(types.boolean)
_F1, _F2, _F3 = numba.float64[::1], numba.float64[:, ::1], numba.float64[:, :, ::1]
_I1, _I2, _B1 = numba.int64[::1], numba.int64[:, ::1], numba.boolean[::1]


@numba.njit(
    numba.void(_I1, _F2, _B1, _B1, _F2, _I2, _I1, _F2, _F1, _F1, _F2, _F2, _F3, _F2, _F2, _I1, _I1),
    cache=True,
)
def _bind(
    table, poses, alive, fix, fl, it, targets, boxes, damage, kills, state, cmd, vel, intent,
    pts, off, ctl,
) -> None:  # fmt: skip
    """Write where the per-step arrays are, and their sizes, into ``table`` (``T_*`` slots).

    :func:`_finish` then takes this one small array instead of 16 (numba converts every
    array argument on every call, a fixed cost that was a third of the kernel's). The
    signature admits only C-contiguous arrays of the dtypes :func:`_views` assumes, and the
    shapes are checked here, so the views are exactly these arrays. The caller must keep
    them alive, and not reallocate them, while the table is in use (``Stepper.run`` holds
    them for the decision).
    """
    n = poses.shape[0]
    if not (
        poses.shape[1] == 3 and alive.shape[0] == n and fix.shape[0] == n
        and fl.shape[1] == n and fl.shape[0] >= 6 and it.shape[1] == n and it.shape[0] >= 3
        and targets.shape[0] == n and boxes.shape[1] == 8 and damage.shape[0] == 2
        and kills.shape[0] == 2 and state.shape[0] == n and cmd.shape[0] == n
        and cmd.shape[1] == 3 and vel.shape[0] == 2 and vel.shape[1] == n and vel.shape[2] == 3
        and intent.shape[0] == n and intent.shape[1] == 5 and pts.shape[1] == 2
        and off.shape[0] == n + 1 and ctl.shape[0] >= 10 and table.shape[0] >= TABLE_SIZE
    ):  # fmt: skip
        raise ValueError("Stepper: array shapes do not match the number of robots")
    table[T_POSES] = poses.ctypes.data
    table[T_ALIVE] = alive.ctypes.data
    table[T_FIX] = fix.ctypes.data
    table[T_FL] = fl.ctypes.data
    table[T_IT] = it.ctypes.data
    table[T_TARGETS] = targets.ctypes.data
    table[T_BOXES] = boxes.ctypes.data
    table[T_DAMAGE] = damage.ctypes.data
    table[T_KILLS] = kills.ctypes.data
    table[T_STATE] = state.ctypes.data
    table[T_CMD] = cmd.ctypes.data
    table[T_VEL] = vel.ctypes.data
    table[T_INTENT] = intent.ctypes.data
    table[T_PTS] = pts.ctypes.data
    table[T_OFF] = off.ctypes.data
    table[T_CTL] = ctl.ctypes.data
    table[T_N], table[T_N_BOXES], table[T_STATE_WIDTH] = n, boxes.shape[0], state.shape[1]
    table[T_N_PTS], table[T_N_CTL] = pts.shape[0], ctl.shape[0]


@numba.njit(cache=True)
def _views(table):
    """The arrays :func:`_bind` recorded in ``table``, as arrays again."""
    n = table[T_N]
    return (
        numba.carray(_f64_at(table[T_POSES]), (n, 3)),
        numba.carray(_bool_at(table[T_ALIVE]), n),
        numba.carray(_bool_at(table[T_FIX]), n),
        numba.carray(_f64_at(table[T_FL]), (6, n)),
        numba.carray(_i64_at(table[T_IT]), (3, n)),
        numba.carray(_i64_at(table[T_TARGETS]), n),
        numba.carray(_f64_at(table[T_BOXES]), (table[T_N_BOXES], 8)),
        numba.carray(_f64_at(table[T_DAMAGE]), 2),
        numba.carray(_f64_at(table[T_KILLS]), 2),
        numba.carray(_f64_at(table[T_STATE]), (n, table[T_STATE_WIDTH])),
        numba.carray(_f64_at(table[T_CMD]), (n, 3)),
        numba.carray(_f64_at(table[T_VEL]), (2, n, 3)),
        numba.carray(_f64_at(table[T_INTENT]), (n, 5)),
        numba.carray(_f64_at(table[T_PTS]), (table[T_N_PTS], 2)),
        numba.carray(_i64_at(table[T_OFF]), n + 1),
        numba.carray(_i64_at(table[T_CTL]), table[T_N_CTL]),
    )


@numba.njit(cache=True)
def _start(table, sub_dt) -> None:
    """A decision's first step: :func:`_control_and_drive` on the arrays in ``table``."""
    poses, alive, _, _, _, _, _, _, _, state, cmd, vel, intent, pts, off, ctl = _views(table)
    _control_and_drive(ctl, sub_dt, intent, pts, off, poses, alive, cmd, state, vel)


@numba.njit(cache=True)
def _finish(readout, table, draws, sub_dt) -> int:
    """The rest of a physics step after PyBullet's, then the next step's velocities.

    On the arrays in ``table`` (:func:`_bind`): :func:`_settle_and_fire` on the readout as
    PyBullet gave it (a tuple of each robot's ``((x, y, z), quaternion)``,
    :func:`~.world.settle_readout`); destroyed robots stopped (``Chassis.stop``, command
    zeroed); the step counted; and, unless the episode is over (the time limit, or a team
    without live robots: ``Referee.check_end``'s test) or the decision is, the next step's
    :func:`_control_and_drive`. Returns the ``DESTROYED`` and ``ENDED`` bits and, from
    ``FIX_SHIFT`` up, the mask of robots flagged in ``fix``.
    """
    (
        poses, alive, fix, fl, it, targets, boxes, tally_damage, tally_kills, state, cmd, vel,
        intent, pts, off, ctl,
    ) = _views(table)  # fmt: skip
    n_fix = settle_readout(readout, poses, alive, fix)
    destroyed = fire(
        poses, alive, fl, it, targets, boxes, ctl[C_NSTATIC], draws, tally_damage, tally_kills
    )
    n = poses.shape[0]
    if destroyed:
        for i in range(n):
            if not alive[i]:
                stop_row(state, i)
                cmd[i, 0], cmd[i, 1], cmd[i, 2] = 0.0, 0.0, 0.0
    t = ctl[C_T] + 1
    ctl[C_T] = t
    blue = red = False
    for i in range(n):
        if alive[i]:
            if i < ctl[C_NBLUE]:
                blue = True
            else:
                red = True
    ended = t >= ctl[C_LIMIT] or not (blue and red)
    k = ctl[C_K] + 1
    ctl[C_K] = k
    if not ended and k < ctl[C_PERIOD]:
        _control_and_drive(ctl, sub_dt, intent, pts, off, poses, alive, cmd, state, vel)
    code = (DESTROYED if destroyed else 0) | (ENDED if ended else 0)
    if n_fix:
        for i in range(n):
            if fix[i]:
                code |= 1 << (FIX_SHIFT + i)
    return code


class Stepper:
    """Advances a world, its robots' chassis and the referee together, one physics step."""

    def __init__(self, world: World, chassis: Chassis, referee: Referee) -> None:
        self.world, self.chassis, self.referee = world, chassis, referee
        n = world.n_robots
        self._vel = np.zeros((2, n, 3))
        self._fix = np.zeros(n, dtype=np.bool_)
        self._ctl = np.zeros(10, dtype=np.int64)
        self._table = np.zeros(TABLE_SIZE, dtype=np.int64)
        self._finish_for: dict[int, Callable[..., int]] = {}

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

    def run(
        self,
        poses: np.ndarray,
        cmd: np.ndarray,
        targets: np.ndarray,
        orders: Orders,
        t: int,
        limit: int,
        period: int,
        every: int,
        tally: StepTally,
    ) -> int:
        """A decision: up to ``period`` physics steps from step ``t`` under ``orders``, the
        controller updating ``cmd`` every ``every`` steps; stops early when the episode ends
        (``limit`` steps, or a team destroyed). Returns the step count after the last step.

        The same steps as ``orders.apply`` every ``every`` steps and :meth:`step` in between,
        with the Python between two PyBullet steps cut to the PyBullet calls of
        :meth:`World.advance <neuronsmae.server.sim.world.World.advance>` (inlined here) and
        one :func:`_finish` call, made straight to its compiled code (:func:`_compiled`) with
        the arrays passed once per decision (:func:`_bind`). The caller decides the
        episode's end (``check_end``).
        """
        world, ref, chassis = self.world, self.referee, self.chassis
        ctl, vel, table = self._ctl, self._vel, self._table
        wheels = chassis.state
        ctl[C_HEAD], ctl[C_LEN], ctl[C_NSUB] = wheels.head, wheels.length, chassis.n_sub
        ctl[C_NSTATIC], ctl[C_T], ctl[C_LIMIT] = ref.n_static, t, limit
        ctl[C_NBLUE], ctl[C_K], ctl[C_PERIOD], ctl[C_EVERY] = ref.n_blue, 0, period, every
        # Held here until the decision is over: the table points into these arrays.
        bound = (
            poses, ref.alive, self._fix, ref.fl, ref.it, targets, ref.boxes, tally.damage,
            tally.kills, wheels.rows, cmd, vel, orders.intent, orders.pts, orders.off, ctl,
        )  # fmt: skip
        _bind(table, *bound)
        sub_dt = chassis.sub_dt
        cid, bodies = world.client, world.bodies
        cids = [cid] * len(bodies)
        finish = self._finish_for.get(len(bodies))
        if finish is None:
            readout = (((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),) * len(bodies)
            finish = _compiled(_finish, (readout, table, _NO_DRAWS, sub_dt))
            self._finish_for[len(bodies)] = finish
        draws, sampled = ref.draws, ref.sampled
        reset_velocity, step_simulation = pb.resetBaseVelocity, pb.stepSimulation
        read_pose = pb.getBasePositionAndOrientation
        _start(table, sub_dt)
        for _ in range(period):
            lin, ang = vel.tolist()
            _drain(map(reset_velocity, bodies, lin, ang, cids))
            step_simulation(cid)
            code = finish(
                tuple(map(read_pose, bodies, cids)),
                table,
                draws() if sampled else _NO_DRAWS,
                sub_dt,
            )
            if code >> FIX_SHIFT:
                world.replace(code >> FIX_SHIFT, poses)
            if code & DESTROYED:
                ref.after_kills()
            if code & ENDED:
                break
        del bound
        wheels.head = int(ctl[C_HEAD])
        return int(ctl[C_T])


def _compiled(kernel: Any, args: tuple) -> Callable[..., Any]:
    """``kernel``'s compiled code for the types of ``args``, callable like ``kernel``.

    Calling a numba dispatcher types every argument on every call before it finds the
    compiled code; :meth:`Stepper.run` calls :func:`_finish` 20 times a decision with
    arguments whose types never change for a given number of robots (the readout tuple,
    the stepper's own table, a float64 array of draws, a float), so it resolves the code
    once and calls it directly. The compiled code itself does not check the types of what it
    is given. The code comes from numba's cache like any other call; should ``compile`` not
    return it, this is the dispatcher itself.
    """
    entry = kernel.compile(tuple(numba.typeof(a) for a in args))
    return entry if callable(entry) else kernel
