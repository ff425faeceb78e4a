"""The ``sawyer`` adapter: the real arm, reached through its robot-side bridge over zenoh.

The bridge (``bridge/intera_bridge.py`` on the robot's PC, or :mod:`~legws_daemon.hardware.
fake_bridge` without a robot) publishes joint states on ``legws/<robot>/bridge/state`` and
applies joint velocity commands from ``legws/<robot>/bridge/command`` (contract:
``docs/bridge.md``). The adapter keeps a kinematic model of the Sawyer to turn the measured
joint angles into the EE pose, and an EE velocity into joint velocities with mink's
differential IK (:class:`~legws_daemon.robot.mink_ik.MinkVelocityIK`: a QP whose joint speed
and position limits are hard constraints, so the twist is tracked as well as they allow).
A solver failure is not covered up by another method: the command raises, and the daemon
halts the arm and reports the fault.

Thread safety: the state callback runs on a zenoh thread and only fills the newest-state
slot (under a lock); every other method is meant for one control thread.
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import TYPE_CHECKING, Literal

import numpy as np
import zenoh

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import BridgeTimeoutError, HardwareError, InputError, LegwsError
from legws_daemon.formats.bridge_messages import (
    JOINT_SPEED_LIMITS,
    MAX_TTL,
    BridgeCommand,
    BridgeState,
    bridge_keys,
    parse_state,
)
from legws_daemon.formats.messages import dump
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState, model_state, register
from legws_daemon.robot.kinematics import ORIENTATION_GAIN, small_rotation_error
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.scene import Scene

if TYPE_CHECKING:
    from legws_daemon.robot.mink_ik import MinkVelocityIK

#: Zero-velocity commands sent by :meth:`SawyerAdapter.disconnect`, and their spacing (s).
STOP_REPEATS = 3
STOP_SPACING = 0.01
#: A command lives this many control periods on the bridge (its deadman), at most MAX_TTL.
TTL_PERIODS = 2.0

_SPEED_LIMITS = np.asarray(JOINT_SPEED_LIMITS, dtype=np.float64)


@register("sawyer")
class SawyerAdapter(Adapter):
    """The Sawyer through its bridge: joint states in, joint velocity commands out.

    Args:
        profile: the hardware profile (``sawyer.bridge_timeout`` and
            ``sawyer.heartbeat_timeout``; keys under ``legws/<profile.robot>/bridge/``).
        scene: the scene around the robot (its kinematic model is built from it).
        session: the daemon's open zenoh session; required, and never closed here.

    Attributes:
        rejected: how many state messages failed validation (they are never used).
        last_rejection: the message of the latest rejection, or ``None``.
    """

    def __init__(
        self, profile: ProfileSpec, scene: Scene, session: zenoh.Session | None = None
    ) -> None:
        super().__init__(profile, scene, session)
        if session is None:
            raise LegwsError("the sawyer adapter needs the daemon's zenoh session, got None")
        if profile.sawyer.command != "joint_velocity":
            raise InputError(
                f"'{profile.sawyer.command}' is not supported by the bridge contract; "
                "use 'joint_velocity'",
                field="sawyer.command",
            )
        self._session = session
        keys = bridge_keys(profile.robot)
        self.state_key = keys["state"]
        self.command_key = keys["command"]
        self.ttl = min(TTL_PERIODS * self.dt, MAX_TTL)
        self.rejected = 0
        self.last_rejection: str | None = None
        self._lock = threading.Lock()
        self._latest: tuple[BridgeState, float] | None = None  # (message, monotonic receipt)
        self._first = threading.Event()
        self._subscriber: zenoh.Subscriber[None] | None = None
        self._publisher: zenoh.Publisher | None = None
        self._fk: World | None = None  # the kinematic model (the control thread's)
        self._ik: MinkVelocityIK | None = None
        self._seq = 0
        self._gripper: Literal["open", "closed"] | None = None

    # --- connection -------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._subscriber is not None

    def connect(self) -> None:
        """Subscribe to the bridge's state and wait for its first valid message.

        Raises:
            BridgeTimeoutError: no valid state within ``sawyer.bridge_timeout``.
            HardwareError: the session refused the subscription.
        """
        if self.connected:
            return
        if self._fk is None:
            # with the link meshes: the motion planner checks collisions on a twin of it
            self._fk = World(self.scene)
        if self._ik is None:
            # imported here: mink and qpsolvers add ~0.25 s to the import, for this adapter only
            from legws_daemon.robot.mink_ik import MinkVelocityIK

            self._ik = MinkVelocityIK(self._fk)
        with self._lock:
            self._latest = None
        self._first.clear()
        try:
            self._publisher = self._session.declare_publisher(self.command_key)
            self._subscriber = self._session.declare_subscriber(self.state_key, self._on_state)
        except zenoh.ZError as err:
            self._undeclare()
            raise HardwareError(
                f"cannot reach the bridge keys under {self.state_key}: {err}"
            ) from None
        timeout = self.profile.sawyer.bridge_timeout
        if not self._first.wait(timeout):
            self._undeclare()
            with self._lock:
                rejected, last = self.rejected, self.last_rejection
            detail = f"; {rejected} invalid message(s) rejected, last: {last}" if rejected else ""
            raise BridgeTimeoutError(
                f"no valid joint state on '{self.state_key}' within bridge_timeout "
                f"{timeout:g} s: is the bridge running and connected?{detail}"
            )

    def disconnect(self) -> None:
        """Send zero joint velocities a few times, then stop listening (idempotent).

        The session stays open: the daemon owns it.
        """
        if self._publisher is not None:
            for i in range(STOP_REPEATS):
                if i:
                    time.sleep(STOP_SPACING)
                try:
                    self.halt()
                except (zenoh.ZError, LegwsError):
                    break  # the session is already closed: the bridge's ttl stops the arm
        self._undeclare()

    def _undeclare(self) -> None:
        for entity in (self._subscriber, self._publisher):
            if entity is not None:
                # a closed session has undeclared everything already
                with contextlib.suppress(zenoh.ZError):
                    entity.undeclare()  # type: ignore[no-untyped-call]
        self._subscriber = None
        self._publisher = None

    # --- state --------------------------------------------------------------------
    def _on_state(self, sample: zenoh.Sample) -> None:
        """zenoh callback: validate a state message and keep it as the newest."""
        received = time.monotonic()
        try:
            msg = parse_state(sample.payload.to_bytes(), self.state_key)
        except InputError as err:
            with self._lock:
                self.rejected += 1
                self.last_rejection = str(err)
            return
        with self._lock:
            self._latest = (msg, received)
        self._first.set()

    def _fresh(self) -> tuple[BridgeState, float]:
        """The newest state and its receive time, if fresh and the robot can move."""
        if not self.connected:
            raise LegwsError("the sawyer adapter is not connected")
        with self._lock:
            latest = self._latest
        if latest is None:
            raise HardwareError(f"no joint state received on '{self.state_key}'")
        msg, received = latest
        age = time.monotonic() - received
        limit = self.profile.sawyer.heartbeat_timeout
        if age > limit:
            raise HardwareError(
                f"bridge heartbeat lost: the newest joint state on '{self.state_key}' is "
                f"{age:.3f} s old (heartbeat_timeout {limit:g} s)"
            )
        if msg.estop:
            raise HardwareError("the robot's emergency stop is engaged (bridge reports estop)")
        if not msg.enabled:
            raise HardwareError("the robot is disabled (bridge reports enabled=false)")
        return msg, received

    def _model(self) -> World:
        if self._fk is None:
            raise LegwsError("the sawyer adapter is not connected")
        return self._fk

    def _solver(self) -> MinkVelocityIK:
        if self._ik is None:
            raise LegwsError("the sawyer adapter is not connected")
        return self._ik

    @property
    def kinematics(self) -> World:
        return self._model()

    def read_state(self) -> RobotState:
        """The newest measured state, with the EE and link poses from the kinematic model.

        Raises:
            HardwareError: the state is older than ``heartbeat_timeout``, or the bridge
                reports an engaged emergency stop or a disabled robot.
        """
        msg, received = self._fresh()
        model = self._model()
        model.set_q(np.array(msg.q, dtype=np.float64))
        return model_state(model, received, msg.gripper == "closed")

    # --- commands -----------------------------------------------------------------
    def _command(
        self, state: RobotState, velocity: FloatArray, hold: FloatArray | None, box: Box
    ) -> None:
        """Joint velocities realising the EE velocity from this tick's measured ``q``.

        The twist is tracked by the QP within the joint limits; the box was enforced on
        ``velocity`` by the envelope (first order, one period).

        Raises:
            InputError: a non-finite orientation to hold (nothing is sent).
            InfeasibleError: the IK's QP found no solution (nothing is sent; the daemon
                halts the arm on any error).
        """
        dq = np.zeros(7)
        if np.any(velocity):
            R = state.ee_rotation
            target = R if hold is None else np.asarray(hold, dtype=np.float64)
            twist = np.concatenate([velocity, ORIENTATION_GAIN * small_rotation_error(R, target)])
            dq = self._solver().joint_velocity(state.q, twist, self.dt)
            # the contract's limits (bridge_messages); the IK keeps to the same values
            dq = np.clip(dq, -_SPEED_LIMITS, _SPEED_LIMITS)
        # a zero command moves nothing: no orientation correction, no null-space drift
        self._publish(dq)

    def _command_joints(self, state: RobotState, qdot: FloatArray) -> None:
        """Publish joint velocities the envelope has already clamped."""
        self._publish(np.clip(qdot, -_SPEED_LIMITS, _SPEED_LIMITS))

    def halt(self) -> None:
        """Publish zero joint velocities now, without reading the state (e.g. on a fault)."""
        self._publish(np.zeros(7))

    def grip(self, closed: bool) -> None:
        """Request the gripper state; sent now (with zero joint velocities) and with every
        later command."""
        self._gripper = "closed" if closed else "open"
        self.halt()

    def _publish(self, dq: FloatArray) -> None:
        if self._publisher is None:
            raise LegwsError("the sawyer adapter is not connected")
        command = BridgeCommand.model_validate(
            {
                "schema": 1,
                "seq": self._seq,
                "stamp": time.time(),
                "mode": "joint_velocity",
                "dq": [float(v) for v in dq],
                "ttl": self.ttl,
                "gripper": self._gripper,
            }
        )
        self._seq += 1
        self._publisher.put(dump(command))
