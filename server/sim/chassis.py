"""Mecanum chassis model: commanded body velocity → actual body velocity, per physics step.

This is the sim-to-real part of the robot (``docs/reference.md``, "Chassis model"):
the rigid body in PyBullet is driven by the velocity this model produces, not by the raw
command, so that robots accelerate, brake and undershoot like the released build's wheels.
It runs for all N robots at once in one numba kernel, because the arena calls it every physics
step and a Python loop per wheel and sub-step would dominate the environment's cost.

Frames. The spec's formulas are in the released build's left-handed frame (vx lateral, positive
to the robot's right; vy forward; ω positive clockwise). The public API uses the project's
right-handed body frame ``(v_forward, v_left, omega_ccw)``. The conversion happens once, inside
the kernel: ``vx = -v_left, vy = v_forward, ω = -omega_ccw`` on the way in, the inverse on the
way out. Every other module sees only the project frame.

Model, per robot. Inverse kinematics gives four target rim speeds (m/s)::

    w0 = -vx - vy - 0.55ω   w1 = vx - vy - 0.55ω   w2 = vx + vy - 0.55ω   w3 = -vx + vy - 0.55ω

Each 0.02 s physics step is split into 0.5 ms sub-steps. Per sub-step and wheel, a discrete
PID on the rim-speed error ``e`` gives ``u = KP·e + KI·Σe + KD·(e - e_prev)``. The derivative
is the plain difference per sub-step, as the spec says; we read the integral the same way, as
the plain sum of errors (clamped to ±500), neither scaled by dt (KI = 0 by default, so this
reading does not touch the calibration); ``u`` is clamped to ±15000. The wheel then
integrates ``α = (u·VK1 ∓ F·R) / Wheel_I`` with R = 0.05 m, friction opposing the wheel's
motion. Friction is Coulomb friction with a static clamp: a wheel at rest stays at rest while
``|u·VK1| ≤ F·R``, and a wheel whose speed would cross zero inside a sub-step stops exactly at
zero (then moves on only with the drive torque in excess of friction, for the rest of the
sub-step). Without the clamp, the sign-switching friction makes a stopped wheel chatter.
Consequence: commands whose steady error is below ``F·R/(KP·VK1)`` per wheel (0.025 m/s at
μ = 0.1, 0.125 m/s at μ = 0.5 with defaults and KI = 0) do not move a robot at rest.

Friction reading ("rolling and sliding combined according to whether the wheel's lateral and
longitudinal slip share a sign"). Wheel i's rim speed is ``c_i·X + d_i·Y - 0.55Ω`` with
``c = (-1, 1, 1, -1)`` and ``d = (-1, -1, 1, 1)``, where (X, Y, Ω) is the body velocity the wheel
model currently produces (forward kinematics of the current wheel speeds, re-evaluated every
sub-step). We call ``c_i·X`` the wheel's lateral slip and ``d_i·Y`` its longitudinal slip. When
they share a sign, or either is zero (|·| < 1e-9 m/s), both frictions resist:
``F = F_r + F_s``; otherwise only ``F_s``. Here ``F_r = M·g·0.8μ/4`` and ``F_s = M·g·μ/4``.
Pure forward, lateral and rotational motion therefore use ``F_r + F_s``; this is the reading
that reproduces the spec's calibration (steady error ``F·R/(KP·VK1)``: a 2 m/s command settles
at ≈1.975 m/s with μ = 0.1 and ≈1.875 m/s with μ = 0.5, time constant
``Wheel_I/(R·KP·VK1) ≈ 0.083 s``). ``M`` enters only through friction.

Forward kinematics: ``X = (-w0 + w1 + w2 - w3)/4, Y = (-w0 - w1 + w2 + w3)/4,
Ω = -(w0 + w1 + w2 + w3)/2.2``.

Output. ``Chassis.step`` returns the MEAN body velocity over the step's sub-steps, not the value
at its end: the rigid body moves at one constant velocity for the whole physics step, and the
mean makes its displacement equal to the wheel model's integrated displacement (the end value
would overshoot every acceleration by half a step).

Delays (NeuronsGym's vx_dt, vy_dt, vw_dt, in seconds, released naming). Each axis of the
command reaches the wheel model ``round(delay / physics_dt)`` physics steps late (half-up;
e.g. 0.1 s → 5 steps). A ring buffer per robot and axis holds the past (scaled, released-frame)
commands; before the first command it holds zeros (the robot was at rest). ``speed_scale``
multiplies all three axes of the command (the robot behaves as if the policy had sent a scaled
command).

The model is open loop with respect to the rigid body: contacts (walls, other robots) do not
feed back into the wheel speeds. The spec has the resulting velocity drive the rigid body and
leaves collisions to the physics engine.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import astuple, dataclass

import numba
import numpy as np

WHEEL_RADIUS = 0.05
"""R (m): rim speed = wheel angular speed × R."""
HALF_TRACK_PLUS_BASE = 0.55
"""Half-track plus half-wheelbase (m), the lever arm of yaw in the Mecanum kinematics."""
GRAVITY = 9.81
INTEGRAL_LIMIT = 500.0
OUTPUT_LIMIT = 15000.0
SLIP_EPS = 1e-9
"""Below this (m/s) a slip component counts as zero, i.e. as sharing the other's sign."""

