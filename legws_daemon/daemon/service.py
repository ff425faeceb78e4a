"""The daemon as a service: zenoh I/O, the fixed-rate loop, telemetry, signals.

Threads: zenoh's callback threads only validate and hand over (the joystick inbox, the
command queue); the loop thread — the only one touching the robot — runs the
controller once per period, publishes status at the profile's status rate and events
as they happen, and logs to Rerun. I/O never blocks the loop: publishing and logging are
asynchronous. Commands cannot stall control: at most :data:`COMMAND_QUEUE` wait (more are
answered ``busy``), the loop takes up at most :data:`COMMANDS_PER_TICK` per tick, and a load
(``load_scene``, ``load_taskgraph``: files, a new MuJoCo world, a plan) is prepared on its
own thread while the robot goes on (:mod:`.loads`), then swapped in at the start of a
tick (the robot stops there, as for any load); the replaced world is freed off the loop
too. A ``stop`` cancels the loads before it. ``status`` and ``hello`` (a joystick session's
key, in the reply to the asker alone: :mod:`.session_keys`) are answered on the zenoh
thread at once. Where each command goes is one table, :data:`ROUTES` (:mod:`.commands`).

On SIGINT/SIGTERM (or ``--duration``) the loop stops within one period; the robot is
sent zero velocity and disconnected, the recording is flushed and closed, the zenoh
session closed. The same shutdown runs when the loop fails (an unexpected exception is a
``fault`` event, then re-raised): every exit path leaves a complete recording.

Faults that do not end the run:

- the adapter raises anything (a bug in an adapter, a library error): it is a
  :class:`~legws_daemon.errors.HardwareError` (the guard in
  :class:`~legws_daemon.hardware.base.Adapter`), so the controller
  makes its safe stop — zero velocity, one ``fault`` event, status keeps publishing;
- the daemon itself stood still (its process paused: SIGSTOP, a swap storm, a debugger;
  two ticks more than :func:`~.ticker.stall_threshold` apart): a ``stall`` event, zero
  velocity, the input heard before dropped (the lease stays with its holder, heard as of
  the resume), and the adapter told (:meth:`~legws_daemon.hardware.base.Adapter.paused`)
  so that the bridge's heartbeat counts from the resume — the daemon's pause is not the
  bridge's silence;
- the recording fails (disk full, a viewer gone, a logging call raising): control goes
  on; the worker counts the problem and the loop reports it as a ``warning`` event
  ``{"telemetry": ...}`` (the first at once, then at most every
  :data:`TELEMETRY_WARNING_INTERVAL` seconds while problems continue).

For a person (``--operator``, an operator file): every certificate is theirs (the
controller's ``operator``), status says whose (``operator_model``), and the live watch
(:mod:`~legws_daemon.autonomy.operator_watch`) re-fits their model from the picks that
complete, on a thread of its own that steps aside while a tick runs. A calibration
(``legws operator calibrate``, :class:`CalibrationSpec`) runs the controller in mode
``calibrate`` and ends the loop after the last target.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import json
import logging
import queue
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import zenoh

import legws_daemon.hardware.bridge  # noqa: F401  (registers "bridge" and "sawyer")
from legws_daemon.autonomy.calibration import CALIBRATION
from legws_daemon.autonomy.confirms import confirm_forecast
from legws_daemon.autonomy.controller import Controller, PreparedLoad
from legws_daemon.autonomy.events import (
    Commit,
    ConfirmsNeeded,
    Deadman,
    Event,
    Fallback,
    Fault,
    InputRejected,
    InsecureTransport,
    OperatorChanged,
    Overrun,
    RealtimeRefused,
    Shutdown,
    Stall,
    Started,
    TelemetryProblem,
    TraceFailed,
    jsonable,
)
from legws_daemon.autonomy.inputs import TickRecord
from legws_daemon.autonomy.modes import Mode
from legws_daemon.autonomy.operator_watch import OperatorWatch
from legws_daemon.core.geometry import FloatArray, yaw_quat
from legws_daemon.core.params import Params
from legws_daemon.daemon.commands import PendingCommand, Request, Route, Where, check_routes
from legws_daemon.daemon.gate import LoopGate
from legws_daemon.daemon.inbox import JoystickInbox, NoInput
from legws_daemon.daemon.loads import LoadPipeline
from legws_daemon.daemon.scheduling import current_priority, enter_realtime
from legws_daemon.daemon.telemetry_worker import TelemetryReport, TelemetryWorker
from legws_daemon.daemon.throttle import Throttle
from legws_daemon.daemon.ticker import Ticker, stall_threshold
from legws_daemon.errors import BridgeTimeoutError, InputError, LegwsError
from legws_daemon.formats.bridge_messages import StopMessage, bridge_keys, parse_stop, stop_role
from legws_daemon.formats.files import LineFile
from legws_daemon.formats.messages import (
    CommandRequest,
    EventMessage,
    HelloRequest,
    ObjectsMessage,
    StatusMessage,
    dump,
    parse,
    parse_request,
)
from legws_daemon.formats.operator_file import OperatorFile
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState, adapter_class
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.robot.visual import finger_half_gap, robot_visual
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.targets import Held
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from legws_daemon.telemetry.snapshot import TickSnapshot
from legws_daemon.transport.session import keys, open_session, payload_bytes

if TYPE_CHECKING:  # the recording's module imports rerun: only the CLI that records loads it
    from legws_daemon.telemetry.rerun_log import RerunLog

log = logging.getLogger("legws.daemon")
#: Rerun text-log level of each event kind (INFO when not listed).
_SEVERITY = {"fault": "ERROR", "warning": "WARN", "fallback": "WARN", "stall": "WARN"}

#: A command not taken up by the loop within this long is answered ``busy`` (nothing was
#: done), seconds.
COMMAND_TIMEOUT = 5.0
#: Commands waiting for the loop at most; more are answered ``busy`` at once.
COMMAND_QUEUE = 8
#: Commands the loop takes up per tick at most (the others wait for the next tick).
COMMANDS_PER_TICK = 2
#: An overrun warning event at most this often, seconds.
OVERRUN_WARNING_INTERVAL = 5.0
#: A telemetry warning event at most this often while problems continue, seconds.
TELEMETRY_WARNING_INTERVAL = 10.0
#: Seconds between health checks of the recording (on the telemetry worker's thread).
TELEMETRY_CHECK_INTERVAL = 2.0
#: An ``input_rejected`` event per reason at most this often, seconds.
REJECTION_EVENT_INTERVAL = 2.0
#: A ``deadman`` event at most this often (a flickering input is reported as its latest
#: state once the interval has passed), seconds.
DEADMAN_EVENT_INTERVAL = 1.0
#: A role's stop events come at most this often, s (each stop acts at once all the same).
STOP_EVENT_INTERVAL = 1.0
#: Recent events kept in memory (for a look in a debugger; the record is the event stream).
RECENT_EVENTS = 256


#: What a reset's way home waits for, by why no input reaches the loop (``None``: nothing).
WAITING: dict[str, str] = {
    "no_operator": "the operator: nobody holds the lease; the arm moves home only while "
    "the operator's input arrives with enable held",
    "no_input": "the operator's input: none arrived within the deadman timeout; the arm "
    "moves home only while it arrives with enable held",
    "enable_released": "the enable button: the arm moves home only while it is held",
}


def answer_hello(
    inbox: JoystickInbox, request: HelloRequest, started: float | None
) -> tuple[bool, bytes]:
    """The reply to ``hello`` (docs/messages.md): whether it is a key, and the body —
    ``{"ok": true, "command": "hello", "session": <public id>, "key": <64 hex digits>,
    "started": <the daemon's start>}``, or ``{"ok": false, ...}`` with the reason."""
    try:
        key, public = inbox.hello(request.argument)
    except InputError as err:
        return False, json.dumps({"ok": False, "command": "hello", "error": str(err)}).encode()
    reply = {"ok": True, "command": "hello", "session": public, "key": key.hex(),
             "started": started}  # fmt: skip
    return True, json.dumps(reply).encode()


def _waiting(why: str | None) -> str | None:
    """The ``waiting`` of a ``reset``'s reply: what the arm waits for before it moves."""
    return WAITING[why] if why is not None else None


def _operator_text(operator: Mapping[str, str | None] | None) -> str | None:
    """Who holds the joystick lease, in a few words (``None``: nobody)."""
    if not operator:
        return None
    source, session = operator.get("source"), operator.get("session")
    return f"{source} (session {session[:8]})" if session else str(source)


def _held_width(held: Held | None) -> float | None:
    """The held object's extent along the closing axis (the EE's x), m."""
    if held is None:
        return None
    return float(np.abs(held.frame[0]) @ held.extents)


@dataclass(frozen=True, slots=True)
class CalibrationSpec:
    """A calibration to run (``legws operator calibrate``): ``targets`` reaches, seeded."""

    targets: int
    seed: int = 0


@dataclass
class DaemonConfig:
    """Everything ``legws daemon`` (or ``legws operator calibrate``) was asked to do."""

    profile: ProfileSpec
    scene: Scene
    layout: Layout
    params: Params
    zenoh_config: zenoh.Config
    telemetry: RerunLog | None = None
    duration: float | None = None
    trace: LineFile | None = None
    graph: TaskGraph | None = None
    plan: Plan | None = None
    scene_loader: Callable[[str], Scene] = field(default=lambda name: catalog_scene(name))
    graph_loader: Callable[[str], tuple[TaskGraph, Scene]] = field(
        default=lambda name: catalog_taskgraph(name)
    )
    #: ``load_taskgraph`` with ``plan: "auto"`` (the CLI gives the plan cache's)
    plan_loader: Callable[[TaskGraph, Scene], Plan] | None = None
    #: what the transport lacks to be authenticated (``None``: it is authenticated)
    transport_problem: str | None = None
    #: a real arm's daemon started on an unauthenticated transport (``--insecure-transport``)
    insecure_transport: bool = False
    #: the person every certificate is for (``--operator``); ``None``: section 2's user
    operator: OperatorFile | None = None
    #: run a calibration instead of the task (the loop ends after its last target)
    calibration: CalibrationSpec | None = None
    #: also called with every event (on the thread that emits it; must not block)
    on_event: Callable[[Event], None] | None = None


class DaemonService:
    """Runs the daemon until ``stop`` is set (or the configured duration passes)."""

    def __init__(self, config: DaemonConfig) -> None:
        self.config = config
        self.profile = config.profile
        self.keys = keys(self.profile.robot)
        control = self.profile.control
        self.inbox = JoystickInbox(
            self.keys["joystick"],
            control.deadman_timeout,
            control.lease_grace,
            stall_threshold(1.0 / control.rate_hz),
        )
        self._deadman: NoInput | None = "no_operator"  # as last reported (None: input flows)
        self.started_at: float | None = None  # the daemon's wall clock at its start, s
        #: a stop event per role (each stop acts at once; those not announced are counted)
        self._stop_events: Throttle[str] = Throttle(STOP_EVENT_INTERVAL)
        self._deadman_events: Throttle[None] = Throttle(DEADMAN_EVENT_INTERVAL)
        self._rejection_events: Throttle[str] = Throttle(REJECTION_EVENT_INTERVAL)
        self._rejections_unreported: dict[str, InputRejected] = {}
        #: closed while a tick runs: the load preparer and command callbacks pause then
        self.gate = LoopGate()
        self.commands: queue.Queue[PendingCommand] = queue.Queue(maxsize=COMMAND_QUEUE)
        #: loads, prepared off the loop and installed by it
        self.loads = LoadPipeline(
            self._prepare, self._install, _dispose, initializer=self.gate.enter_thread
        )
        self._emit_lock = threading.Lock()
        self.fallback = False
        self.adapter_kind = self.profile.adapter
        self.ticker = Ticker(self.profile.control.rate_hz, paced=self._paced())
        self._event_seq = 0
        self._status_seq = 0
        self._status_lock = threading.Lock()
        self._status_bytes = b""
        self._events: deque[Event] = deque(maxlen=RECENT_EVENTS)
        self._session: zenoh.Session | None = None
        self._event_pub: Any = None
        self._t0 = time.monotonic()
        self._overrun_warnings: Throttle[None] = Throttle(OVERRUN_WARNING_INTERVAL)
        self.controller: Controller | None = None
        self.worker: TelemetryWorker | None = None
        if config.telemetry is not None:
            self.worker = TelemetryWorker(
                check=config.telemetry.check,
                check_every=TELEMETRY_CHECK_INTERVAL,
            )
        self._telemetry_warnings: Throttle[None] = Throttle(TELEMETRY_WARNING_INTERVAL)
        self._telemetry_unreported = 0
        self._telemetry_last: TelemetryReport | None = None
        self._logged_stage: object = None
        #: a tracker's reports for the loop, oldest first: (poses, unseen objects)
        self._objects: deque[tuple[dict[str, ObjectPose], tuple[str, ...]]] = deque(maxlen=8)
        self.objects_rejected = 0
        self.objects_error: str | None = None
        #: stops heard on ``legws/<robot>/stop/<role>``, for the loop: (role, message, error)
        self._stops: deque[tuple[str, StopMessage | None, str | None]] = deque(maxlen=64)
        self.stops_invalid = 0
        #: the loop thread's SCHED_FIFO priority (0: normal scheduling)
        self.realtime_priority = 0
        #: the live watch of the operator (``--operator``, not while calibrating)
        self.watch: OperatorWatch | None = None
        self._watch_pool: ThreadPoolExecutor | None = None
        if config.operator is not None and config.calibration is None:
            self._watch_pool = ThreadPoolExecutor(
                max_workers=1, thread_name_prefix="legws-watch", initializer=self.gate.enter_thread
            )
            self.watch = OperatorWatch(config.operator, config.params, executor=self._watch_pool)

    def _paced(self) -> bool:
        return self.profile.adapter != "sim" or self.profile.sim.realtime

    # --- adapters ---------------------------------------------------------------------
    def make_adapter(self, scene: Scene) -> Adapter:
        """Build and connect the profile's adapter (its calls guarded: see
        :class:`~legws_daemon.hardware.base.Adapter`); fall back to the stand-in if asked."""
        if self.fallback or self.adapter_kind == "sim":
            adapter: Adapter = SimAdapter(self.profile, scene, self._session)
            adapter.connect()
            return adapter
        adapter = adapter_class(self.adapter_kind)(self.profile, scene, self._session)
        try:
            adapter.connect()
        except BridgeTimeoutError as err:
            if not self.profile.link.fallback_to_sim:
                raise
            self.fallback = True
            self.ticker.paced = True
            self._emit(Fallback(str(err), "sim"))
            sim = SimAdapter(self.profile, scene, self._session)
            sim.connect()
            return sim
        return adapter

    # --- events and status ------------------------------------------------------------
    def _emit(self, event: Event) -> None:
        """Publish an event and log it (the loop's thread; the preparer's for a fallback)."""
        with self._emit_lock:
            self._emit_locked(event)

    def _emit_locked(self, event: Event) -> None:
        self._event_seq += 1
        msg = EventMessage.model_validate(
            {
                "schema": 1,
                "robot": self.profile.robot,
                "seq": self._event_seq,
                "stamp": time.time(),
                "kind": event.kind,
                "detail": event.detail(),
            }
        )
        self._events.append(event)
        text = event.text()
        severity = _SEVERITY.get(event.kind, "INFO")
        log.log(logging.getLevelName(severity.replace("WARN", "WARNING")), "%s", text)
        if self._event_pub is not None:
            self._event_pub.put(dump(msg))
        tel = self.config.telemetry
        if tel is not None and self.worker is not None:
            tick = self.controller.ticks if self.controller is not None else 0
            t = time.monotonic() - self._t0
            self.worker.submit(lambda: tel.log_text(tick, t, severity, text))
        hook = self.config.on_event
        if hook is not None:
            try:
                hook(event)
            except Exception:  # a listener's bug must not stop control
                log.exception("event listener failed on %s", event.kind)

    def _from_controller(self, event: Event) -> None:
        """An event of the controller: the live watch sees it first (a commit with its
        goal's position), then it is published."""
        watch, c = self.watch, self.controller
        if watch is not None:
            position = None
            if isinstance(event, Commit) and c is not None:
                with contextlib.suppress(KeyError):
                    position = c.stage.target(event.goal).position
            watch.event(event, position)
        self._log_stage_change()  # a stage begun in this tick is set up before its lines
        self._emit(event)

    def _forecast_confirms(self, c: Controller) -> None:
        """Warn for each decision whose goals are not all commit-certified in the layout it
        runs in: confirms will be needed (:mod:`~legws_daemon.autonomy.confirms`)."""
        cfg = self.config
        operator = cfg.operator.certify_with if cfg.operator is not None else None
        try:
            forecast = confirm_forecast(c.graph, c.scene, cfg.layout, cfg.plan, cfg.params,
                                        operator)  # fmt: skip
        except LegwsError as err:  # a layout the forecast cannot certify: said, not fatal
            log.warning("no forecast of the confirms: %s", err)
            return
        for d in forecast:
            if d.confirms:
                self._emit(ConfirmsNeeded(d.decision, d.layout, d.uncertified, len(d.goals),
                                          d.objective))  # fmt: skip

    def _log_stage_change(self) -> None:
        """Log the set-up of a stage begun since the last one (the loop's thread)."""
        c = self.controller
        if c is not None and c.stage is not self._logged_stage:
            self._logged_stage = c.stage
            self._log_setup()

    def _status(self, rec: TickRecord | None, slack: float | None) -> StatusMessage:
        c, cfg = self.controller, self.config
        assert c is not None
        state = rec.state if rec is not None else c.last_state
        self._status_seq += 1
        rejections = self.inbox.counts()
        calibrating = c.calibration is not None
        targets = {t.name: t.position.tolist() for t in c.stage.targets}
        calibration = None
        if c.calibration is not None:
            position = state.ee_position if state is not None else None
            calibration = c.calibration.status(position)
            targets = {CALIBRATION: calibration["target"]} if calibration is not None else {}
        data: dict[str, Any] = {
            "schema": 1,
            "robot": self.profile.robot,
            "seq": self._status_seq,
            "stamp": time.time(),
            "started": self.started_at,
            "mode": c.mode.value,
            "stage": CALIBRATION if calibrating else c.stage.name,
            "posterior": c.posterior(),
            "committed": c.committed,
            "certificate": None if calibrating else c.stage.current_certificate,
            "adapter": "sim" if self.fallback else self.adapter_kind,
            "fallback": self.fallback,
            "fault": c.fault,
            "phase": rec.phase if rec is not None else None,
            "deadman": rec is not None and rec.joystick is None,
            "tick": c.ticks,
            "overruns": self.ticker.overruns,
            "rejected": sum(rejections.values()),
            "rejections": rejections,
            "operator": self.inbox.operator(),
            "slack": slack,
            "decision": c.decisions,
            "targets": targets,
            "transport": "authenticated" if cfg.transport_problem is None else "unauthenticated",
            "insecure_transport": cfg.insecure_transport,
            "realtime_priority": self.realtime_priority,
            "placement": c.placement.status() if c.placement is not None else None,
            "layout": c.layout_status(),
            "calibration": calibration,
            "operator_model": self._operator_status(),
            "assist": c.policy,
        }
        if state is not None:
            data["ee"] = {
                "position": state.ee_position.tolist(),
                "quaternion": state.ee_quaternion.tolist(),
            }
            data["gripper_closed"] = state.gripper_closed
        return StatusMessage.model_validate(data)

    def _operator_status(self) -> dict[str, Any] | None:
        """Status ``operator_model``: whose certificates these are, and the live watch."""
        record = self.config.operator
        if record is None:
            return None
        watch = self.watch
        return {
            **record.status(),
            "file": record.source or None,
            "watch": watch.status() if watch is not None else None,
        }

    def _operator_lines(self) -> tuple[str, ...] | None:
        """The status panel's lines about the operator model (Rerun)."""
        record = self.config.operator
        if record is None:
            return None
        head = f"operator model {record.name}: {record.certify_with.describe()}"
        return (head, *(self.watch.lines() if self.watch is not None else ()))

    # --- commands ---------------------------------------------------------------------
    def _on_query(self, query: zenoh.Query) -> None:
        """zenoh thread: validate and hand over to the loop; never waits for it (a zenoh
        thread that waits holds up the transport). The loop, or the load preparer, replies
        when the command is done; ``status`` and bad requests are answered here at once."""
        self.gate.wait()  # validated and answered between ticks: a burst shares no tick
        try:
            payload = payload_bytes(query.payload, self.keys["command"])
            request = parse_request(payload, self.keys["command"])
        except InputError as err:
            query.reply_err(json.dumps({"ok": False, "error": str(err)}).encode())
            return
        route = ROUTES[request.command]
        if route.answer is not None:
            route.answer(self, query, request)
            return
        assert isinstance(request, CommandRequest)
        key = self.keys["command"]

        def respond(reply: dict[str, Any]) -> None:
            body = json.dumps(jsonable(reply)).encode()
            try:
                if reply.get("ok"):
                    query.reply(key, body)
                else:
                    query.reply_err(body)
            except Exception as err:  # the asker gone: nothing to tell
                log.debug("reply to %s: %s", request.command, err)
            finally:
                query.drop()  # type: ignore[no-untyped-call]

        pending = PendingCommand(request, respond)
        try:
            self.commands.put_nowait(pending)
        except queue.Full:
            pending.fail(f"busy: {COMMAND_QUEUE} commands are waiting; nothing was done")

    def _answer_status(self, query: zenoh.Query, request: Request) -> None:
        """zenoh thread: ``status`` — the last status published, at once."""
        with self._status_lock:
            status = self._status_bytes
        query.reply(self.keys["command"], status)

    def _answer_hello(self, query: zenoh.Query, request: Request) -> None:
        """zenoh thread: ``hello`` — a key for the session named, in the reply to the asker
        alone (a query's reply never reaches other subscribers); status and events show the
        session's public id only."""
        assert isinstance(request, HelloRequest)
        ok, body = answer_hello(self.inbox, request, self.started_at)
        if ok:
            query.reply(self.keys["command"], body)
        else:
            query.reply_err(body)

    def _on_joystick(self, sample: zenoh.Sample) -> None:
        """zenoh thread: a joystick payload to the inbox (its size read before its bytes)."""
        now = time.monotonic()
        try:
            payload = payload_bytes(sample.payload, self.keys["joystick"])
        except InputError as err:
            self.inbox.refuse(err)
            return
        self.inbox.offer(payload, now)

    def _on_objects(self, sample: zenoh.Sample) -> None:
        """zenoh thread: validate a tracker's object poses; the loop applies them."""
        try:
            payload = payload_bytes(sample.payload, self.keys["objects"])
            msg = parse(ObjectsMessage, payload, self.keys["objects"])
        except InputError as err:
            self.objects_rejected += 1
            self.objects_error = str(err)
            return
        poses = {n: ObjectPose(p.x, p.y, p.yaw) for n, p in msg.objects.items()}
        self._objects.append((poses, tuple(msg.unseen)))

    def _on_stop(self, sample: zenoh.Sample) -> None:
        """zenoh thread: a stop on ``legws/<robot>/stop/<role>``; the loop carries it out
        first thing in its next tick. Any sample stops, even one that does not validate."""
        key = str(sample.key_expr)
        role = stop_role(key)
        if role == "daemon":
            return  # its own word to the bridge (bridge adapter), heard back
        try:
            message: StopMessage | None = parse_stop(payload_bytes(sample.payload, key), key)
            error = None
        except InputError as err:
            message, error = None, str(err)
            self.stops_invalid += 1
        self._stops.append((role, message, error))

    def _run_stops(self) -> bool:
        """Carry out the stops heard since the last tick (loads before them are cancelled)."""
        c = self.controller
        if not self._stops or c is None:
            return False
        now = time.monotonic()
        while self._stops:
            role, message, error = self._stops.popleft()
            self.loads.cancel(f"cancelled: a stop by {role} came after it")
            source = message.source if message is not None else None
            reason = message.reason if message is not None else f"invalid stop message: {error}"
            # every stop acts at once; a stop that stops the robot is always announced, a
            # role's further stops (and log lines) at most one a second, the next one counting
            # those not announced
            repeats = self._stop_events.attempt(role, now=now, force=c.mode != Mode.STOPPED)
            if repeats is not None:
                c.stop(role, source, reason, repeats=repeats)
            else:
                c.stop(role, source, reason, announce=False)
        return True

    def _apply_objects(self) -> None:
        """The tracker's reports that came since the last tick, in order, judged once."""
        reports = []
        while self._objects:
            reports.append(self._objects.popleft())
        if reports and self.controller is not None:
            self.controller.observe_all(reports)

    def _run_commands(self, now: float, install: bool = True) -> int:
        """Take up at most :data:`COMMANDS_PER_TICK` operator commands (a prepared load
        installed counts as one; only when ``install``); returns how many. Each goes its
        :data:`ROUTES` way: loads to the pipeline (prepared off the loop, one at a time, in
        order), the others carried out here; one that cancels loads (``stop``) answers the
        loads before it first (a load must not undo it)."""
        done = self.loads.install_finished() if install else 0
        while done < COMMANDS_PER_TICK:
            try:
                pending = self.commands.get_nowait()
            except queue.Empty:
                break
            done += 1
            request = pending.request
            if time.monotonic() - pending.arrived > COMMAND_TIMEOUT:  # the loop was stalled
                pending.fail(f"busy: not taken up within {COMMAND_TIMEOUT:g} s; nothing was done")
                continue
            route = ROUTES[request.command]
            if route.where == Where.LOAD:
                self.loads.offer(pending)
                continue
            if route.cancels_loads:
                self.loads.cancel(f"cancelled: a {request.command} came after it")
            assert route.run is not None
            try:
                reply = {"ok": True, "command": request.command, **route.run(self, request, now)}
            except LegwsError as err:
                reply = {"ok": False, "command": request.command, "error": str(err)}
            pending.finish(reply)
        return done

    def _prepare(self, request: CommandRequest) -> PreparedLoad:
        """The preparer's thread: a load built for the controller (files, world, plan)."""
        c, cfg = self.controller, self.config
        assert c is not None
        return c.prepare(request, cfg.scene_loader, cfg.graph_loader, cfg.plan_loader)

    def _install(self, prepared: PreparedLoad) -> tuple[dict[str, Any], Any]:
        """The loop: a prepared load swapped in (its reply's detail, the adapter replaced)."""
        assert self.controller is not None
        return self.controller.install(prepared)

    def _run_stop(self, request: CommandRequest, now: float) -> dict[str, Any]:
        """``stop``: zero velocity, the robot side told to hold it, until ``reset``."""
        c = self.controller
        assert c is not None
        c.stop("operator", "the command key")
        return {"mode": c.mode.value}

    def _run_reset(self, request: CommandRequest, now: float) -> dict[str, Any]:
        """``reset``: home and the task again; ``waiting`` says what the arm waits for."""
        assert self.controller is not None
        detail = self.controller.reset()
        detail["waiting"] = _waiting(self.inbox.poll(now, tick=False)[1])
        return detail

    def _run_lease(self, request: CommandRequest, now: float) -> dict[str, Any]:
        """``release`` / ``take_control``: the lease changes hands now (the events follow)."""
        now = time.monotonic()  # when it is carried out, not when the tick began
        if request.command == "release":
            self.inbox.release(now)
        else:
            assert request.argument is not None
            self.inbox.take_control(request.argument, now)
        return {"operator": self.inbox.operator()}

    # --- the operator's input ---------------------------------------------------------------
    def _report_input(self, now: float, why: NoInput | None) -> None:
        """Events for lease changes (each), the dead-man state (on a change, at most every
        :data:`DEADMAN_EVENT_INTERVAL`) and rejected input (per reason, at most every
        :data:`REJECTION_EVENT_INTERVAL`, with the count since the last one)."""
        report = self.inbox.take_report()
        for change in report.changes:
            self._emit(
                OperatorChanged(
                    change.operator.describe() if change.operator else None,
                    change.previous.describe() if change.previous else None,
                    change.reason,
                )
            )
        flipped = (why is None) != (self._deadman is None)
        if flipped and self._deadman_events.attempt(now=now) is not None:
            self._deadman = why
            self._emit(Deadman(why is not None, why))
        totals = self.inbox.counts() if report.rejections else {}
        for reason, tally in report.rejections.items():
            before = self._rejections_unreported.get(reason)
            count = tally.count + (before.count if before is not None else 0)
            self._rejections_unreported[reason] = InputRejected(
                reason, count, totals[reason], tally.source, tally.session, tally.error
            )
        for kind, event in list(self._rejections_unreported.items()):
            if self._rejection_events.attempt(kind, now=now) is not None:
                del self._rejections_unreported[kind]
                self._emit(event)

    # --- telemetry ----------------------------------------------------------------------
    def _log_robot(self) -> None:
        """The arm's meshes, once, before the first tick (taken on the worker's thread)."""
        tel, c, worker = self.config.telemetry, self.controller, self.worker
        if tel is None or c is None or worker is None:
            return
        world = c.adapter.kinematics
        worker.submit(lambda: tel.log_robot(robot_visual(world)))

    def _log_setup(self) -> None:
        tel, c = self.config.telemetry, self.controller
        if tel is None or c is None or self.worker is None or not c.stage.targets:
            return  # the task is done: no decision
        goals = c.stage.goals_home  # None: a single candidate, a stage without inference
        setup = functools.partial(
            tel.log_setup,
            scene=c.scene,
            goals=goals if goals is not None else c.stage.goal_names,
            goal_objects={g: g for g in c.stage.goal_names if g in c.scene.objects},
            planned=dict(c.layouts.planned),
            p_thresh=c.params.p_thresh,
            params_json=json.dumps(c.params.as_dict()),
            stage=c.stage.name,
        )
        self.worker.submit(setup)

    @staticmethod
    def _observed_objects(c: Controller) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Reported object poses as 3-D poses (objects rest on the table)."""
        out = {}
        for name, p in c.layouts.observed.items():
            position = np.array([p.x, p.y, c.scene.z_center(name)])
            out[name] = (position, yaw_quat(p.yaw))
        return out

    @staticmethod
    def _corrections(c: Controller) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Each misplaced object's move: from where it stands to where it should (3-D)."""
        if c.placement is None:
            return {}
        out = {}
        for o in c.placement.misplaced:
            seen = c.layouts.seen.get(o.name)
            if seen is None or o.move is None:
                continue
            p, z = seen[0], c.scene.z_center(o.name)
            start = np.array([p.x, p.y, z])
            out[o.name] = (start, start + np.array([o.move["x"], o.move["y"], 0.0]))
        return out

    def _log_tick(self, rec: TickRecord, slack: float | None) -> None:
        tel, c, worker = self.config.telemetry, self.controller, self.worker
        if tel is None or c is None or rec.state is None or worker is None:
            return
        try:
            objects = c.adapter.object_poses() or self._observed_objects(c)
            snapshot = self._snapshot(c, rec, rec.state, slack, objects)
        except Exception as err:  # drawing must not stop control: reported as telemetry
            worker.record_error(f"tick snapshot: {type(err).__name__}: {err}")
            return
        worker.submit(lambda: tel.log_tick(snapshot), droppable=True)

    def _snapshot(
        self,
        c: Controller,
        rec: TickRecord,
        state: RobotState,
        slack: float | None,
        objects: Mapping[str, tuple[FloatArray, FloatArray]],
    ) -> TickSnapshot:
        """What the recording shows of this tick (built once, on the loop's thread)."""
        return TickSnapshot(
            tick=rec.tick,
            t=time.monotonic() - self._t0,
            link_positions=state.links.positions,
            link_rotations=state.links.rotations,
            ee_position=state.ee_position,
            ee_quaternion=state.ee_quaternion,
            objects=objects,
            posterior=rec.posterior if rec.mode == Mode.TELEOP or rec.committed else None,
            joystick=rec.joystick,
            command=rec.command,
            mode=rec.mode.value,
            slack=slack,
            committed=rec.committed,
            tick_seconds=self.ticker.last_duration,
            gripper_half_gap=finger_half_gap(state.gripper_closed, _held_width(c.held)),
            phase=rec.phase,
            operator=_operator_text(self.inbox.operator()),
            fault=c.fault,
            stage=CALIBRATION if c.calibration is not None else c.stage.name,
            placement=tuple(c.placement.lines()) if c.placement is not None else None,
            corrections=self._corrections(c),
            calibration=self._calibration_marker(c),
            operator_model=self._operator_lines(),
        )

    @staticmethod
    def _calibration_marker(c: Controller) -> tuple[tuple[float, float, float], str] | None:
        """The calibration target shown, and its label (``target 3 of 20``)."""
        run = c.calibration
        target = run.target if run is not None else None
        if run is None or target is None:
            return None
        xyz = (float(target[0]), float(target[1]), float(target[2]))
        return xyz, f"target {run.index + 1} of {run.count}"

    def _report_telemetry(self) -> None:
        """Turn telemetry problems the worker counted into a ``warning`` event (loop thread):
        the first at once, then at most every :data:`TELEMETRY_WARNING_INTERVAL` seconds."""
        worker = self.worker
        if worker is None:
            return
        report = worker.take_report()
        if report is not None:
            self._telemetry_unreported += report.new
            self._telemetry_last = report
        if not self._telemetry_unreported:
            return
        if self._telemetry_warnings.attempt() is None:
            return
        last = self._telemetry_last
        assert last is not None
        self._emit(
            TelemetryProblem(last.last_error, self._telemetry_unreported, last.errors, last.dropped)
        )
        self._telemetry_unreported = 0

    # --- the loop -------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> int:
        """Open the session, run the loop until ``stop``, shut down cleanly; returns 0.

        Whatever ends the run — ``stop``, the duration, an exception (re-raised after a
        ``fault`` event) — the robot gets zero velocity, the recording is closed and the
        session too.
        """
        tune_allocator()
        try:
            return self._run(stop)
        finally:
            self._close_telemetry()

    def _run(self, stop: threading.Event) -> int:
        cfg = self.config
        with open_session(cfg.zenoh_config) as session:
            self._session = session
            status_pub = session.declare_publisher(self.keys["status"])
            self._event_pub = session.declare_publisher(self.keys["events"])
            controller = Controller(
                self.profile,
                cfg.scene,
                cfg.layout,
                self.make_adapter,
                cfg.params,
                self._from_controller,
                graph=cfg.graph,
                plan=cfg.plan,
                operator=cfg.operator.certify_with if cfg.operator is not None else None,
            )
            self.controller = controller
            if cfg.calibration is not None:
                try:
                    controller.start_calibration(cfg.calibration.targets, cfg.calibration.seed)
                except BaseException:
                    _quietly("robot shutdown", controller.shutdown)
                    raise
            self._logged_stage = controller.stage
            self._log_robot()
            self._log_setup()
            calibrating = controller.calibration is not None
            self.started_at = time.time()
            self._emit(
                Started(
                    "sim" if self.fallback else self.adapter_kind, cfg.scene.name,
                    controller.graph.name, CALIBRATION if calibrating else controller.stage.name,
                    None if calibrating else controller.stage.certificate,
                    None if cfg.operator is None else {
                        "name": cfg.operator.name, "model": cfg.operator.certify_with.as_dict(),
                    },
                )
            )  # fmt: skip
            if not calibrating:
                self._forecast_confirms(controller)
            subscriber = session.declare_subscriber(
                self.keys["joystick"],
                self._on_joystick,
            )
            queryable = session.declare_queryable(self.keys["command"], self._on_query)
            objects = session.declare_subscriber(self.keys["objects"], self._on_objects)
            stops = session.declare_subscriber(
                bridge_keys(self.profile.robot)["stop"], self._on_stop
            )
            if cfg.insecure_transport:
                self._emit(InsecureTransport(cfg.transport_problem or "unauthenticated"))
            log.info(
                "robot %s on %s at %g Hz (deadman %g s); keys legws/%s/{joystick,status,events,"
                "command}",
                self.profile.robot,
                "sim (fallback)" if self.fallback else _adapter_name(controller.adapter),
                self.profile.control.rate_hz,
                self.profile.control.deadman_timeout,
                self.profile.robot,
            )
            try:
                self._loop(stop, status_pub)
            except Exception as err:  # recorded, then the shutdown below, then re-raised
                error = f"daemon loop: {type(err).__name__}: {err}"
                _quietly("fault event", self._emit, Fault(error))
                raise
            finally:
                # each step on its own: one failing must not skip the others
                _quietly("robot shutdown", controller.shutdown)
                _quietly("shutdown event", self._emit,
                         Shutdown(controller.ticks, self.ticker.overruns))  # fmt: skip
                _quietly("last status", self._publish_status, status_pub, None, None)
                for entity in (subscriber, queryable, objects, stops):
                    _quietly("undeclare", entity.undeclare)
                self._fail_pending()
                if self._watch_pool is not None:  # a fit under way is not waited for
                    self._watch_pool.shutdown(wait=False, cancel_futures=True)
                self._close_telemetry()
        return 0

    def _close_telemetry(self) -> None:
        """Log what is queued and close the recording (idempotent; every exit path)."""
        worker, tel = self.worker, self.config.telemetry
        if worker is not None and worker.alive:
            if not worker.close():
                log.warning("telemetry: the worker did not finish within its timeout")
            if worker.dropped or worker.errors:
                log.warning(
                    "telemetry: %d tick snapshots dropped, %d errors (last: %s)",
                    worker.dropped,
                    worker.errors,
                    worker.last_error,
                )
        if tel is not None:
            _quietly("closing the recording", tel.close)

    def _loop(self, stop: threading.Event, status_pub: Any) -> None:
        c = self.controller
        assert c is not None
        control = self.profile.control
        status_every = max(1, round(control.rate_hz / control.status_rate_hz))
        end = None if self.config.duration is None else time.monotonic() + self.config.duration
        self._enter_realtime()
        ticker = self.ticker
        ticker.restart()
        try:
            self._ticks(stop, status_pub, end, status_every)
        finally:
            self.gate.open()  # nothing waits for a loop that has ended

    def _enter_realtime(self) -> None:
        """The loop's thread on SCHED_FIFO if the profile asks (a ``warning`` when refused)."""
        wanted = self.profile.control.realtime_priority
        if wanted:
            problem = enter_realtime(wanted)
            if problem is not None:
                self._emit(RealtimeRefused(problem))
        self.realtime_priority = current_priority()

    def _ticks(
        self, stop: threading.Event, status_pub: Any, end: float | None, status_every: int
    ) -> None:
        c, ticker = self.controller, self.ticker
        assert c is not None
        while not stop.is_set() and (end is None or time.monotonic() < end):
            now = ticker.begin()
            self.gate.close()
            self._run_stops()
            # a prepared load is swapped in on a tick that publishes no status (each costs
            # ~1-2 ms; together they would make the longest ticks)
            commands = self._run_commands(now, install=(c.ticks + 1) % status_every != 0)
            self._apply_objects()
            gap = ticker.standstill()  # right before the robot is read
            if gap is not None:
                now = self._stalled(gap)
            sample, why = self.inbox.poll(now)
            rec = c.tick(sample.operator if sample is not None else None)
            self._report_input(now, why)
            if self.watch is not None:
                self.watch.tick(rec)
                for event in self.watch.poll():  # a finished fit, never waited for
                    self._emit(event)
            self._log_stage_change()
            slack = None
            if rec.tick % status_every == 0:
                slack = c.live_slack()
                c.check_placement()  # objects a tracker stopped reporting turn unseen
                self._publish_status(status_pub, rec, slack)
            self._log_tick(rec, slack)
            self._report_telemetry()
            self._trace(rec, now, commands)
            self.gate.open()
            self.loads.hand_over()
            if ticker.end():
                self._overrun_warning()
            if c.calibration is not None and c.calibration.finished:
                log.info("calibration: all %d targets reached", c.calibration.count)
                break  # the shutdown's last status says idle: the publishers see the end

    def _stalled(self, gap: float) -> float:
        """The loop stood still for ``gap`` s (the process was paused): stop, drop the stale
        input (the holder keeps the lease), judge the bridge's heartbeat from now, say so.
        Returns the time of the resume (the tick's time from here on)."""
        c = self.controller
        assert c is not None
        now = time.monotonic()
        self.inbox.stalled(now)  # no input this tick: the controller commands zero
        with contextlib.suppress(LegwsError):  # (only an adapter's bug, guarded, raises here)
            c.adapter.paused(now)
        self._emit(Stall(round(gap, 3), self.ticker.stall_after, self.ticker.stalls))
        return now

    def _publish_status(self, pub: Any, rec: TickRecord | None, slack: float | None) -> None:
        data = dump(self._status(rec, slack))
        with self._status_lock:
            self._status_bytes = data
        pub.put(data)

    def _overrun_warning(self) -> None:
        if self._overrun_warnings.attempt() is not None:
            last = self.ticker.last_duration or 0.0
            self._emit(
                Overrun(round(1000 * last, 2), 1000 * self.ticker.period, self.ticker.overruns)
            )

    def _trace(self, rec: TickRecord, started: float, commands: int) -> None:
        """One JSON line: this tick's work so far (s), when it began, the sample used, the
        command sent (m/s) and when, and how many operator commands the tick carried out."""
        out = self.config.trace
        if out is None or out.closed:  # closed: a write failed (the disk is full)
            return
        row: dict[str, Any] = {
            "tick": rec.tick,
            "work": time.monotonic() - started,
            "begin": started,
            "mode": rec.mode.value,
            "seq": rec.sample_seq,
            "stamp": rec.sample_stamp,
            "received": rec.sample_received,
            "sent": rec.command_sent,
            "command": [round(float(v), 6) for v in rec.command],
            "commands": commands,
        }
        wall_minus_mono = time.time() - time.monotonic()
        row["wall_sent"] = rec.command_sent + wall_minus_mono
        if rec.sample_received is not None:
            row["wall_received"] = rec.sample_received + wall_minus_mono
        try:
            out.write(json.dumps(row) + "\n")
        except InputError as err:  # a full disk ends the trace, not the control
            self._emit(TraceFailed(str(err)))  # cut back to its last whole line, closed

    def _fail_pending(self) -> None:
        """At shutdown: answer every command not carried out; discard a prepared load."""
        self.loads.shutdown()
        while True:
            try:
                pending = self.commands.get_nowait()
            except queue.Empty:
                return
            pending.finish({"ok": False, "error": "the daemon is shutting down"})


#: glibc's ``mallopt`` parameter number of ``M_MMAP_THRESHOLD``.
_M_MMAP_THRESHOLD = -3
#: Allocations from this size on are mapped (and unmapped when freed), bytes.
MMAP_THRESHOLD = 1 << 20


@functools.cache
def _libc() -> ctypes.CDLL | None:
    """The C library if it is glibc (it has ``malloc_trim``), else ``None``."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    if libc is None or not hasattr(libc, "malloc_trim") or not hasattr(libc, "mallopt"):
        return None
    libc.malloc_trim.argtypes, libc.malloc_trim.restype = [ctypes.c_size_t], ctypes.c_int
    libc.mallopt.argtypes, libc.mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return libc


def tune_allocator() -> None:
    """Map large allocations and give them back when freed (glibc; a no-op elsewhere).

    Loading a scene builds a new MuJoCo world (~90 MB of buffers) and frees the old one.
    glibc raises its mmap threshold after such frees (up to 32 MB), so the next world's
    buffers come from a thread's heap arena, whose freed memory is kept: the resident set
    grew by ~90 MB with every load (12 loads: 450 MB -> 1.5 GB). A fixed threshold of
    :data:`MMAP_THRESHOLD` stops that (12 loads: +10 MB); :func:`release_memory` after a
    load returns the rest.
    """
    libc = _libc()
    if libc is not None:
        libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)


def release_memory() -> None:
    """Return freed heap memory to the operating system (glibc ``malloc_trim``; ~7 ms, on a
    tick that stopped the robot for a load anyway)."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)


def _dispose(adapter: Adapter) -> None:
    """Disconnect a replaced adapter and give its memory back (off the control loop)."""
    try:
        adapter.disconnect()
    except Exception:
        log.exception("disconnecting the replaced adapter failed")
    del adapter
    release_memory()  # the old scene's world is freed: give the memory back


def _quietly(what: str, fn: Callable[..., Any], *args: Any) -> None:
    """Run one shutdown step; an exception is logged, not raised (the next steps run)."""
    try:
        fn(*args)
    except Exception:
        log.exception("shutdown: %s failed", what)


def _adapter_name(adapter: Adapter) -> str:
    return type(adapter).__name__


def catalog_scene(name: str) -> Scene:
    """A scene by catalog name only: a remote command never names a file path."""
    if "/" in name or "\\" in name or name.endswith(".toml") or name.startswith("."):
        raise InputError(f"expected a scene name from the catalog, got {name!r}", field="argument")
    return load_scene(name)


def catalog_taskgraph(name: str) -> tuple[TaskGraph, Scene]:
    """A task graph by name from ``taskgraphs/`` only (a remote command names no path)."""
    if not re.fullmatch(r"[a-z][a-z0-9_]*", name):
        raise InputError(f"expected a task graph name, got {name!r}", field="argument")
    return load_taskgraph(resolve_taskgraph(name))


#: The command router: every command on the command key, where it is carried out and by
#: which handler (:mod:`.commands`; checked against the messages' commands at import).
ROUTES: dict[str, Route[DaemonService]] = {
    "hello": Route(Where.AT_ONCE, answer=DaemonService._answer_hello),
    "status": Route(Where.AT_ONCE, answer=DaemonService._answer_status),
    "stop": Route(Where.LOOP, run=DaemonService._run_stop, cancels_loads=True),
    "reset": Route(Where.LOOP, run=DaemonService._run_reset),
    "release": Route(Where.LOOP, run=DaemonService._run_lease),
    "take_control": Route(Where.LOOP, run=DaemonService._run_lease),
    "load_scene": Route(Where.LOAD),
    "load_taskgraph": Route(Where.LOAD),
}
check_routes(ROUTES)
