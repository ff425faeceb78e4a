"""The :class:`Client`: one zenoh session to one robot's daemon.

It connects where the daemon listens (a hardware profile's ``[transport]``, turned into
connect endpoints as every publisher does) or with a zenoh configuration file — e.g. the
operator's of ``legws secure init``, for an authenticated transport. It keeps the newest
status and queues the events it hears (bounded: a client that never reads drops the oldest),
sends commands and waits for their replies, and opens joystick publishers on the same
transport.

What the daemon says is data for the caller, but the messages the client makes of it — a
refusal's reason, a reply that is not JSON — are terminal-safe
(:func:`~legws_daemon.formats.printable.safe_text`): a daemon (or anything publishing on its
keys) cannot put an escape sequence on the terminal of a script that prints them.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import zenoh

from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.messages import (
    SCHEMA_VERSION,
    CommandRequest,
    EventMessage,
    StatusMessage,
    parse,
)
from legws_daemon.formats.printable import safe_text
from legws_daemon.formats.profile import ProfileSpec, load_profile_named
from legws_daemon.formats.validation import validate
from legws_daemon.joystick.daemon_status import StatusWatch, wait_for_status
from legws_daemon.joystick.publisher import Publisher, dial_spec, process_source
from legws_daemon.transport.session import (
    config_from_file,
    config_from_spec,
    keys,
    open_session,
    payload_bytes,
)

#: Events kept for :meth:`Client.events` before the oldest are dropped.
EVENT_QUEUE = 1024
#: How long a command waits for the daemon's reply by default, s.
COMMAND_TIMEOUT = 10.0


class CommandRefusedError(LegwsError):
    """The daemon answered a command with an error (``reply.error`` says why)."""

    def __init__(self, reply: Reply) -> None:
        self.reply = reply
        super().__init__(safe_text(f"{reply.command}: refused: {reply.error}"))


@dataclass(frozen=True, slots=True)
class Reply:
    """The daemon's answer to a command.

    Attributes:
        command: the command sent; ok: carried out; detail: the reply's fields
            (``status``: the status message; ``reset``: ``mode``, ``plan``, ``waiting`` …);
        error: why it was refused (``None`` when ``ok``), terminal-safe.
    """

    command: str
    ok: bool
    detail: dict[str, Any] = field(default_factory=dict)
    error: str | None = None


def _reply_detail(payload: zenoh.ZBytes | None, source: str) -> dict[str, Any]:
    """A reply's fields (a JSON object); anything else, a refusal saying what came."""
    try:
        raw = payload_bytes(payload, source) or b"{}"
    except InputError as err:  # over the size bound
        return {"ok": False, "error": str(err)}
    try:
        detail = json.loads(raw)
    except ValueError:  # not JSON (not UTF-8 either: UnicodeDecodeError is a ValueError)
        return {"ok": False, "error": raw.decode(errors="replace")}
    if not isinstance(detail, dict):
        return {"ok": False, "error": f"the reply is not a JSON object: {raw.decode()}"}
    return detail


