"""The ``bridge`` adapter: the real arm, reached through its robot-side bridge over zenoh.

Any registered arm (the profile's ``arm``; ``adapter = "sawyer"`` is the same adapter on the
Sawyer, its older name). The bridge (``bridge/intera_bridge.py`` on the Sawyer's PC,
``bridge/franka_bridge.py`` on a Franka's, or :mod:`~legws_daemon.hardware.fake_bridge`
without a robot) publishes joint states on ``legws/<robot>/bridge/state`` and applies joint
velocity commands from ``legws/<robot>/bridge/command`` (contract: ``docs/bridge.md``; the
joint vectors are the arm's, :func:`~legws_daemon.formats.bridge_messages.bridge_contract`).
The adapter keeps a kinematic model of the arm to turn the measured
joint angles into the EE pose, and an EE velocity into joint velocities with mink's
differential IK (:class:`~legws_daemon.robot.mink_ik.MinkVelocityIK`: a QP whose joint speed
and position limits are hard constraints, so the twist is tracked as well as they allow).
A solver failure is not covered up by another method: the command raises, and the daemon
halts the arm and reports the fault. Joint speeds keep to the bridge's own cap
(``bridge.joint_speed_cap``), which the bridge enforces whatever it is sent.

What it believes: only states that validate, and only plausible ones — a joint faster than
its specification between two states, an angle outside its range or an EE outside the
workspace box grown by :data:`PLAUSIBLE_MARGIN` makes every later read a
:class:`~legws_daemon.errors.HardwareError` (a safe stop) until :meth:`BridgeAdapter.resume`,
which the operator's ``reset`` calls. Who may publish states at all is the transport's access
control (``legws secure init``: the bridge's identity only).

Stops: :meth:`BridgeAdapter.stop_by` halts and has the bridge hold a stop
(``legws/<robot>/stop/daemon``); the bridge also holds stops any authenticated role sends on
its own stop key, and reports the holder in its state (``stopped_by``, passed on in
:class:`~legws_daemon.hardware.base.RobotState`); :meth:`BridgeAdapter.resume` clears it.
With nothing at all on the state key within ``bridge_timeout`` the bridge is absent
(:class:`~legws_daemon.errors.BridgeTimeoutError`, the only case ``fallback_to_sim`` acts on).

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

from legws_daemon.arms import ArmSpec
from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import BridgeTimeoutError, HardwareError, InputError, LegwsError
from legws_daemon.formats.bridge_messages import (
    MAX_TTL,
    BridgeState,
    ResumeMessage,
    StopMessage,
    bridge_contract,
    bridge_keys,
    stop_key,
)
from legws_daemon.formats.messages import dump
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState, model_state, register
from legws_daemon.robot.kinematics import ORIENTATION_GAIN, small_rotation_error
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import Box, within_speed
from legws_daemon.scene.scene import Scene
from legws_daemon.transport.session import payload_bytes

if TYPE_CHECKING:
    from legws_daemon.robot.mink_ik import MinkVelocityIK

#: Zero-velocity commands sent by :meth:`BridgeAdapter.disconnect`, and their spacing (s).
STOP_REPEATS = 3
STOP_SPACING = 0.01
#: A command lives this many control periods on the bridge (its deadman), at most MAX_TTL.
TTL_PERIODS = 2.0
#: Plausibility of the measured state: between two joint states a joint moves at most its
#: speed limit times the time between their receipts plus this (bursts after a delay), s.
JUMP_JITTER = 0.02
#: ... and the measured angles lie within the joint limits widened by this, rad.
LIMIT_SLACK = 0.05
#: ... and the EE within the workspace box grown by this, m (the bridge keeps it within
#: ``bridge.workspace_margin`` of the box, 0.02 m by default).
PLAUSIBLE_MARGIN = 0.05
#: How long :meth:`BridgeAdapter.resume` waits for the bridge to clear its stop, s.
RESUME_TIMEOUT = 0.5


def implausible_jump(
    arm: ArmSpec,
    q0: FloatArray | tuple[float, ...],
    q1: FloatArray | tuple[float, ...],
    elapsed: float,
) -> str | None:
    """What makes the step ``q0 -> q1`` in ``elapsed`` seconds impossible for the arm (a
    joint faster than its specification), or ``None``."""
    limits = np.asarray(arm.speed_limits, dtype=np.float64)
    allowed = limits * (max(elapsed, 0.0) + JUMP_JITTER)
    moved = np.abs(np.asarray(q1, dtype=np.float64) - np.asarray(q0, dtype=np.float64))
    over = np.flatnonzero(moved > allowed)
    if over.size == 0:
        return None
    i = int(over[0])
    return (
        f"{arm.hardware_joints[i]} moved {moved[i]:.3f} rad in {elapsed:.3f} s between two "
        f"joint states (at most {limits[i]:g} rad/s)"
    )


def implausible_angles(arm: ArmSpec, q: FloatArray | tuple[float, ...]) -> str | None:
    """A measured angle outside the joint limits (widened by LIMIT_SLACK), or ``None``."""
    qa = np.asarray(q, dtype=np.float64)
    lower, upper = np.asarray(arm.lower), np.asarray(arm.upper)
    over = np.flatnonzero((qa < lower - LIMIT_SLACK) | (qa > upper + LIMIT_SLACK))
    if over.size == 0:
        return None
    i = int(over[0])
    return (
        f"{arm.hardware_joints[i]} at {qa[i]:.3f} rad is outside its range [{lower[i]}, {upper[i]}]"
    )


@register("sawyer")
@register("bridge")
class BridgeAdapter(Adapter):
    """The arm through its bridge: joint states in, joint velocity commands out.

    Args:
        profile: the hardware profile (its ``arm``; ``link.bridge_timeout`` and
            ``link.heartbeat_timeout``; keys under ``legws/<profile.robot>/bridge/``).
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
            raise LegwsError("the bridge adapter needs the daemon's zenoh session, got None")
        if profile.link.command != "joint_velocity":
            raise InputError(
                f"'{profile.link.command}' is not supported by the bridge contract; "
                "use 'joint_velocity'",
                field="link.command",
            )
        #: the arm's side of the contract: its joint vectors, order and limits
        self.contract = bridge_contract(profile.arm)
        self._session = session
        keys = bridge_keys(profile.robot)
        self.state_key = keys["state"]
        self.command_key = keys["command"]
        self.resume_key = keys["resume"]
        self.stop_key = stop_key(profile.robot, "daemon")
        self.ttl = min(TTL_PERIODS * self.dt, MAX_TTL)
        self.rejected = 0
        self.last_rejection: str | None = None
        #: why the bridge's state stopped being believed (latched until :meth:`resume`)
        self.implausible: str | None = None
        self._lock = threading.Lock()
        self._latest: tuple[BridgeState, float] | None = None  # (message, monotonic receipt)
        #: the daemon's resume after its last stall (:meth:`paused`): the heartbeat's age
        #: counts from it — the daemon heard nothing while it stood still
        self._awake = -np.inf
        self._first = threading.Event()
        self._subscriber: zenoh.Subscriber[None] | None = None
        self._publisher: zenoh.Publisher | None = None
        self._signals: zenoh.Publisher | None = None  # resume
        self._stopper: zenoh.Publisher | None = None
        self._resume_seq = 0
        self._fk: World | None = None  # the kinematic model (the control thread's)
        self._ik: MinkVelocityIK | None = None
        self._seq = 0
        self._gripper: Literal["open", "closed"] | None = None

    # --- connection -------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._subscriber is not None

    def _connect(self) -> None:
        """Subscribe to the bridge's state and wait for its first valid message.

        Raises:
            BridgeTimeoutError: no valid state within ``link.bridge_timeout``.
            HardwareError: the session refused the subscription.
        """
        if self.connected:
            return
        if self._fk is None:
            # with the link meshes: the motion planner checks collisions on a twin of it
            self._fk = World(self.scene, arm=self.profile.arm)
        if self._ik is None:
            # imported here: mink and qpsolvers add ~0.25 s to the import, for this adapter only
            from legws_daemon.robot.mink_ik import MinkVelocityIK

            self._ik = MinkVelocityIK(self._fk, speed_limits=self.speed_limits)
        with self._lock:
            self._latest = None
            self.rejected = 0
        self._first.clear()
        try:
            self._publisher = self._session.declare_publisher(self.command_key)
            self._signals = self._session.declare_publisher(self.resume_key)
            self._stopper = self._session.declare_publisher(self.stop_key)
            self._subscriber = self._session.declare_subscriber(self.state_key, self._on_state)
        except zenoh.ZError as err:
            self._undeclare()
            raise HardwareError(
                f"cannot reach the bridge keys under {self.state_key}: {err}"
            ) from None
        timeout = self.profile.link.bridge_timeout
        if not self._first.wait(timeout):
            self._undeclare()
            with self._lock:
                rejected, last = self.rejected, self.last_rejection
            if rejected:  # a bridge is there, and wrong: never a reason to fall back
                raise HardwareError(
                    f"no valid joint state on '{self.state_key}' within bridge_timeout "
                    f"{timeout:g} s: {rejected} invalid message(s) rejected, last: {last}"
                )
            raise BridgeTimeoutError(
                f"no joint state on '{self.state_key}' within bridge_timeout "
                f"{timeout:g} s: is the bridge running and connected?"
            )

    def _disconnect(self) -> None:
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
        for entity in (self._subscriber, self._publisher, self._signals, self._stopper):
            if entity is not None:
                # a closed session has undeclared everything already
                with contextlib.suppress(zenoh.ZError):
                    entity.undeclare()  # type: ignore[no-untyped-call]
        self._subscriber = None
        self._publisher = None
        self._signals = None
        self._stopper = None

    # --- state --------------------------------------------------------------------
    def _on_state(self, sample: zenoh.Sample) -> None:
        """zenoh callback: validate a state message and keep it as the newest."""
        received = time.monotonic()
        try:
            msg = self.contract.parse_state(
                payload_bytes(sample.payload, self.state_key), self.state_key
            )
        except InputError as err:
            with self._lock:
                self.rejected += 1
                self.last_rejection = str(err)
            return
        with self._lock:
            previous = self._latest
            arm = self.contract.arm
            problem = implausible_angles(arm, msg.q)
            if problem is None and previous is not None:
                problem = implausible_jump(arm, previous[0].q, msg.q, received - previous[1])
            if problem is not None and self.implausible is None:
                self.implausible = problem
            self._latest = (msg, received)
        self._first.set()

    def _fresh(self) -> tuple[BridgeState, float]:
        """The newest state and its receive time, if fresh and the robot can move."""
        if not self.connected:
            raise LegwsError("the bridge adapter is not connected")
        with self._lock:
            latest, implausible = self._latest, self.implausible
        if implausible is not None:
            raise HardwareError(
                f"implausible joint state from the bridge: {implausible}; the arm is stopped "
                "(reset to believe the bridge again)"
            )
        if latest is None:
            raise HardwareError(f"no joint state received on '{self.state_key}'")
        msg, received = latest
        age = time.monotonic() - max(received, self._awake)
        limit = self.profile.link.heartbeat_timeout
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
            raise LegwsError("the bridge adapter is not connected")
        return self._fk

    def _solver(self) -> MinkVelocityIK:
        if self._ik is None:
            raise LegwsError("the bridge adapter is not connected")
        return self._ik

    def _kinematics(self) -> World:
        return self._model()

    def _read_state(self) -> RobotState:
        """The newest measured state, with the EE and link poses from the kinematic model.

        Raises:
            HardwareError: the state is older than ``heartbeat_timeout``, or the bridge
                reports an engaged emergency stop or a disabled robot.
        """
        msg, received = self._fresh()
        model = self._model()
        model.set_q(np.array(msg.q, dtype=np.float64))
        state = model_state(model, received, msg.gripper == "closed", msg.stopped_by)
        p = state.ee_position
        if not self.box.contains(p, tol=PLAUSIBLE_MARGIN):
            problem = (
                f"the EE at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m is outside the workspace "
                f"box grown by {PLAUSIBLE_MARGIN:g} m, where the bridge keeps it"
            )
            with self._lock:
                if self.implausible is None:
                    self.implausible = problem
            raise HardwareError(f"implausible joint state from the bridge: {problem}")
        return state

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
        dq = np.zeros(self.contract.arm.dof)
        if np.any(velocity):
            R = state.ee_rotation
            target = R if hold is None else np.asarray(hold, dtype=np.float64)
            twist = np.concatenate([velocity, ORIENTATION_GAIN * small_rotation_error(R, target)])
            dq = self._solver().joint_velocity(state.q, twist, self.dt)
            # the bridge's caps; the IK keeps to the same values (rounding aside)
            dq = within_speed(dq, self.speed_limits)
        # a zero command moves nothing: no orientation correction, no null-space drift
        self._publish(dq)

    def _command_joints(self, state: RobotState, qdot: FloatArray) -> None:
        """Publish joint velocities the envelope has already clamped."""
        self._publish(within_speed(qdot, self.speed_limits))

    def _halt(self) -> None:
        """Publish zero joint velocities now, without reading the state (e.g. on a fault)."""
        self._publish(np.zeros(self.contract.arm.dof))

    def _stop_by(self, by: str) -> None:
        """Halt now and have the bridge hold a stop (``legws/<robot>/stop/daemon``)."""
        self.halt()
        if self._stopper is None:
            raise LegwsError("the bridge adapter is not connected")
        message = StopMessage.model_validate(
            {"schema": 1, "stamp": time.time(), "source": by[:64], "reason": None}
        )
        self._stopper.put(dump(message))

    def _paused(self, resumed: float) -> None:
        """The daemon stood still until ``resumed``: the bridge's heartbeat is judged from
        then (states it sent meanwhile arrive after the resume, or it is silent and faults
        ``heartbeat_timeout`` after it)."""
        self._awake = max(self._awake, resumed)

    def _resume(self) -> None:
        """Believe the bridge again and have it clear its stop; waits up to
        :data:`RESUME_TIMEOUT` for a joint state that shows no stop.

        Raises:
            HardwareError: the bridge still reports a stop (or sends nothing).
        """
        if self._signals is None:
            raise LegwsError("the bridge adapter is not connected")
        with self._lock:
            self.implausible = None
            latest = self._latest
        if latest is not None and latest[0].stopped_by is None:
            return
        sent = time.monotonic()
        message = ResumeMessage.model_validate(
            {"schema": 1, "seq": self._resume_seq, "stamp": time.time()}
        )
        self._resume_seq += 1
        self._signals.put(dump(message))
        deadline = sent + RESUME_TIMEOUT
        while time.monotonic() < deadline:
            time.sleep(0.005)
            with self._lock:
                latest = self._latest
            if latest is not None and latest[1] > sent and latest[0].stopped_by is None:
                return
        holder = latest[0].stopped_by if latest is not None else None
        raise HardwareError(
            f"the bridge still holds the stop from {holder or 'nobody (no joint state)'} "
            f"{RESUME_TIMEOUT:g} s after the resume"
        )

    def _grip(self, closed: bool) -> None:
        """Request the gripper state; sent now (with zero joint velocities) and with every
        later command."""
        self._gripper = "closed" if closed else "open"
        self.halt()

    def _publish(self, dq: FloatArray) -> None:
        if self._publisher is None:
            raise LegwsError("the bridge adapter is not connected")
        command = self.contract.Command.model_validate(
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
