"""A fake robot-side bridge: the bridge contract (``docs/bridge.md``) without a robot.

It plays the part of ``bridge/intera_bridge.py`` for tests and for trying the ``sawyer``
profile on a desk: a thread integrates the commanded joint velocities at its own rate
(clipped to the joint speed and position limits, zero once a command's ttl expires, zero
after a rejected command) and publishes the joint state, its heartbeat. Faults can be
injected: a lost heartbeat (:meth:`FakeBridge.stop_publishing`), an emergency stop
(:meth:`FakeBridge.set_estop`), a disabled robot (:meth:`FakeBridge.set_enabled`).
"""

from __future__ import annotations

import contextlib
import threading
import time
from types import TracebackType
from typing import Literal

import numpy as np
import zenoh
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.bridge_messages import (
    JOINT_SPEED_LIMITS,
    BridgeCommand,
    BridgeState,
    GripperState,
    bridge_keys,
    parse_command,
)
from legws_daemon.formats.messages import dump
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.scene.scene import Scene

#: Time the fake gripper takes to open or close, s.
GRIPPER_TIME = 0.2

_SPEED_LIMITS = np.asarray(JOINT_SPEED_LIMITS, dtype=np.float64)


class FakeBridge:
    """The bridge side of the contract, in a thread of this process.

    Args:
        session: an open zenoh session (the caller owns it and closes it).
        robot: the robot name: keys under ``legws/<robot>/bridge/``.
        scene: the scene whose EE home pose gives the default start configuration.
        q0: start joint angles (7,), rad; default: the scene's home configuration.
        rate_hz: integration and state publication rate.

    Attributes:
        rejected: commands that failed validation (each one stopped the arm).
        received: valid commands received (those ignored while disabled included).
        last_rejection: the message of the latest rejection, or ``None``.
    """

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        scene: Scene,
        *,
        q0: ArrayLike | None = None,
        rate_hz: float = 200.0,
    ) -> None:
        if not 1.0 <= rate_hz <= 1000.0:
            raise InputError(f"must be in [1, 1000] Hz, got {rate_hz:g}", field="rate_hz")
        world = World(scene, visual=False)
        self.lower = np.array(world.arm.lower)
        self.upper = np.array(world.arm.upper)
        if q0 is None:
            start = home_configuration(world, scene.home.position, scene.home.rotation).q
        else:
            start = np.asarray(q0, dtype=np.float64)
            if start.shape != (7,) or not np.all(np.isfinite(start)):
                raise InputError(f"must be 7 finite joint angles, got {start.tolist()}", field="q0")
            if np.any(start < self.lower) or np.any(start > self.upper):
                raise InputError("outside the joint position limits", field="q0")
        self._session = session
        keys = bridge_keys(robot)
        self.state_key = keys["state"]
        self.command_key = keys["command"]
        self.period = 1.0 / rate_hz
        self.rejected = 0
        self.received = 0
        self.last_rejection: str | None = None
        self._lock = threading.Lock()
        self._q = np.array(start, dtype=np.float64)
        self._t = time.monotonic()  # integrated up to this time
        self._command: tuple[BridgeCommand, float] | None = None  # (command, receive time)
        self._gripper_target: Literal["open", "closed"] = "open"
        self._gripper_done = 0.0  # monotonic time the gripper reaches its target
        self._enabled = True
        self._estop = False
        self._publishing = True
        self._seq = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._subscriber: zenoh.Subscriber[None] | None = None
        self._publisher: zenoh.Publisher | None = None

    # --- life cycle ---------------------------------------------------------------
    def start(self) -> None:
        """Subscribe to commands and start integrating and publishing (idempotent)."""
        if self._thread is not None:
            return
        self._publisher = self._session.declare_publisher(self.state_key)
        self._subscriber = self._session.declare_subscriber(self.command_key, self._on_command)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="fake-bridge", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread and undeclare (idempotent); the session stays open."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            if self._thread.is_alive():
                raise LegwsError("the fake bridge thread did not stop within 5 s")
            self._thread = None
        for entity in (self._subscriber, self._publisher):
            if entity is not None:
                with contextlib.suppress(zenoh.ZError):  # a closed session: nothing left
                    entity.undeclare()  # type: ignore[no-untyped-call]
        self._subscriber = None
        self._publisher = None

    def __enter__(self) -> FakeBridge:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # --- faults -------------------------------------------------------------------
    def stop_publishing(self) -> None:
        """Simulate a lost heartbeat: keep running, publish no more state."""
        with self._lock:
            self._publishing = False

    def resume_publishing(self) -> None:
        with self._lock:
            self._publishing = True

    def set_estop(self, engaged: bool) -> None:
        """Engage (which also disables the robot, as Intera does) or release the e-stop."""
        with self._lock:
            self._advance(time.monotonic())
            self._estop = engaged
            if engaged:
                self._enabled = False
                self._command = None

    def set_enabled(self, enabled: bool) -> None:
        """Enable or disable the robot; enabling is refused while the e-stop is engaged."""
        with self._lock:
            if enabled and self._estop:
                raise LegwsError("cannot enable the robot while its emergency stop is engaged")
            self._advance(time.monotonic())
            self._enabled = enabled
            if not enabled:
                self._command = None

    # --- observation --------------------------------------------------------------
    @property
    def q(self) -> FloatArray:
        """The joint angles now, rad."""
        with self._lock:
            self._advance(time.monotonic())
            return self._q.copy()

    @property
    def gripper(self) -> GripperState:
        with self._lock:
            return self._gripper_state(time.monotonic())

    def _gripper_state(self, now: float) -> GripperState:
        return "moving" if now < self._gripper_done else self._gripper_target

    # --- the bridge's work ----------------------------------------------------------
    def _on_command(self, sample: zenoh.Sample) -> None:
        """zenoh callback: a valid command replaces the current one; an invalid one stops."""
        now = time.monotonic()
        try:
            command = parse_command(sample.payload.to_bytes(), self.command_key)
        except InputError as err:
            with self._lock:
                self._advance(now)
                self.rejected += 1
                self.last_rejection = str(err)
                self._command = None
            return
        with self._lock:
            self._advance(now)
            self.received += 1
            if not self._enabled or self._estop:
                return  # never moves while disabled or e-stopped
            self._command = (command, now)
            if command.gripper is not None and command.gripper != self._gripper_target:
                self._gripper_target = command.gripper
                self._gripper_done = now + GRIPPER_TIME

    def _advance(self, now: float) -> None:
        """Integrate the current command from the last integration time to ``now``.

        Called with the lock held, before anything changes the command or the robot's
        state, so the motion is exact piecewise: a command acts from its receipt until it
        is replaced, rejected or expired.
        """
        start, self._t = self._t, max(self._t, now)
        if self._command is None or now <= start:
            return
        command, received = self._command
        expires = received + command.ttl
        active = min(now, expires) - start
        if active > 0.0 and self._enabled and not self._estop:
            dq = np.clip(np.asarray(command.dq), -_SPEED_LIMITS, _SPEED_LIMITS)
            self._q = np.clip(self._q + dq * active, self.lower, self.upper)
        if now >= expires:
            self._command = None  # the deadman: no fresh command, no motion

    def _tick(self, now: float, previous: tuple[float, FloatArray]) -> tuple[bytes, FloatArray]:
        """Advance to ``now`` and build the state message (empty when not publishing)."""
        with self._lock:
            self._advance(now)
            t_prev, q_prev = previous
            dq = (self._q - q_prev) / (now - t_prev) if now > t_prev else np.zeros(7)
            state = BridgeState.model_validate(
                {
                    "schema": 1,
                    "seq": self._seq,
                    "stamp": time.time(),
                    "q": self._q.tolist(),
                    "dq": dq.tolist(),
                    "gripper": self._gripper_state(now),
                    "enabled": self._enabled,
                    "estop": self._estop,
                }
            )
            self._seq += 1
            q = self._q.copy()
            publishing = self._publishing
        return (dump(state) if publishing else b""), q

    def _run(self) -> None:
        now = time.monotonic()
        with self._lock:
            previous = (now, self._q.copy())
        deadline = now
        while True:
            deadline += self.period
            if self._stop.wait(max(0.0, deadline - time.monotonic())):
                return
            now = time.monotonic()
            if now - deadline > self.period:
                deadline = now  # late: resynchronise instead of bursting
            payload, q = self._tick(now, previous)
            previous = (now, q)
            publisher = self._publisher
            if payload and publisher is not None:
                try:
                    publisher.put(payload)
                except zenoh.ZError:
                    return  # the session was closed under us
