"""The daemon as a service: zenoh I/O, the fixed-rate loop, telemetry, signals.

Threads: zenoh's callback threads only validate and hand over (the joystick inbox, the
command queue); the loop thread — the only one touching the robot — runs the
controller once per period, publishes status at the profile's status rate and events
as they happen, and logs to Rerun. I/O never blocks the loop: publishing and logging are
asynchronous, and a command that takes long (loading a scene) stops the robot first.

On SIGINT/SIGTERM (or ``--duration``) the loop stops within one period; the robot is
sent zero velocity and disconnected, the recording is flushed and closed, the zenoh
session closed.
"""

from __future__ import annotations

import json
import logging
import queue
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO, Any, Protocol

import numpy as np
import zenoh

import legws_daemon.hardware.sawyer  # noqa: F401  (registers "sawyer")
from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.params import Params
from legws_daemon.daemon.controller import Controller, TickRecord
from legws_daemon.daemon.inbox import JoystickInbox
from legws_daemon.daemon.telemetry_worker import TelemetryWorker
from legws_daemon.daemon.ticker import Ticker
from legws_daemon.design.plan import Plan
from legws_daemon.errors import BridgeTimeoutError, InputError, LegwsError
from legws_daemon.formats.messages import (
    CommandRequest,
    EventMessage,
    ObjectsMessage,
    StatusMessage,
    dump,
    parse,
)
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.formats.taskgraph_file import load_taskgraph, resolve_taskgraph
from legws_daemon.hardware.base import Adapter, adapter_class
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.transport.session import keys, open_session

log = logging.getLogger("legws.daemon")
#: Rerun text-log level of each event kind (INFO when not listed).
_SEVERITY = {"fault": "ERROR", "warning": "WARN", "fallback": "WARN"}

#: A command waits at most this long for the loop to carry it out, seconds.
COMMAND_TIMEOUT = 5.0
#: An overrun warning event at most this often, seconds.
OVERRUN_WARNING_INTERVAL = 5.0


class Telemetry(Protocol):
    """What the loop logs to (the Rerun recording)."""

    def log_setup(
        self,
        *,
        scene: Scene,
        goals: Any,
        goal_objects: dict[str, str],
        planned: Layout,
        p_thresh: float,
        params_json: str,
        stage: str | None = None,
    ) -> None: ...

    def log_tick(
        self,
        tick: int,
        t: float,
        *,
        link_positions: FloatArray,
        link_rotations: FloatArray,
        ee_position: FloatArray,
        ee_quaternion: FloatArray,
        objects: dict[str, tuple[FloatArray, FloatArray]],
        posterior: dict[str, float] | None,
        joystick: FloatArray | None,
        command: FloatArray,
        mode: str,
        slack: float | None,
        committed: str | None,
        tick_seconds: float | None = None,
    ) -> None: ...

    def log_text(self, tick: int, t: float, level: str, text: str) -> None: ...

    def close(self) -> None: ...


@dataclass
class DaemonConfig:
    """Everything ``legws daemon`` was asked to do."""

    profile: ProfileSpec
    scene: Scene
    layout: Layout
    params: Params
    zenoh_config: zenoh.Config
    telemetry: Telemetry | None = None
    duration: float | None = None
    trace: IO[str] | None = None
    graph: TaskGraph | None = None
    plan: Plan | None = None
    scene_loader: Callable[[str], Scene] = field(default=lambda name: catalog_scene(name))
    graph_loader: Callable[[str], tuple[TaskGraph, Scene]] = field(
        default=lambda name: catalog_taskgraph(name)
    )


@dataclass
class _PendingCommand:
    request: CommandRequest
    done: threading.Event = field(default_factory=threading.Event)
    reply: dict[str, Any] = field(default_factory=dict)