# Column order of ``ChassisParams.as_row`` (the dataclass field order).
_MU, _KP, _KI, _KD, _VK1, _M, _WI, _VX_DT, _VY_DT, _VW_DT, _SCALE = range(11)
N_PARAMS = 11

S_DELAY = N_PARAMS
"""First of the three columns of :attr:`ChassisState.rows` holding each axis's delay in
physics steps (released vx, vy, ω). The columns before it are the parameters, in
:class:`ChassisParams` field order."""
S_STOPPED = S_DELAY + 3
"""Column of the stopped flag (1.0: destroyed, the command is ignored until ``reset``)."""
S_W = S_STOPPED + 1
"""First of four columns of wheel speeds (rad/s, released wheel order)."""
S_E = S_W + 4
"""First of four columns of the previous sub-step's rim-speed errors."""
S_I = S_E + 4
"""First of four columns of the error sums (the PID's integral)."""
S_BUF = S_I + 4
"""First column of the three delay lines (released vx, vy, ω), ``length`` columns each."""


@dataclass(frozen=True)
class ChassisParams:
    """Per-robot chassis parameters; the released build's context keys are named per field."""

    friction_coeff: float = 0.1
    """``Friction_coeff``: sliding μ; rolling friction uses 0.8μ. The released build used 0.5
    for the learning team, 0.1 is the spec default."""
    kp: float = 8.0
    """``KP``: proportional gain on rim-speed error (m/s)."""
    ki: float = 0.0
    """``KI``: gain on the per-sub-step sum of errors (sum clamped to ±500)."""
    kd: float = 2.0
    """``KD``: gain on the error difference per sub-step (not divided by dt)."""
    vk1: float = 0.375
    """``VK1``: motor torque constant ("motor character"); torque = u·VK1."""
    m: float = 3.4
    """``M``: mass in the wheel model; it enters only the friction forces."""
    wheel_i: float = 0.0125
    """``Wheel_I``: wheel rotational inertia; sets the time constant with KP and VK1."""
    vx_dt: float = 0.0
    """``vx_dt`` (s): delay of the lateral axis (released vx, i.e. the project's v_left)."""
    vy_dt: float = 0.0
    """``vy_dt`` (s): delay of the forward axis (released vy, the project's v_forward)."""
    vw_dt: float = 0.0
    """``vw_dt`` (s): delay of the yaw-rate axis."""
    speed_scale: float = 1.0
    """Multiplies the whole commanded body velocity (the paper's opponent-velocity knob)."""

    def as_row(self) -> np.ndarray:
        """The parameters as the float64 row the kernel reads (columns in field order)."""
        return np.array(astuple(self), dtype=np.float64)