class Client:
    """A session with one robot's daemon; a context manager.

    Args:
        config: the zenoh configuration (see :meth:`from_profile`, :meth:`from_config`).
        robot: the robot's name (``legws/<robot>/…`` keys; a profile's ``robot``).
        where: the endpoints dialled, for messages.
    """

    def __init__(self, config: zenoh.Config, robot: str, where: list[str] | None = None) -> None:
        self.config = config
        self.robot = robot
        self.keys = keys(robot)
        self.where = list(where or [])
        self._watch = StatusWatch(self.keys["status"])
        self._events: queue.Queue[EventMessage] = queue.Queue(EVENT_QUEUE)
        self._lock = threading.Lock()
        self._session: zenoh.Session | None = None
        self._closing: Callable[[], None] | None = None
        self._status_seen = threading.Condition()
        self._status_count = 0
        self.dropped_events = 0  # events dropped because nobody read them

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def from_profile(cls, profile: str | Path | ProfileSpec = "sim") -> Client:
        """Connect where the profile's daemon listens (a name in hw_profiles/, a .toml
        path, or a loaded profile)."""
        spec = profile if isinstance(profile, ProfileSpec) else load_profile_named(Path(profile))
        dial = dial_spec(spec.transport)
        return cls(config_from_spec(dial), spec.robot, list(dial.connect))

    @classmethod
    def from_config(cls, path: Path | str, robot: str = "sawyer_sim") -> Client:
        """Connect with a zenoh JSON5 configuration file (a real network, TLS, the
        operator's identity of ``legws secure init``)."""
        return cls(config_from_file(Path(path)), robot, [f"the endpoints of {path}"])

    # -- lifetime -------------------------------------------------------------------------
    def __enter__(self) -> Client:
        if self._session is not None:
            raise LegwsError("the client is already open")
        context = open_session(self.config)
        session = context.__enter__()
        try:
            subs = [
                session.declare_subscriber(self.keys["status"], self._on_status),
                session.declare_subscriber(self.keys["events"], self._on_event),
            ]
        except BaseException:
            context.__exit__(None, None, None)
            raise

        def closing() -> None:
            for sub in subs:
                sub.undeclare()  # type: ignore[no-untyped-call]
            context.__exit__(None, None, None)

        self._session, self._closing = session, closing
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the session (idempotent)."""
        closing, self._closing, self._session = self._closing, None, None
        if closing is not None:
            closing()

    @property
    def session(self) -> zenoh.Session:
        """The open zenoh session."""
        if self._session is None:
            raise LegwsError("the client is not open (use it in a with block)")
        return self._session

    # -- what the daemon says -------------------------------------------------------------
    def _on_status(self, sample: zenoh.Sample) -> None:
        before = self._watch.newest
        self._watch.offer(sample.payload.to_bytes())
        if self._watch.newest is not before:
            with self._status_seen:
                self._status_count += 1
                self._status_seen.notify_all()

    def _on_event(self, sample: zenoh.Sample) -> None:
        try:
            event = parse(EventMessage, sample.payload.to_bytes(), self.keys["events"])
        except InputError:
            return
        while True:
            try:
                self._events.put_nowait(event)
                return
            except queue.Full:
                try:
                    self._events.get_nowait()  # the oldest goes
                    self.dropped_events += 1
                except queue.Empty:
                    pass

    def status(self, timeout: float = 5.0) -> StatusMessage:
        """The newest status, waiting up to ``timeout`` s for the first one.

        Raises:
            InputError: none came (no daemon there): the key and the endpoints dialled.
        """
        self.session  # noqa: B018 (open, or say so)
        return wait_for_status(self._watch, timeout, self.where)

    def statuses(self, timeout: float | None = None) -> Iterator[StatusMessage]:
        """Each new status as it arrives (the profile's status rate, 10 Hz); ends when none
        came for ``timeout`` s (``None``: never)."""
        seen = -1

        def new() -> bool:
            return self._status_count != seen

        while True:
            with self._status_seen:
                if not self._status_seen.wait_for(new, timeout):
                    return
                seen = self._status_count
            status = self._watch.newest
            if status is not None:
                yield status

    def events(self, timeout: float | None = None) -> Iterator[EventMessage]:
        """The events heard since the client opened (or since the last read), in order,
        then each as it comes; ends when none came for ``timeout`` s (``None``: never)."""
        while True:
            try:
                yield self._events.get(timeout=timeout)
            except queue.Empty:
                return

    def next_status(self, timeout: float = 1.0) -> StatusMessage | None:
        """The next status to arrive after this call (``None`` after ``timeout`` s)."""
        with self._status_seen:
            seen = self._status_count
            if not self._status_seen.wait_for(lambda: self._status_count != seen, timeout):
                return None
        return self._watch.newest

    def wait_for(
        self, predicate: Callable[[StatusMessage], bool], timeout: float
    ) -> StatusMessage | None:
        """The first status (the newest, then each new one) for which ``predicate`` holds,
        or ``None`` after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        newest = self._watch.newest
        if newest is not None and predicate(newest):
            return newest
        for status in self.statuses(timeout=max(0.0, deadline - time.monotonic())):
            if predicate(status):
                return status
            if time.monotonic() >= deadline:
                break
        return None

    # -- what it is asked -----------------------------------------------------------------
    def command(
        self,
        command: str,
        argument: str | None = None,
        *,
        plan: str | None = None,
        timeout: float = COMMAND_TIMEOUT,
        check: bool = True,
    ) -> Reply:
        """Send a command (docs/messages.md: ``status``, ``stop``, ``reset``,
        ``load_scene``, ``load_taskgraph``, ``release``, ``take_control``) and wait for the
        reply.

        Raises:
            InputError: the command does not validate (nothing is sent).
            CommandRefusedError: the daemon refused it (``check``; else the reply says so).
            LegwsError: no reply within ``timeout`` s.
        """
        body: dict[str, Any] = {"schema": SCHEMA_VERSION, "command": command}
        if argument is not None:
            body["argument"] = argument
        if plan is not None:
            body["plan"] = plan
        request = validate(CommandRequest, body, self.keys["command"])
        payload = json.dumps(request.model_dump(by_alias=True, exclude_none=True)).encode()
        for answer in self.session.get(self.keys["command"], payload=payload, timeout=timeout):
            sample = answer.ok if answer.ok is not None else answer.err
            detail = _reply_detail(
                sample.payload if sample is not None else None, self.keys["command"]
            )
            ok = answer.ok is not None and bool(detail.get("ok", True))
            error = None if ok else safe_text(str(detail.get("error", "no detail")))
            reply = Reply(command, ok, detail, error)
            if check and not reply.ok:
                raise CommandRefusedError(reply)
            return reply
        raise LegwsError(
            f"{self.keys['command']}: no reply to {command} within {timeout:g} s (is the daemon "
            "running, and does its access control let this identity send commands?)"
        )

    def joystick(self, kind: str = "client", *, take_control: bool = False) -> Publisher:
        """A (not yet opened) joystick publisher on this robot's key, on the client's
        transport, labelled ``kind:<pid>``; open it with ``with``."""
        return Publisher(
            self.config,
            self.keys["joystick"],
            source=process_source(kind),
            take_control=take_control,
        )
