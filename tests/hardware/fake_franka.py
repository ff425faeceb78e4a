"""A Franka arm at the hardware edge: what ``bridge/franka_bridge.py`` uses of ``pylibfranka``.

The bridge's own code runs unchanged on it — its control loop (:meth:`FrankaArm.cycle`,
stepped by the test instead of its thread), its ramp, its guard and its state — and only the
arm is faked: a ``Robot`` (``read_once``, ``start_joint_velocity_control``,
``automatic_error_recovery``), its motion handle (``readOnce`` / ``writeOnce``, 1 ms
cycles), the ``RobotState`` fields read (``q``, ``dq``, ``O_T_EE`` column-major in the
base frame, ``robot_mode``, ``control_command_success_rate``), ``Duration`` and the
``Model``'s ``zero_jacobian``. Its kinematics are legws' Panda (the stand-in's MJCF:
:class:`~legws_daemon.robot.world.World` with ``arm="panda"``), read in the arm's base frame
(libfranka's ``O`` frame) at its mount, so the endpoint the bridge guards is the one the
test checks. The arm integrates exactly the velocities written to it, 1 ms at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from legws_daemon.robot.world import World

#: libfranka's control period, s.
CYCLE = 0.001


@dataclass(frozen=True)
class RobotMode:
    name: str


@dataclass(frozen=True)
class Duration:
    seconds: float

    def to_sec(self) -> float:
        return self.seconds


@dataclass(frozen=True)
class FrankaState:
    """The fields of libfranka's ``RobotState`` the bridge reads."""

    q: tuple[float, ...]
    dq: tuple[float, ...]
    O_T_EE: tuple[float, ...]
    robot_mode: RobotMode
    control_command_success_rate: float = 1.0


class JointVelocities:
    """``pylibfranka.JointVelocities``: the command of one cycle."""

    def __init__(self, velocities: list[float]) -> None:
        self.velocities = [float(v) for v in velocities]
        self.motion_finished = False


#: The module the bridge is handed as ``library``: the names it uses.
LIBRARY = SimpleNamespace(
    ControllerMode=SimpleNamespace(JointImpedance="JointImpedance"),
    JointVelocities=JointVelocities,
)


class FakeFranka:
    """The arm: joints integrated from what is written, kinematics from legws' Panda.

    Args:
        world: legws' Panda model (its arm at the table's mount), moved to each state read.
        q0: the start posture, rad.
    """

    def __init__(self, world: World, q0: Any) -> None:
        self.world = world
        self.q = np.array(q0, dtype=np.float64)
        self.dq = np.zeros_like(self.q)
        self.time = 0.0  # the arm's own time: 1 ms per control cycle, s
        self.moving = False
        self.written = 0
        mount = world.spec.mount
        self._origin = np.array([mount.x, mount.y, mount.z])
        c, s = math.cos(mount.yaw), math.sin(mount.yaw)
        self._to_base = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # R(yaw)^T

    # --- pylibfranka.Robot ---------------------------------------------------------
    def read_once(self) -> FrankaState:
        self.time += CYCLE
        return self.state("Idle")

    def start_joint_velocity_control(self, mode: str) -> FakeFranka:
        assert mode == "JointImpedance"
        assert not self.moving, "a second motion started while one runs"
        self.moving = True
        return self

    def automatic_error_recovery(self) -> None:
        pass

    # --- the active motion (libfranka's control handle) ----------------------------
    def readOnce(self) -> tuple[FrankaState, Duration]:  # noqa: N802 (libfranka's name)
        assert self.moving
        return self.state("Move"), Duration(CYCLE)

    def writeOnce(self, command: JointVelocities) -> None:  # noqa: N802 (libfranka's name)
        assert self.moving
        self.dq = np.array(command.velocities)
        self.q = self.q + self.dq * CYCLE
        self.time += CYCLE
        self.written += 1
        if command.motion_finished:
            assert not np.any(self.dq), "a motion finished while the arm moves"
            self.moving = False

    # --- pylibfranka.Model -----------------------------------------------------------
    def zero_jacobian(self, state: FrankaState) -> list[float]:
        """The 6 x 7 Jacobian of the endpoint in the base frame, column-major (42)."""
        self.world.set_q(state.q)
        J = self.world.jacobian()
        base = np.vstack([self._to_base @ J[:3], self._to_base @ J[3:]])
        return [float(v) for v in base.T.reshape(-1)]

    # --- the state -----------------------------------------------------------------
    def state(self, mode: str) -> FrankaState:
        self.world.set_q(self.q)
        rotation = self._to_base @ self.world.ee_rotation()
        position = self._to_base @ (self.world.ee_position() - self._origin)
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rotation, position
        return FrankaState(
            tuple(float(v) for v in self.q),
            tuple(float(v) for v in self.dq),
            tuple(float(v) for v in pose.T.reshape(-1)),  # column-major, as libfranka's
            RobotMode(mode),
        )


@dataclass
class Stepped:
    """The bridge's control loop stepped on the test's clock: :meth:`catch_up` runs its
    cycles until the arm's own time reaches the clock's (1 ms each)."""

    arm: Any  # the bridge's FrankaArm (its thread not started)
    robot: FakeFranka
    start: float
    cycles: int = field(default=0)

    def catch_up(self, now: float) -> None:
        while self.start + self.robot.time < now - CYCLE / 2:
            self.arm.cycle()
            self.cycles += 1