@dataclass
class ChassisState:
    """The wheel model's state of N robots, in the form the kernels read and write.

    :class:`Chassis` owns one and advances it; kernels that fuse the chassis with other
    per-step work (``server/sim/stepper.py``) take ``rows`` and ``head`` from it and give
    the head back when they are done.
    """

    rows: np.ndarray
    """``(N, S_BUF + 3·length)`` float64, one row per robot, updated in place: parameters,
    delays, stopped flag, wheel speeds, errors, error sums and delay lines at the ``S_*``
    columns."""
    length: int
    """Length of each delay line: the longest delay in physics steps, plus one."""
    head: int = 0
    """Delay-line slot the last physics step's command was written to."""


@numba.njit(cache=True, error_model="numpy")
def _wheel(
    w: float,
    target: float,
    e_prev: float,
    acc: float,
    kp: float,
    ki: float,
    kd: float,
    g: float,
    gf: float,
) -> tuple[float, float, float]:
    """One sub-step of one wheel: PID, then Coulomb friction with a static clamp.

    ``g = VK1·dt/Wheel_I`` turns ``u`` into a change of wheel speed (rad/s) and
    ``gf = F·R·dt/Wheel_I`` is friction's change over one sub-step; folding the constants keeps
    the hot loop short. Returns the new wheel speed, the error (next ``e_prev``) and the error
    sum, which is only tracked when KI ≠ 0 (it cannot affect anything otherwise). A scalar
    function so LLVM inlines it and keeps all wheel state in registers.
    """
    e = target - w * WHEEL_RADIUS
    u = kp * e + kd * (e - e_prev)
    if ki != 0.0:
        acc += e
        acc = acc if acc < INTEGRAL_LIMIT else INTEGRAL_LIMIT
        acc = acc if acc > -INTEGRAL_LIMIT else -INTEGRAL_LIMIT
        u += ki * acc
    u = u if u < OUTPUT_LIMIT else OUTPUT_LIMIT
    u = u if u > -OUTPUT_LIMIT else -OUTPUT_LIMIT
    du = u * g
    if w > 0.0:
        d = du - gf
    elif w < 0.0:
        d = du + gf
    elif du > gf:  # at rest: moves only with the torque in excess of static friction
        return du - gf, e, acc
    elif du < -gf:
        return du + gf, e, acc
    else:
        return 0.0, e, acc
    w_new = w + d
    if w_new != 0.0 and (w_new > 0.0) == (w > 0.0):
        return w_new, e, acc
    # The wheel reaches zero after the fraction -w/d of the sub-step; friction turns static
    # there and only the excess torque moves it on for the remaining 1 + w/d.
    if du > gf:
        return (du - gf) * (1.0 + w / d), e, acc
    if du < -gf:
        return (du + gf) * (1.0 + w / d), e, acc
    return 0.0, e, acc


