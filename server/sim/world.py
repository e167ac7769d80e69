"""The PyBullet side of the arena: static field, robot bodies, stepping and pose readout.

Each :class:`World` owns its own PyBullet client in DIRECT mode and passes the client id on
every call, so any number of arenas can live in one process without interfering. Robots are
planar: there is no gravity and no floor, each physics step sets every live robot's velocity
from the chassis model (z, roll and pitch rates zero) and PyBullet resolves the collisions
with walls, obstacles and other robots; any out-of-plane drift is projected away.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import math

import numba
import numpy as np
import pybullet as pb

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.server.sim import field as F

ROBOT_Z = F.ROBOT_HEIGHT / 2.0
PLANE_TOL = 1e-3
"""Out-of-plane drift (m, or quaternion x/y) beyond which a robot is put back on the plane."""
_chain = itertools.chain.from_iterable
_drain = collections.deque(maxlen=0).extend
"""Consume an iterator for its side effects (the fastest way in CPython)."""


class World:
    """A PyBullet world holding the RMUA field and ``n_robots`` robot bodies."""

    def __init__(
        self, n_robots: int, physics_dt: float = F.PHYSICS_DT, gui: bool = False, n_blue: int = 0
    ) -> None:
        self.n_robots = n_robots
        self.physics_dt = physics_dt
        self.gui, self.n_blue = gui, n_blue
        self.client = pb.connect(pb.GUI if gui else pb.DIRECT)
        if self.client < 0:  # PyBullet allows one GUI per process, and needs a display
            raise InvalidOptionError(
                "option gui=True: PyBullet could not open its window (one per process)"
            )
        if gui:  # top-down camera over the field, no side panels
            pb.configureDebugVisualizer(pb.COV_ENABLE_GUI, 0, physicsClientId=self.client)
            pb.resetDebugVisualizerCamera(
                6.0, 0.0, -89.9, [F.CENTER[0], F.CENTER[1], 0.0], physicsClientId=self.client
            )
        self.bodies: list[int] = []
        self.static_bodies: list[int] = []
        self._robot_shape = -1

    # --- building -----------------------------------------------------------------------
    def build(self, poses: np.ndarray) -> None:
        """Place fresh robot bodies at ``poses`` (N, 3) x, y, yaw; build the field once.

        The robots of the previous episode are removed and new bodies created, which drops
        every contact manifold and solver warm-start involving them (static-static pairs
        keep none), so an episode never inherits state from the one before: episode n of a
        long-lived arena is bit-identical to the same episode in a fresh arena. Rebuilding
        only the four robots costs a few milliseconds instead of the ~20 ms of a full
        ``resetSimulation`` and field rebuild.
        """
        cid = self.client
        if not self.static_bodies:
            self._build_field()
        for body in self.bodies:
            pb.removeBody(body, physicsClientId=cid)
        self.bodies = []
        for x, y, yaw in poses:
            body = pb.createMultiBody(
                baseMass=F.ROBOT_MASS,
                baseCollisionShapeIndex=self._robot_shape,
                basePosition=[x, y, ROBOT_Z],
                baseOrientation=pb.getQuaternionFromEuler([0, 0, yaw]),
                useMaximalCoordinates=True,
                physicsClientId=cid,
            )
            pb.changeDynamics(
                body,
                -1,
                lateralFriction=0.0,
                restitution=0.0,
                linearDamping=0.0,
                angularDamping=0.0,
                physicsClientId=cid,
            )
            self.bodies.append(body)
        if self.gui:
            self._colour()

    def _build_field(self) -> None:
        """Engine settings, walls and obstacles, and the shared robot collision shape."""
        cid = self.client
        pb.resetSimulation(physicsClientId=cid)
        pb.setGravity(0, 0, 0, physicsClientId=cid)
        pb.setPhysicsEngineParameter(
            fixedTimeStep=self.physics_dt,
            numSubSteps=1,
            numSolverIterations=10,
            deterministicOverlappingPairs=1,
            physicsClientId=cid,
        )
        self.static_bodies = [self._box(*b) for b in _static_boxes()]
        self._robot_shape = pb.createCollisionShape(
            pb.GEOM_BOX,
            halfExtents=[F.ROBOT_LENGTH / 2, F.ROBOT_WIDTH / 2, F.ROBOT_HEIGHT / 2],
            physicsClientId=cid,
        )

    def _colour(self) -> None:
        """Team colours for robots, dark tall and light low obstacles (the GUI only)."""
        cid = self.client
        for i, body in enumerate(self.bodies):
            rgba = [0.16, 0.43, 0.9, 1] if i < self.n_blue else [0.86, 0.2, 0.2, 1]
            pb.changeVisualShape(body, -1, rgbaColor=rgba, physicsClientId=cid)
        for body, box in zip(self.static_bodies, _static_boxes(), strict=True):
            tall = box[5] > F.ARMOR_HEIGHT
            rgba = [0.27, 0.27, 0.31, 1] if tall else [0.67, 0.67, 0.69, 1]
            pb.changeVisualShape(body, -1, rgbaColor=rgba, physicsClientId=cid)

    def _box(self, cx: float, cy: float, hx: float, hy: float, yaw: float, h: float) -> int:
        cid = self.client
        shape = pb.createCollisionShape(
            pb.GEOM_BOX, halfExtents=[hx, hy, h / 2], physicsClientId=cid
        )
        body = pb.createMultiBody(
            baseMass=0,
            baseCollisionShapeIndex=shape,
            basePosition=[cx, cy, h / 2],
            baseOrientation=pb.getQuaternionFromEuler([0, 0, yaw]),
            useMaximalCoordinates=True,
            physicsClientId=cid,
        )
        pb.changeDynamics(body, -1, lateralFriction=0.0, restitution=0.0, physicsClientId=cid)
        return body

    # --- stepping -----------------------------------------------------------------------
    def step(self, poses: np.ndarray, body_vel: np.ndarray, alive: np.ndarray) -> None:
        """Drive each robot at its body-frame velocity for one physics step, then read poses.

        ``poses`` (N, 3) is updated in place with the poses after the step. ``body_vel`` is
        (N, 3) forward, left, ω (CCW). Destroyed robots are held still: they stay in place
        as obstacles. The arena's hot loop fuses these pieces with the chassis and referee
        kernels (:mod:`~neuronsmae.server.sim.stepper`); this is the same step on its own.
        """
        n = len(self.bodies)
        vel, fix = np.empty((2, n, 3)), np.empty(n, np.bool_)
        world_velocity(np.ascontiguousarray(body_vel, dtype=np.float64), poses, alive, vel)
        if settle_poses(self.advance(vel), poses, alive, fix):
            self.fix(fix, poses)

    def advance(self, vel: np.ndarray) -> np.ndarray:
        """Set every robot's world velocity, step once, and return every base pose.

        ``vel`` (2, N, 3) holds the robots' linear then angular velocities (world frame, from
        :func:`world_velocity`). Returns the readout as a flat (7N,) array: x, y, z, qx, qy,
        qz, qw per robot. These are the PyBullet calls any planar-robot loop needs; the rest
        happens in numba. This runs 50 times per simulated second per arena, so the calls
        are mapped rather than looped and take positional arguments (keyword parsing costs
        per call).
        """
        cid, bodies = self.client, self.bodies
        cids = [cid] * len(bodies)
        lin, ang = vel.tolist()
        _drain(map(pb.resetBaseVelocity, bodies, lin, ang, cids))
        pb.stepSimulation(physicsClientId=cid)
        readout = map(pb.getBasePositionAndOrientation, bodies, cids)  # ((x, y, z), quat)
        return np.fromiter(_chain(_chain(readout)), np.float64, 7 * len(bodies))

    def fix(self, fix: np.ndarray, poses: np.ndarray) -> None:
        """Put the robots flagged by :func:`settle_poses` back on the plane at ``poses``."""
        for body, flagged, (x, y, yaw) in zip(
            self.bodies, fix.tolist(), poses.tolist(), strict=True
        ):
            if flagged:
                self._place(body, (x, y, ROBOT_Z), yaw)

    def replace(self, mask: int, poses: np.ndarray) -> None:
        """:meth:`fix` for the robots in the bit mask ``mask`` (robot ``i`` at ``1 << i``)."""
        reset, cid, i = pb.resetBasePositionAndOrientation, self.client, 0
        while mask:
            if mask & 1:
                x, y, yaw = poses[i].tolist()
                q = (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))  # as in _place
                reset(self.bodies[i], (x, y, ROBOT_Z), q, cid)
            mask >>= 1
            i += 1

    def contacts(self) -> list[int]:
        """Contact points each robot has right now (walls, obstacles or robots); 0 = free."""
        robot = {body: i for i, body in enumerate(self.bodies)}.get
        counts = [0] * len(self.bodies)
        # One query for the whole world (a robot-robot contact counts for both robots, as
        # querying each robot would) instead of one round trip per robot.
        for contact in pb.getContactPoints(physicsClientId=self.client):
            a, b = robot(contact[1]), robot(contact[2])
            if a is not None:
                counts[a] += 1
            if b is not None:
                counts[b] += 1
        return counts

    def _place(self, body: int, pos: tuple[float, float, float], yaw: float) -> None:
        q = (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))
        pb.resetBasePositionAndOrientation(body, pos, q, physicsClientId=self.client)

    def place(self, i: int, x: float, y: float, yaw: float) -> None:
        """Teleport robot ``i`` (used by tests to build scenes)."""
        self._place(self.bodies[i], (x, y, ROBOT_Z), yaw)

    def close(self) -> None:
        """Disconnect the PyBullet client; safe to call twice."""
        if self.client >= 0:
            # Already disconnected (for example at interpreter shutdown) is fine.
            with contextlib.suppress(pb.error):
                pb.disconnect(physicsClientId=self.client)
            self.client = -1


def _static_boxes() -> list[tuple[float, float, float, float, float, float]]:
    """Walls (outside the interior) and obstacles as (cx, cy, hx, hy, yaw, height)."""
    t, h = F.WALL_THICKNESS, F.WALL_HEIGHT
    X, Y = F.FIELD_X, F.FIELD_Y
    walls = [
        (X / 2, -t / 2, X / 2 + t, t / 2, 0.0, h),
        (X / 2, Y + t / 2, X / 2 + t, t / 2, 0.0, h),
        (-t / 2, Y / 2, t / 2, Y / 2 + t, 0.0, h),
        (X + t / 2, Y / 2, t / 2, Y / 2 + t, 0.0, h),
    ]
    return walls + [tuple(row) for row in F.obstacle_array()]  # type: ignore[misc]


@numba.njit(cache=True)
def world_velocity(
    body_vel: np.ndarray, poses: np.ndarray, alive: np.ndarray, out: np.ndarray
) -> None:
    """Body-frame (forward, left, ω) → world linear (``out[0]``) and angular (``out[1]``)
    velocities, ``out`` (2, N, 3). Destroyed robots get zero: they stay where they died."""
    for i in range(poses.shape[0]):
        vf, vl, w = body_vel[i, 0], body_vel[i, 1], body_vel[i, 2]
        for j in range(3):
            out[0, i, j] = 0.0
            out[1, i, j] = 0.0
        if alive[i]:
            c, s = math.cos(poses[i, 2]), math.sin(poses[i, 2])
            out[0, i, 0] = c * vf - s * vl
            out[0, i, 1] = s * vf + c * vl
            out[1, i, 2] = w


@numba.njit(cache=True)
def _settle_one(i, x, y, z, qx, qy, qz, qw, poses, alive, fix) -> bool:
    """Robot ``i``'s part of :func:`settle_poses`; returns its ``fix`` flag."""
    if not alive[i]:
        fix[i] = x != poses[i, 0] or y != poses[i, 1]
    else:
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        fix[i] = abs(z - ROBOT_Z) > PLANE_TOL or abs(qx) > PLANE_TOL or abs(qy) > PLANE_TOL
        poses[i, 0], poses[i, 1], poses[i, 2] = x, y, yaw
    return fix[i]


