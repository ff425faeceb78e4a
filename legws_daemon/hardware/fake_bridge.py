"""A fake robot-side bridge: the bridge contract (``docs/bridge.md``) without a robot.

It plays the part of ``bridge/intera_bridge.py`` or ``bridge/franka_bridge.py`` for tests
and for trying a ``bridge`` profile on a desk, on any registered arm (its joint vectors,
limits and forward kinematics from the arm's description): a thread integrates the
commanded joint velocities at its own rate and publishes the joint state, its heartbeat.
Like a real bridge it enforces its own limits whatever it is sent (the one guard of every
bridge, :mod:`legws_daemon.safety.limits`, through
:class:`~legws_daemon.safety.bridge_guard.BridgeGuard`: the command rate, joint speed, ttl,
the endpoint's speed and workspace, checked on every integration step with the forward
kinematics of its own joints), stops on any sample on ``legws/<robot>/stop/*`` until a
resume on ``legws/<robot>/bridge/resume``, and reports both in its state (``stopped_by``,
``limited``). Faults can be injected: a lost heartbeat (:meth:`FakeBridge.stop_publishing`),
an emergency stop (:meth:`FakeBridge.set_estop`), a disabled robot
(:meth:`FakeBridge.set_enabled`).

Time is an injected clock (``clock``, default ``time.monotonic``): a test that holds it
moves the arm by advancing it, and publishes states with :meth:`FakeBridge.tick`
(``start(thread=False)``), so nothing it asserts depends on the wall clock.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Literal

import numpy as np
import zenoh
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.bridge_messages import (
    GripperState,
    Limit,
    bridge_contract,
    bridge_keys,
    parse_resume,
    parse_stop,
    stop_role,
)
from legws_daemon.formats.messages import dump
from legws_daemon.formats.profile import BridgeLimitsSpec, WorkspaceBox
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.safety.bridge_guard import BridgeGuard
from legws_daemon.scene.scene import Scene

#: Time the fake gripper takes to open or close, s.
GRIPPER_TIME = 0.2


class FakeBridge:
    """The bridge side of the contract, in a thread of this process.

    Args:
        session: an open zenoh session (the caller owns it and closes it).
        robot: the robot name: keys under ``legws/<robot>/bridge/`` and the stop keys
            ``legws/<robot>/stop/*``.
        scene: the scene whose EE home pose gives the default start configuration.
        arm: the arm's registered name (its joints, limits, model and mount).
        q0: start joint angles (one per joint), rad; default: the scene's home
            configuration.
        rate_hz: integration and state publication rate; the limits are checked on every
            integration step, at most one period long.
        limits: the limits it enforces (a profile's ``[bridge]``; default: the profile
            defaults).
        workspace: the box the endpoint stays in, grown by ``limits.workspace_margin``
            (a profile's ``[workspace]``; default: the profile default).
        clock: monotonic seconds: the command's life, the rate, the integration, the
            gripper (default ``time.monotonic``); the state's ``stamp`` stays wall time.

    Attributes:
        rejected: commands that failed validation (each one stopped the arm).
        received: valid commands received (those ignored while disabled, stopped or over
            the rate included).
        last_rejection: the message of the latest rejection, or ``None``.
        stops: samples received on the stop keys (each one stopped the arm).
        invalid_stops: of those, the ones whose payload did not validate.
        resumes: valid resume messages received.
        rejected_resumes: resume messages that did not validate (the latch stays).
        limits, workspace: as given (or the defaults).
        guard: the limits at work (:class:`~legws_daemon.safety.bridge_guard.BridgeGuard`).
        stopped_by, limited: properties: the latched stop's role; per limit, the times it
            was enforced.
    """

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        scene: Scene,
        *,
        arm: str = "sawyer",
        q0: ArrayLike | None = None,
        rate_hz: float = 200.0,
        limits: BridgeLimitsSpec | None = None,
        workspace: WorkspaceBox | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 1.0 <= rate_hz <= 1000.0:
            raise InputError(f"must be in [1, 1000] Hz, got {rate_hz:g}", field="rate_hz")
        world = World(scene, visual=False, arm=arm)
        #: the arm's side of the contract (its joint vectors and limits)
        self.contract = bridge_contract(world.spec)
        dof = world.spec.dof
        self.lower = np.array(world.arm.lower)
        self.upper = np.array(world.arm.upper)
        if q0 is None:
            start = home_configuration(world, scene.home.position, scene.home.rotation).q
        else:
            start = np.asarray(q0, dtype=np.float64)
            if start.shape != (dof,) or not np.all(np.isfinite(start)):
                raise InputError(
                    f"must be {dof} finite joint angles, got {start.tolist()}", field="q0"
                )
            if np.any(start < self.lower) or np.any(start > self.upper):
                raise InputError("outside the joint position limits", field="q0")
        self._session = session
        self.clock = clock
        keys = bridge_keys(robot)
        self.state_key = keys["state"]
        self.command_key = keys["command"]
        self.stop_key = keys["stop"]
        self.resume_key = keys["resume"]
        self.period = 1.0 / rate_hz
        self.limits = limits if limits is not None else BridgeLimitsSpec()
        self.workspace = workspace if workspace is not None else WorkspaceBox()

        def ee_position(q: FloatArray) -> FloatArray:  # called under the lock only
            world.set_q(q)
            return world.ee_position()

        self.guard = BridgeGuard(
            self.limits,
            self.workspace,
            ee_position,
            spec=world.spec,
            lower=self.lower,
            upper=self.upper,
            clock=clock,
        )
        self.rejected = 0
        self.received = 0
        self.last_rejection: str | None = None
        self.stops = 0
        self.invalid_stops = 0
        self.resumes = 0
        self.rejected_resumes = 0
        self._lock = threading.Lock()
        self._q = np.array(start, dtype=np.float64)
        self._t = clock()  # integrated up to this time
        self._gripper_target: Literal["open", "closed"] = "open"
        self._gripper_done = 0.0  # monotonic time the gripper reaches its target
        self._enabled = True
        self._estop = False
        self._publishing = True
        self._seq = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._subscribers: list[zenoh.Subscriber[None]] = []
        self._publisher: zenoh.Publisher | None = None
        self._previous = (self._t, self._q.copy())  # the previous state's time and angles

    # --- life cycle ---------------------------------------------------------------
    def start(self, thread: bool = True) -> None:
        """Subscribe to commands, stops and resumes, and start integrating and publishing
        (idempotent); ``thread=False``: no thread, the caller publishes with :meth:`tick`."""
        if self._thread is not None or self._publisher is not None:
            return
        self._publisher = self._session.declare_publisher(self.state_key)
        self._subscribers = [
            self._session.declare_subscriber(self.command_key, self._on_command),
            self._session.declare_subscriber(self.stop_key, self._on_stop),
            self._session.declare_subscriber(self.resume_key, self._on_resume),
        ]
        self._stop.clear()
        with self._lock:
            self._previous = (self.clock(), self._q.copy())
        if not thread:
            return
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
        for entity in (*self._subscribers, self._publisher):
            if entity is not None:
                with contextlib.suppress(zenoh.ZError):  # a closed session: nothing left
                    entity.undeclare()  # type: ignore[no-untyped-call]
        self._subscribers = []
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
            self._advance(self.clock())
            self._estop = engaged
            if engaged:
                self._enabled = False
                self.guard.clear()

    def set_enabled(self, enabled: bool) -> None:
        """Enable or disable the robot; enabling is refused while the e-stop is engaged."""
        with self._lock:
            if enabled and self._estop:
                raise LegwsError("cannot enable the robot while its emergency stop is engaged")
            self._advance(self.clock())
            self._enabled = enabled
            if not enabled:
                self.guard.clear()

    # --- observation --------------------------------------------------------------
    @property
    def q(self) -> FloatArray:
        """The joint angles now, rad."""
        with self._lock:
            self._advance(self.clock())
            return self._q.copy()

    @property
    def gripper(self) -> GripperState:
        with self._lock:
            return self._gripper_state(self.clock())

    @property
    def stopped_by(self) -> str | None:
        """The role whose stop is latched (``None``: none)."""
        with self._lock:
            return self.guard.stopped_by

    @property
    def limited(self) -> dict[Limit, int]:
        """Per limit, how many times it was enforced since the start."""
        with self._lock:
            self._advance(self.clock())
            return dict(self.guard.counts)

    def _gripper_state(self, now: float) -> GripperState:
        return "moving" if now < self._gripper_done else self._gripper_target

    # --- the bridge's work ----------------------------------------------------------
    def _on_command(self, sample: zenoh.Sample) -> None:
        """zenoh callback: a valid command within the rate replaces the current one (as
        the guard allows); an invalid one, or one over the rate, stops."""
        now = self.clock()
        try:
            command = self.contract.parse_command(sample.payload.to_bytes(), self.command_key)
        except InputError as err:
            with self._lock:
                self._advance(now)
                self.rejected += 1
                self.last_rejection = str(err)
                self.guard.clear()
            return
        with self._lock:
            self._advance(now)
            self.received += 1
            if not self.guard.admit(now):
                return  # over the rate: refused, the arm stopped
            if not self._enabled or self._estop:
                return  # never moves while disabled or e-stopped
            if self.guard.accept(command.dq, command.ttl, now) != "accepted":
                return  # a latched stop: nothing moves, the gripper neither
            if command.gripper is not None and command.gripper != self._gripper_target:
                self._gripper_target = command.gripper
                self._gripper_done = now + GRIPPER_TIME

    def _on_stop(self, sample: zenoh.Sample) -> None:
        """zenoh callback: any sample on a stop key stops and latches, valid or not."""
        now = self.clock()
        key = str(sample.key_expr)
        try:
            parse_stop(sample.payload.to_bytes(), key)
            valid = True
        except InputError:
            valid = False
        with self._lock:
            self._advance(now)
            self.stops += 1
            if not valid:
                self.invalid_stops += 1
            self.guard.stop(stop_role(key))

    def _on_resume(self, sample: zenoh.Sample) -> None:
        """zenoh callback: a valid resume message clears a latched stop."""
        now = self.clock()
        try:
            parse_resume(sample.payload.to_bytes(), self.resume_key)
        except InputError:
            with self._lock:
                self.rejected_resumes += 1
            return
        with self._lock:
            self._advance(now)
            self.resumes += 1
            self.guard.resume()

    def _advance(self, now: float) -> None:
        """Integrate the live command from the last integration time to ``now``, in steps
        of at most one period, each one checked by the guard.

        Called with the lock held, before anything changes the command or the robot's
        state, so the motion is exact piecewise: a command acts from its receipt until it
        is replaced, rejected, refused or expired.
        """
        t, self._t = self._t, max(self._t, now)
        while t < now and self.guard.live is not None:
            end = min(now, t + self.period)
            if self._enabled and not self._estop:
                step = self.guard.step(self._q, t, end)
                if step.duration > 0.0:
                    self._q = np.clip(self._q + step.displacement, self.lower, self.upper)
            t = end

    def _tick(self, now: float, previous: tuple[float, FloatArray]) -> tuple[bytes, FloatArray]:
        """Advance to ``now`` and build the state message (empty when not publishing)."""
        with self._lock:
            self._advance(now)
            t_prev, q_prev = previous
            dq = (self._q - q_prev) / (now - t_prev) if now > t_prev else np.zeros(len(self._q))
            state = self.contract.State.model_validate(
                {
                    "schema": 1,
                    "seq": self._seq,
                    "stamp": time.time(),
                    "q": self._q.tolist(),
                    "dq": dq.tolist(),
                    "gripper": self._gripper_state(now),
                    "enabled": self._enabled,
                    "estop": self._estop,
                    "stopped_by": self.guard.stopped_by,
                    # what was enforced since the previous message actually sent
                    "limited": self.guard.take_limited() if self._publishing else (),
                }
            )
            self._seq += 1
            q = self._q.copy()
            publishing = self._publishing
        return (dump(state) if publishing else b""), q

    def tick(self) -> bool:
        """Advance to the clock's time and publish one state (none while the heartbeat is
        stopped); ``False`` when the session is closed or the bridge not started."""
        now = self.clock()
        payload, q = self._tick(now, self._previous)
        self._previous = (now, q)
        publisher = self._publisher
        if publisher is None:
            return False
        if payload:
            try:
                publisher.put(payload)
            except zenoh.ZError:
                return False  # the session was closed under us
        return True

    def _run(self) -> None:
        """Tick every period of the wall clock (the pacing only: the state is the clock's)."""
        deadline = time.monotonic()
        while True:
            deadline += self.period
            if self._stop.wait(max(0.0, deadline - time.monotonic())):
                return
            if time.monotonic() - deadline > self.period:
                deadline = time.monotonic()  # late: resynchronise instead of bursting
            if not self.tick():
                return