@numba.njit(cache=True, error_model="numpy")
def step_kernel(
    cmd: np.ndarray, state: np.ndarray, head: int, n_sub: int, sub_dt: float, out: np.ndarray
) -> None:
    """Advance every robot's wheels by one physics step; write the mean body velocity to out.

    ``state`` (:attr:`ChassisState.rows`, see the ``S_*`` columns) holds parameters, wheel
    state and the delay lines and is updated in place: one array argument keeps numba's
    per-call dispatch cost low.
    """
    length = (state.shape[1] - S_BUF) // 3
    slip_eps = SLIP_EPS * 4.0 / WHEEL_RADIUS  # the same threshold on sums of wheel speeds
    for i in range(cmd.shape[0]):
        s = state[i]
        if s[S_STOPPED] != 0.0:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 0.0
            continue
        scale = s[_SCALE]
        # Project frame → released frame (vx = -v_left, vy = v_forward, ω = -omega_ccw),
        # then through each axis's delay line.
        s[S_BUF + head] = -cmd[i, 1] * scale
        s[S_BUF + length + head] = cmd[i, 0] * scale
        s[S_BUF + 2 * length + head] = -cmd[i, 2] * scale
        vx = s[S_BUF + (head - int(s[S_DELAY])) % length]
        vy = s[S_BUF + length + (head - int(s[S_DELAY + 1])) % length]
        wz = s[S_BUF + 2 * length + (head - int(s[S_DELAY + 2])) % length]
        t0 = -vx - vy - HALF_TRACK_PLUS_BASE * wz
        t1 = vx - vy - HALF_TRACK_PLUS_BASE * wz
        t2 = vx + vy - HALF_TRACK_PLUS_BASE * wz
        t3 = -vx + vy - HALF_TRACK_PLUS_BASE * wz

        kp = s[_KP]
        ki = s[_KI]
        kd = s[_KD]
        dt_i = sub_dt / s[_WI]
        g = s[_VK1] * dt_i
        f_s = s[_M] * GRAVITY * s[_MU] / 4.0
        gf_both = f_s * 1.8 * WHEEL_RADIUS * dt_i  # F_r + F_s with F_r = 0.8·F_s
        gf_slide = f_s * WHEEL_RADIUS * dt_i

        w0, w1, w2, w3 = s[S_W], s[S_W + 1], s[S_W + 2], s[S_W + 3]
        e0, e1, e2, e3 = s[S_E], s[S_E + 1], s[S_E + 2], s[S_E + 3]
        a0, a1, a2, a3 = s[S_I], s[S_I + 1], s[S_I + 2], s[S_I + 3]
        m0 = m1 = m2 = m3 = 0.0
        for _ in range(n_sub):
            # Slip signs from the wheel model's current body velocity (module docstring):
            # sums of wheel speeds proportional to X and Y, paired as in the output below.
            # Wheels 0, 2 have c·d = +1 (their slips share a sign when X and Y do), wheels
            # 1, 3 have c·d = -1.
            sx = (w1 - w0) + (w2 - w3)
            sy = (w2 - w0) + (w3 - w1)
            if abs(sx) < slip_eps or abs(sy) < slip_eps:
                gf02 = gf_both
                gf13 = gf_both
            elif (sx > 0.0) == (sy > 0.0):
                gf02 = gf_both
                gf13 = gf_slide
            else:
                gf02 = gf_slide
                gf13 = gf_both
            w0, e0, a0 = _wheel(w0, t0, e0, a0, kp, ki, kd, g, gf02)
            w1, e1, a1 = _wheel(w1, t1, e1, a1, kp, ki, kd, g, gf13)
            w2, e2, a2 = _wheel(w2, t2, e2, a2, kp, ki, kd, g, gf02)
            w3, e3, a3 = _wheel(w3, t3, e3, a3, kp, ki, kd, g, gf13)
            m0 += w0
            m1 += w1
            m2 += w2
            m3 += w3
        s[S_W], s[S_W + 1], s[S_W + 2], s[S_W + 3] = w0, w1, w2, w3
        s[S_E], s[S_E + 1], s[S_E + 2], s[S_E + 3] = e0, e1, e2, e3
        s[S_I], s[S_I + 1], s[S_I + 2], s[S_I + 3] = a0, a1, a2, a3

        # Mean rim speeds → forward kinematics → project frame. The pairings make an axis that
        # is not commanded come out exactly 0 (wheels that must cancel are exact negatives or
        # equal), and +0.0 turns -0.0 into 0.0.
        k = WHEEL_RADIUS / n_sub
        m0 *= k
        m1 *= k
        m2 *= k
        m3 *= k
        out[i, 0] = ((m2 - m0) + (m3 - m1)) * 0.25 + 0.0
        out[i, 1] = -(((m1 - m0) + (m2 - m3)) * 0.25) + 0.0
        out[i, 2] = ((m0 + m2) + (m1 + m3)) / (4.0 * HALF_TRACK_PLUS_BASE) + 0.0


@numba.njit(cache=True)
def stop_row(rows: np.ndarray, i: int) -> None:
    """Freeze robot ``i`` of ``rows`` (:attr:`ChassisState.rows`): zero its wheels, PID state
    and delay lines and set its stopped flag."""
    rows[i, S_STOPPED:] = 0.0
    rows[i, S_STOPPED] = 1.0


