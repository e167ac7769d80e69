"""The PyBullet side of the arena: static field, robot bodies, stepping and pose readout.

Each :class:`World` owns its own PyBullet client in DIRECT mode and passes the client id on
every call, so any number of arenas can live in one process without interfering. Robots are
planar: there is no gravity and no floor, each physics step sets every live robot's velocity
from the chassis model (z, roll and pitch rates zero) and PyBullet resolves the collisions
with walls, obstacles and other robots; any out-of-plane drift is projected away.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pybullet as pb

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.server.sim import field as F

ROBOT_Z = F.ROBOT_HEIGHT / 2.0
_ZERO = (0.0, 0.0, 0.0)


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
        as obstacles. This runs 50 times per simulated second per arena, so it works on
        Python lists and local names rather than numpy scalars.
        """
        cid = self.client
        reset_vel, get_pose = pb.resetBaseVelocity, pb.getBasePositionAndOrientation
        cos, sin, atan2 = math.cos, math.sin, math.atan2
        old = poses.tolist()
        live = alive.tolist()
        for body, (_, _, yaw), (vf, vl, w), a in zip(
            self.bodies, old, body_vel.tolist(), live, strict=True
        ):
            if a:
                c, s = cos(yaw), sin(yaw)
                reset_vel(body, (c * vf - s * vl, s * vf + c * vl, 0.0), (0.0, 0.0, w), cid)
            else:
                reset_vel(body, _ZERO, _ZERO, cid)
        pb.stepSimulation(physicsClientId=cid)
        new = []
        for body, prev, a in zip(self.bodies, old, live, strict=True):
            pos, q = get_pose(body, cid)  # positional: keyword parsing costs per call
            if not a:
                # Hold destroyed robots exactly where they died, even if something pushed them.
                if pos[0] != prev[0] or pos[1] != prev[1]:
                    self._place(body, (prev[0], prev[1], ROBOT_Z), prev[2])
                new.append(prev)
                continue
            yaw = atan2(2.0 * (q[3] * q[2] + q[0] * q[1]), 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]))
            if abs(pos[2] - ROBOT_Z) > 1e-3 or abs(q[0]) > 1e-3 or abs(q[1]) > 1e-3:
                self._place(body, (pos[0], pos[1], ROBOT_Z), yaw)
            new.append((pos[0], pos[1], yaw))
        poses[:] = new

    def contacts(self) -> list[int]:
        """Contact points each robot has right now (walls, obstacles or robots); 0 = free."""
        cid = self.client
        return [len(pb.getContactPoints(bodyA=b, physicsClientId=cid)) for b in self.bodies]

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