@numba.njit(cache=True)
def settle_poses(raw: np.ndarray, poses: np.ndarray, alive: np.ndarray, fix: np.ndarray) -> int:
    """Planar poses from PyBullet's flat readout ``raw`` (7N,), in place; flag robots to
    re-place.

    A live robot takes its new (x, y, yaw) and is flagged in ``fix`` when it drifted out of
    the plane. A destroyed robot keeps its pose and is flagged when something pushed it, so
    that it is held exactly where it died. Returns how many robots are flagged.
    """
    n_fix = 0
    for i in range(poses.shape[0]):
        r = 7 * i
        n_fix += _settle_one(
            i, raw[r], raw[r + 1], raw[r + 2], raw[r + 3], raw[r + 4], raw[r + 5], raw[r + 6],
            poses, alive, fix,
        )  # fmt: skip
    return n_fix


@numba.njit(cache=True)
def settle_readout(readout, poses: np.ndarray, alive: np.ndarray, fix: np.ndarray) -> int:
    """:func:`settle_poses` on PyBullet's own answers, a tuple holding each robot's
    ``getBasePositionAndOrientation`` ``((x, y, z), (qx, qy, qz, qw))``: no flat array to
    build in Python."""
    n_fix = 0
    for i in range(poses.shape[0]):
        (x, y, z), (qx, qy, qz, qw) = readout[i]
        n_fix += _settle_one(i, x, y, z, qx, qy, qz, qw, poses, alive, fix)
    return n_fix