class Chassis:
    """Wheel state of N robots, advanced one physics step at a time by ``step``."""

    def __init__(self, n_robots: int, physics_dt: float = 0.02, sub_dt: float = 0.0005) -> None:
        """Allocate state for ``n_robots`` and reset them all to default parameters.

        ``physics_dt`` must be a whole multiple of ``sub_dt`` so every physics step has the
        same number of sub-steps (40 by default).
        """
        if n_robots < 1:
            raise ValueError(f"n_robots must be >= 1, got {n_robots}")
        n_sub = round(physics_dt / sub_dt)
        if n_sub < 1 or abs(n_sub * sub_dt - physics_dt) > 1e-9 * physics_dt:
            raise ValueError(f"physics_dt {physics_dt} is not a multiple of sub_dt {sub_dt}")
        self.n_robots = n_robots
        self.physics_dt = float(physics_dt)
        """Length of a physics step (s)."""
        self.sub_dt = float(sub_dt)
        """Length of a wheel-model sub-step (s)."""
        self.n_sub = int(n_sub)
        """Sub-steps per physics step."""
        self.state = ChassisState(np.zeros((n_robots, S_BUF + 3)), 1)
        """Parameters, wheel state and delay lines of every robot."""
        self.reset([ChassisParams()] * n_robots)

    def delay_steps(self, seconds: float) -> int:
        """A delay in seconds quantised to whole physics steps (nearest, halves round up)."""
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise ValueError(f"command delay must be finite and >= 0, got {seconds}")
        return math.floor(seconds / self.physics_dt + 0.5 + 1e-9)

    def reset(self, params: Sequence[ChassisParams]) -> None:
        """Set each robot's parameters and zero wheel speeds, PID state and delay lines."""
        if len(params) != self.n_robots:
            raise ValueError(f"need {self.n_robots} ChassisParams, got {len(params)}")
        delays = np.zeros((self.n_robots, 3))
        for i, p in enumerate(params):
            if not (p.wheel_i > 0.0 and p.friction_coeff >= 0.0 and p.m >= 0.0):
                raise ValueError(f"robot {i}: need wheel_i > 0, friction_coeff >= 0, m >= 0")
            delays[i] = [self.delay_steps(d) for d in (p.vx_dt, p.vy_dt, p.vw_dt)]
        # Delay lines just long enough for the longest delay; zeros = at rest before the start.
        length = int(delays.max()) + 1
        rows = np.zeros((self.n_robots, S_BUF + 3 * length))
        for i, p in enumerate(params):
            rows[i, :N_PARAMS] = p.as_row()
        rows[:, S_DELAY : S_DELAY + 3] = delays
        self.state = ChassisState(rows, length)

    def step(self, cmd: np.ndarray) -> np.ndarray:
        """Advance one physics step under ``cmd`` and return the body velocity to apply.

        ``cmd`` is (N, 3) ``(v_forward, v_left, omega_ccw)`` in each robot's body frame
        (project, right-handed). The result is a new (N, 3) array, same layout and frame: the
        mean body velocity over this physics step (the module docstring says why the mean).
        """
        cmd = np.ascontiguousarray(cmd, dtype=np.float64)  # one numba specialisation only
        if cmd.shape != (self.n_robots, 3):
            raise ValueError(f"cmd must have shape ({self.n_robots}, 3), got {cmd.shape}")
        out = np.empty((self.n_robots, 3))
        step_kernel(cmd, *self.tick(), out)
        return out

    def tick(self) -> tuple[np.ndarray, int, int, float]:
        """Advance the delay lines' head; return ``(state, head, n_sub, sub_dt)`` for one
        :func:`step_kernel` call. For fused per-step kernels that call it from numba."""
        state = self.state
        state.head = (state.head + 1) % state.length
        return state.rows, state.head, self.n_sub, self.sub_dt

    def stop(self, idx: int) -> None:
        """Freeze a destroyed robot: zero its wheels and ignore its command until ``reset``."""
        stop_row(self.state.rows, idx)

    @property
    def rim_speeds(self) -> np.ndarray:
        """Copy of the current wheel rim speeds (N, 4) in m/s, released wheel order and signs."""
        return self.state.rows[:, S_W : S_W + 4] * WHEEL_RADIUS