class DaemonService:
    """Runs the daemon until ``stop`` is set (or the configured duration passes)."""

    def __init__(self, config: DaemonConfig) -> None:
        self.config = config
        self.profile = config.profile
        self.keys = keys(self.profile.robot)
        self.inbox = JoystickInbox(self.keys["joystick"])
        self.commands: queue.Queue[_PendingCommand] = queue.Queue()
        self.fallback = False
        self.adapter_kind = self.profile.adapter
        self.ticker = Ticker(self.profile.control.rate_hz, paced=self._paced())
        self._event_seq = 0
        self._status_seq = 0
        self._status_lock = threading.Lock()
        self._status_bytes = b""
        self._events: list[tuple[str, dict[str, Any]]] = []
        self._session: zenoh.Session | None = None
        self._event_pub: Any = None
        self._t0 = time.monotonic()
        self._last_overrun_warning = -np.inf
        self.controller: Controller | None = None
        self.worker = TelemetryWorker() if config.telemetry is not None else None
        self._logged_stage: object = None
        self._objects_lock = threading.Lock()
        self._objects: dict[str, ObjectPose] = {}
        self.objects_rejected = 0
        self.objects_error: str | None = None

    def _paced(self) -> bool:
        return self.profile.adapter != "sim" or self.profile.sim.realtime

    # --- adapters ---------------------------------------------------------------------
    def make_adapter(self, scene: Scene) -> Adapter:
        """Build and connect the profile's adapter; fall back to the stand-in if asked."""
        if self.fallback or self.adapter_kind == "sim":
            adapter: Adapter = SimAdapter(self.profile, scene, self._session)
            adapter.connect()
            return adapter
        adapter = adapter_class(self.adapter_kind)(self.profile, scene, self._session)
        try:
            adapter.connect()
        except BridgeTimeoutError as err:
            if not self.profile.sawyer.fallback_to_sim:
                raise
            self.fallback = True
            self.ticker.paced = True
            self._emit("fallback", {"reason": str(err), "adapter": "sim", "note": "falling back"})
            sim = SimAdapter(self.profile, scene, self._session)
            sim.connect()
            return sim
        return adapter

    # --- events and status ------------------------------------------------------------
    def _emit(self, kind: str, detail: dict[str, Any]) -> None:
        """Publish an event and log it (called on the loop thread)."""
        self._event_seq += 1
        msg = EventMessage.model_validate(
            {
                "schema": 1,
                "robot": self.profile.robot,
                "seq": self._event_seq,
                "stamp": time.time(),
                "kind": kind,
                "detail": _jsonable(detail),
            }
        )
        self._events.append((kind, detail))
        text = _event_text(kind, detail)
        severity = _SEVERITY.get(kind, "INFO")
        log.log(logging.getLevelName(severity.replace("WARN", "WARNING")), "%s", text)
        if self._event_pub is not None:
            self._event_pub.put(dump(msg))
        tel = self.config.telemetry
        if tel is not None and self.worker is not None:
            tick = self.controller.ticks if self.controller is not None else 0
            self.worker.submit(tel.log_text, tick, time.monotonic() - self._t0, severity, text)

    def _status(self, rec: TickRecord | None, slack: float | None) -> StatusMessage:
        c = self.controller
        assert c is not None
        state = rec.state if rec is not None else c.last_state
        self._status_seq += 1
        data: dict[str, Any] = {
            "schema": 1,
            "robot": self.profile.robot,
            "seq": self._status_seq,
            "stamp": time.time(),
            "mode": c.mode,
            "stage": c.stage.name,
            "posterior": c.posterior(),
            "committed": c.committed,
            "certificate": c.stage.extras.get("observed_certificate", c.stage.certificate),
            "adapter": "sim" if self.fallback else self.adapter_kind,
            "fallback": self.fallback,
            "fault": c.fault,
            "phase": rec.phase if rec is not None else None,
            "deadman": rec is not None and rec.joystick is None,
            "tick": c.ticks,
            "overruns": self.ticker.overruns,
            "rejected": self.inbox.rejected,
            "slack": slack,
            "decision": c.decisions,
            "targets": {t.name: t.position.tolist() for t in c.stage.targets},
        }
        if state is not None:
            data["ee"] = {
                "position": state.ee_position.tolist(),
                "quaternion": state.ee_quaternion.tolist(),
            }
            data["gripper_closed"] = state.gripper_closed
        return StatusMessage.model_validate(data)

    # --- commands ---------------------------------------------------------------------
    def _on_query(self, query: zenoh.Query) -> None:
        """zenoh thread: validate, hand over to the loop, reply when it is done."""
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            request = parse(CommandRequest, payload, self.keys["command"])
        except InputError as err:
            query.reply_err(json.dumps({"ok": False, "error": str(err)}).encode())
            return
        if request.command == "status":
            with self._status_lock:
                status = self._status_bytes
            query.reply(self.keys["command"], status)
            return
        pending = _PendingCommand(request)
        self.commands.put(pending)
        if not pending.done.wait(COMMAND_TIMEOUT):
            query.reply_err(json.dumps({"ok": False, "error": "timed out"}).encode())
            return
        body = json.dumps(_jsonable(pending.reply)).encode()
        if pending.reply.get("ok"):
            query.reply(self.keys["command"], body)
        else:
            query.reply_err(body)

    def _on_objects(self, sample: zenoh.Sample) -> None:
        """zenoh thread: validate a tracker's object poses; the loop applies them."""
        try:
            msg = parse(ObjectsMessage, sample.payload.to_bytes(), self.keys["objects"])
        except InputError as err:
            self.objects_rejected += 1
            self.objects_error = str(err)
            return
        poses = {n: ObjectPose(p.x, p.y, p.yaw) for n, p in msg.objects.items()}
        with self._objects_lock:
            self._objects.update(poses)

    def _apply_objects(self) -> None:
        with self._objects_lock:
            poses, self._objects = self._objects, {}
        if poses and self.controller is not None:
            self.controller.observe(poses)

    def _run_commands(self) -> None:
        c = self.controller
        assert c is not None
        while True:
            try:
                pending = self.commands.get_nowait()
            except queue.Empty:
                return
            try:
                detail = c.command(
                    pending.request, self.config.scene_loader, self.config.graph_loader
                )
                pending.reply = {"ok": True, "command": pending.request.command, **detail}
            except LegwsError as err:
                pending.reply = {"ok": False, "command": pending.request.command, "error": str(err)}
            pending.done.set()

    # --- telemetry ----------------------------------------------------------------------
    def _log_setup(self) -> None:
        tel, c = self.config.telemetry, self.controller
        if tel is None or c is None or self.worker is None or c.stage.goals_home is None:
            return  # nothing to infer in this stage (a single candidate, or the task is done)
        self.worker.submit(
            tel.log_setup,
            scene=c.scene,
            goals=c.stage.goals_home,
            goal_objects={g: g for g in c.stage.goal_names if g in c.scene.objects},
            planned=dict(c.planned),
            p_thresh=c.params.p_thresh,
            params_json=json.dumps(c.params.as_dict()),
            stage=c.stage.name,
        )

    @staticmethod
    def _observed_objects(c: Controller) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Reported object poses as 3-D poses (objects rest on the table)."""
        out = {}
        for name, p in c.observed.items():
            position = np.array([p.x, p.y, c.scene.z_center(name)])
            out[name] = (position, np.array([np.cos(p.yaw / 2), 0.0, 0.0, np.sin(p.yaw / 2)]))
        return out

    def _log_tick(self, rec: TickRecord, slack: float | None) -> None:
        tel, c = self.config.telemetry, self.controller
        if tel is None or c is None or rec.state is None or self.worker is None:
            return
        links_p, links_R = c.adapter.link_poses(rec.state.q)
        self.worker.submit(
            tel.log_tick,
            rec.tick,
            time.monotonic() - self._t0,
            link_positions=links_p,
            link_rotations=links_R,
            ee_position=rec.state.ee_position,
            ee_quaternion=rec.state.ee_quaternion,
            objects=c.adapter.object_poses() or self._observed_objects(c),
            posterior=rec.posterior if rec.mode == "teleop" or rec.committed else None,
            joystick=rec.joystick,
            command=rec.command,
            mode=rec.mode,
            slack=slack,
            committed=rec.committed,
            tick_seconds=self.ticker.last_duration,
            droppable=True,
        )

    # --- the loop -------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> int:
        """Open the session, run the loop until ``stop``, shut down cleanly; returns 0."""
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
                self._emit,
                graph=cfg.graph,
                plan=cfg.plan,
            )
            self.controller = controller
            self._logged_stage = controller.stage
            self._log_setup()
            self._emit(
                "started",
                {"adapter": "sim" if self.fallback else self.adapter_kind,
                 "scene": cfg.scene.name, "task": controller.graph.name,
                 "stage": controller.stage.name, "certificate": controller.stage.certificate},
            )  # fmt: skip
            subscriber = session.declare_subscriber(
                self.keys["joystick"],
                lambda s: self.inbox.offer(s.payload.to_bytes(), time.monotonic()),
            )
            queryable = session.declare_queryable(self.keys["command"], self._on_query)
            objects = session.declare_subscriber(self.keys["objects"], self._on_objects)
            log.info(
                "robot %s on %s at %g Hz (deadman %g s); keys legws/%s/{joystick,status,events,"
                "command}",
                self.profile.robot,
                "sim (fallback)" if self.fallback else controller.adapter.__class__.__name__,
                self.profile.control.rate_hz,
                self.profile.control.deadman_timeout,
                self.profile.robot,
            )
            try:
                self._loop(stop, status_pub)
            finally:
                controller.shutdown()
                self._emit("shutdown", {"ticks": controller.ticks})
                self._publish_status(status_pub, None, None)
                subscriber.undeclare()  # type: ignore[no-untyped-call]
                queryable.undeclare()  # type: ignore[no-untyped-call]
                objects.undeclare()  # type: ignore[no-untyped-call]
                self._fail_pending()
                if self.worker is not None:
                    self.worker.close()
                    if self.worker.dropped or self.worker.errors:
                        log.warning(
                            "telemetry: %d tick snapshots dropped, %d errors (last: %s)",
                            self.worker.dropped,
                            self.worker.errors,
                            self.worker.last_error,
                        )
                if cfg.telemetry is not None:
                    cfg.telemetry.close()
        return 0

    def _loop(self, stop: threading.Event, status_pub: Any) -> None:
        c = self.controller
        assert c is not None
        control = self.profile.control
        status_every = max(1, round(control.rate_hz / control.status_rate_hz))
        end = None if self.config.duration is None else time.monotonic() + self.config.duration
        ticker = self.ticker
        ticker.restart()
        while not stop.is_set() and (end is None or time.monotonic() < end):
            now = ticker.begin()
            self._run_commands()
            self._apply_objects()
            sample = self.inbox.latest(now, control.deadman_timeout)
            rec = c.tick(sample)
            if c.stage is not self._logged_stage:
                self._logged_stage = c.stage
                self._log_setup()
            slack = None
            if rec.tick % status_every == 0:
                slack = c.live_slack()
                self._publish_status(status_pub, rec, slack)
            self._log_tick(rec, slack)
            self._trace(rec, now)
            if ticker.end():
                self._overrun_warning()

    def _publish_status(self, pub: Any, rec: TickRecord | None, slack: float | None) -> None:
        data = dump(self._status(rec, slack))
        with self._status_lock:
            self._status_bytes = data
        pub.put(data)

    def _overrun_warning(self) -> None:
        now = time.monotonic()
        if now - self._last_overrun_warning >= OVERRUN_WARNING_INTERVAL:
            self._last_overrun_warning = now
            last = self.ticker.last_duration or 0.0
            self._emit(
                "warning",
                {"overrun_ms": round(1000 * last, 2), "period_ms": 1000 * self.ticker.period,
                 "overruns": self.ticker.overruns},
            )  # fmt: skip

    def _trace(self, rec: TickRecord, started: float) -> None:
        out = self.config.trace
        if out is None:
            return
        row: dict[str, Any] = {
            "tick": rec.tick,
            "work": self.ticker.last_duration,
            "begin": started,
            "mode": rec.mode,
            "seq": rec.sample_seq,
            "stamp": rec.sample_stamp,
            "received": rec.sample_received,
            "sent": rec.command_sent,
        }
        wall_minus_mono = time.time() - time.monotonic()
        row["wall_sent"] = rec.command_sent + wall_minus_mono
        if rec.sample_received is not None:
            row["wall_received"] = rec.sample_received + wall_minus_mono
        out.write(json.dumps(row) + "\n")

    def _fail_pending(self) -> None:
        while True:
            try:
                pending = self.commands.get_nowait()
            except queue.Empty:
                return
            pending.reply = {"ok": False, "error": "the daemon is shutting down"}
            pending.done.set()


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


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _event_text(kind: str, detail: dict[str, Any]) -> str:
    if kind == "commit":
        return f"commit goal={detail['goal']} p={detail['p']}"
    parts = " ".join(f"{k}={v}" for k, v in detail.items() if k != "posterior")
    return f"{kind} {parts}".strip()
