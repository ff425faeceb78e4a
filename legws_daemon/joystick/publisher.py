"""The part every joystick publisher shares: session, sequence numbers, recording, the loop.

A :class:`Publisher` opens one zenoh session, declares a publisher on the robot's
``legws/<robot>/joystick`` key and turns deflections into validated
:class:`~legws_daemon.formats.messages.JoystickMessage` payloads (schema 1, a random
``session`` id chosen when it opens, ``seq`` from 0 within it, ``stamp = time.time()``);
its last message says goodbye (``bye``: zero deflection, enable released), which ends its
operator lease at the daemon at once. Every message it puts can also be appended to a JSONL
recording, one :func:`~legws_daemon.formats.messages.dump` per line, which
``legws joystick replay`` reads back.

Every session is *keyed* (docs/messages.md, ``hello``): before its first message the
publisher asks the daemon for a key for its session id — a zenoh query, whose reply only
the asker gets — and tags every message with it (``auth``). Then nobody who sees its
messages can steer as its session: the daemon refuses a keyed session's message without the
right tag. When no daemon answers yet, the messages go untagged and the publisher asks again
(at most every :data:`HELLO_RETRY` s); once a daemon answers, a session whose id has already
been seen untagged is not keyed — the publisher says goodbye on it and goes on in a fresh,
keyed session (``seq`` from 0; ``take_control`` again if it was asked for). The same when the
daemon's status shows another daemon (its ``started``) than the one that keyed the session: a
restarted daemon knows no key.

The daemon's profile *listens* on its endpoints; a publisher must *connect* to them:
:func:`dial_spec` turns the profile's transport table into the publisher's.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import secrets
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

import zenoh

from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.files import LineFile, open_output
from legws_daemon.formats.messages import (
    SCHEMA_VERSION,
    Buttons,
    HelloReply,
    JoystickMessage,
    auth_tag,
    dump,
    public_session_id,
)
from legws_daemon.formats.profile import ProfileSpec, TransportSpec
from legws_daemon.formats.validation import validate
from legws_daemon.transport.session import (
    config_from_file,
    config_from_spec,
    keys,
    open_session,
    payload_bytes,
)

#: A deflection (x, y, z) in the robot base frame.
Axes = tuple[float, float, float]
#: What an input device yields per tick: a deflection and the buttons, and with rotation
#: axes the rotation (``rotation`` of the message).
Sample = tuple[Axes, Buttons] | tuple[Axes, Buttons, Axes]
#: Called once per tick; ``None`` means "publish nothing this tick".
SampleFn = Callable[[], Sample | None]

ZERO: Axes = (0.0, 0.0, 0.0)
#: How long opening with ``take_control`` waits for the daemon's subscriber first, s.
CLAIM_WAIT = 3.0
#: Highest publishing rate accepted, Hz (the profile's control rate has the same bound).
MAX_RATE = 1000.0
#: How long a ``hello`` waits for the daemon's key at most, s (a daemon answers in ms; with
#: no daemon the query ends at once).
HELLO_TIMEOUT = 2.0
#: A session without a key asks for one again at most this often, s.
HELLO_RETRY = 0.5


def clip_norm(axes: Sequence[float]) -> Axes:
    """Scale a deflection down to norm 1 if it is longer (direction kept); each axis in [-1, 1].

    Raises :class:`InputError` for anything but three finite numbers.
    """
    values = tuple(float(a) for a in axes)
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(f"expected three finite numbers, got {values!r}", field="axes")
    norm = math.sqrt(sum(v * v for v in values))
    scale = 1.0 / norm if norm > 1.0 else 1.0
    x, y, z = (min(1.0, max(-1.0, v * scale)) for v in values)
    return (x, y, z)


def process_source(kind: str) -> str:
    """A ``source`` label naming the publisher for people, e.g. ``keyboard:4242``
    (the daemon tells publishers apart by their ``session``, not by this label)."""
    return f"{kind[:50]}:{os.getpid()}"


def new_session_id() -> str:
    """A fresh publisher session id: 16 random hexadecimal digits."""
    return secrets.token_hex(8)


def dial_spec(spec: TransportSpec) -> TransportSpec:
    """The publisher's transport: connect to what the daemon listens on, listen on nothing."""
    connect = list(dict.fromkeys([*spec.connect, *spec.listen]))
    data = {**spec.model_dump(), "listen": [], "connect": connect}
    return validate(TransportSpec, data, "transport")


def publisher_config(profile: ProfileSpec, zenoh_config: Path | None = None) -> zenoh.Config:
    """The zenoh configuration of a publisher: the file if given, else :func:`dial_spec`."""
    if zenoh_config is not None:
        return config_from_file(zenoh_config)
    return config_from_spec(dial_spec(profile.transport))


def _check_rate(rate: float) -> float:
    if not (math.isfinite(rate) and 0.0 < rate <= MAX_RATE):
        raise InputError(f"must be in (0, {MAX_RATE:g}] Hz, got {rate!r}", field="rate")
    return float(rate)


def _check_duration(duration: float | None) -> float:
    """``None`` -> infinity; otherwise a positive number of seconds."""
    if duration is None:
        return math.inf
    if math.isnan(duration) or duration <= 0.0:
        raise InputError(
            f"must be a positive number of seconds, got {duration!r}", field="duration"
        )
    return float(duration)


class Publisher:
    """Publishes joystick messages on one robot's joystick key; a context manager.

    Args:
        config: the zenoh configuration (see :func:`publisher_config`).
        key: the key expression, normally ``keys(profile.robot)["joystick"]``.
        source: the ``source`` label of every message (1 to 64 characters).
        record: a JSONL file every published message is appended to, or ``None``.
        take_control: on opening, ask the daemon for the operator lease
            (:meth:`take_control`; a refusal or no answer is a :class:`LegwsError`).

    The session and the recording are opened by ``with`` and closed on leaving it.
    :meth:`publish` may be called from any thread.

    Attributes:
        session_id: this session as the daemon's status and events name it (its public
            id: :func:`~legws_daemon.formats.messages.public_session_id`).
        wire_session: the ``session`` id its messages carry.
        keyed: whether the daemon gave the session a key (its messages are tagged).
    """

    def __init__(
        self,
        config: zenoh.Config,
        key: str,
        *,
        source: str,
        record: Path | None = None,
        take_control: bool = False,
    ) -> None:
        if not 1 <= len(source) <= 64:
            raise InputError(f"must be 1 to 64 characters, got {source!r}", field="source")
        if not key:
            raise InputError("must not be empty", field="key")
        self.config = config
        self.key = key
        #: the daemon's command key (``hello``, ``take_control``) and status key, next to
        #: the joystick key
        self.command_key = key.rsplit("/", 1)[0] + "/command"
        self.status_key = key.rsplit("/", 1)[0] + "/status"
        self.source = source
        self.record_path = record
        self.claim = take_control
        self._lock = threading.Lock()
        self._seq = 0
        self._stack: ExitStack | None = None
        self._session: zenoh.Session | None = None
        self._publisher: zenoh.Publisher | None = None
        self._record: LineFile | None = None
        self._wire = new_session_id()
        self._key: bytes | None = None
        self._key_started: float | None = None  # the ``started`` of the daemon that keyed it
        self._daemon_started: float | None = None  # the newest status's ``started``
        self._asked = -math.inf  # when the last hello went out (monotonic)

    @classmethod
    def for_profile(
        cls,
        profile: ProfileSpec,
        *,
        source: str,
        zenoh_config: Path | None = None,
        record: Path | None = None,
        take_control: bool = False,
    ) -> Publisher:
        """A publisher on ``profile.robot``'s joystick key that connects to its daemon."""
        config = publisher_config(profile, zenoh_config)
        key = keys(profile.robot)["joystick"]
        return cls(config, key, source=source, record=record, take_control=take_control)

    # -- lifetime -------------------------------------------------------------------------

    def __enter__(self) -> Publisher:
        if self._stack is not None:
            raise LegwsError("publisher is already open")
        with ExitStack() as stack:
            if self.record_path is not None:
                self._record = stack.enter_context(_open_record(self.record_path))
            self._session = stack.enter_context(open_session(self.config))
            self._publisher = self._session.declare_publisher(self.key)
            with self._lock:  # each opening is a new session, seq from 0, keyed afresh
                self._wire, self._key, self._key_started = new_session_id(), None, None
                self._daemon_started, self._asked, self._seq = None, -math.inf, 0
            self._session.declare_subscriber(self.status_key, self._on_status)
            if self.claim:
                self.wait_matched(CLAIM_WAIT)
                self.take_control()
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the session and the recording (idempotent)."""
        with self._lock:
            stack, self._stack = self._stack, None
            self._publisher = None
            self._session = None
            self._record = None
        if stack is not None:
            stack.close()

    @property
    def seq(self) -> int:
        """The ``seq`` the next message will carry (= messages published in the session)."""
        return self._seq

    @property
    def session_id(self) -> str:
        """This session as the daemon's status and events name it (its public id)."""
        return public_session_id(self._wire)

    @property
    def wire_session(self) -> str:
        """The ``session`` id the messages carry."""
        return self._wire

    @property
    def keyed(self) -> bool:
        """Whether the daemon keyed this session (its messages carry ``auth``)."""
        return self._key is not None

    @property
    def session(self) -> zenoh.Session:
        """The open zenoh session."""
        if self._session is None:
            raise LegwsError("publisher is not open (use it in a with block)")
        return self._session

    def matched(self) -> bool:
        """Whether some subscriber (normally the daemon) listens on the joystick key."""
        pub = self._publisher
        if pub is None:
            return False
        status: object = pub.matching_status
        return bool(getattr(status, "matching", status))

    def wait_matched(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for a subscriber on the key; whether one appeared."""
        deadline = time.monotonic() + timeout
        while not self.matched():
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def take_control(self, timeout: float = 5.0) -> dict[str, Any]:
        """Ask the daemon to give this session the operator lease (the ``take_control``
        command with :attr:`wire_session`); returns the reply. The session is keyed first
        (the command shows its id).

        Raises :class:`LegwsError` with the daemon's reason when it refuses, and when no
        reply comes (no daemon, or its access control refuses commands from this identity).
        """
        with self._lock:
            self._ensure_key(time.monotonic())
        return self._take_control(timeout)

    def _take_control(self, timeout: float = 5.0) -> dict[str, Any]:
        body = {"schema": SCHEMA_VERSION, "command": "take_control", "argument": self._wire}
        for reply in self.session.get(
            self.command_key, payload=json.dumps(body).encode(), timeout=timeout
        ):
            if reply.ok is not None:
                answer: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
                return answer
            err = reply.err
            error = err.payload.to_bytes().decode(errors="replace") if err else "no detail"
            raise LegwsError(f"{self.command_key}: take_control refused: {error}")
        raise LegwsError(
            f"{self.command_key}: no reply to take_control within {timeout:g} s (is the daemon "
            "running, and does its access control let this identity send commands?)"
        )

    # -- the session's key ----------------------------------------------------------------

    def _on_status(self, sample: zenoh.Sample) -> None:
        """zenoh thread: note which daemon runs (status ``started``); nothing else."""
        try:
            data = json.loads(payload_bytes(sample.payload, self.status_key))
        except (InputError, ValueError, RecursionError):
            return
        started = data.get("started") if isinstance(data, dict) else None
        if isinstance(started, float) and math.isfinite(started):
            self._daemon_started = started

    def _key_due(self, now: float) -> bool:
        """Whether to ask for a key now: none yet, or a status names another daemon than the
        one that gave it (at most every :data:`HELLO_RETRY` s)."""
        if now - self._asked < HELLO_RETRY:
            return False
        started = self._daemon_started
        return self._key is None or (started is not None and started != self._key_started)

    def _ensure_key(self, now: float) -> None:
        """Under the lock, before a message: key the session if it is due (module
        docstring); a new session if the current one's id is out already."""
        if not self._key_due(now):
            return
        self._asked = now
        fresh = self._seq > 0 or self._key is not None  # its id was seen, or keyed elsewhere
        wire = new_session_id() if fresh else self._wire
        reply, refused = self._hello(wire)
        if reply is None:
            if refused and not fresh:
                self._wire = new_session_id()  # someone asked for this id first: another one
            return
        key = bytes.fromhex(reply.key)
        if self._key is not None and reply.started == self._key_started:
            self._daemon_started = self._key_started  # the same daemon: the status was not its
            return
        if fresh and self._seq > 0:
            self._put(ZERO, Buttons(enable=False), bye=True)  # the old session ends
        self._wire, self._key, self._key_started = wire, key, reply.started
        if self._daemon_started is None:
            self._daemon_started = reply.started
        if fresh:
            self._seq = 0
            if self.claim:
                with contextlib.suppress(LegwsError):  # refused: it takes the lease by steering
                    self._take_control()

    def _hello(self, wire: str) -> tuple[HelloReply | None, bool]:
        """Ask the daemon for a key for session ``wire``: its reply (``None``: none came,
        or it was refused — then the flag is set)."""
        body = {"schema": SCHEMA_VERSION, "command": "hello", "argument": wire}
        refused = False
        try:
            replies = self.session.get(
                self.command_key, payload=json.dumps(body).encode(), timeout=HELLO_TIMEOUT
            )
            for reply in replies:
                if reply.ok is None:
                    refused = True
                    continue
                try:
                    data = json.loads(payload_bytes(reply.ok.payload, self.command_key))
                    answer = validate(HelloReply, data, self.command_key)
                except (InputError, ValueError, RecursionError):
                    continue  # not the daemon's answer
                if answer.session == public_session_id(wire):
                    return answer, False
        except Exception:  # zenoh raises its own error types (a session closing)
            return None, refused
        return None, refused

    # -- publishing -----------------------------------------------------------------------

    def publish(
        self,
        axes: Sequence[float],
        buttons: Buttons | None = None,
        rotation: Sequence[float] | None = None,
        *,
        bye: bool = False,
    ) -> JoystickMessage:
        """Validate and put one message; returns it. The recording gets it too.

        Raises :class:`InputError` (naming the field) if ``axes`` is not a valid deflection
        (three numbers in [-1, 1], norm <= 1; see :func:`clip_norm`); nothing is sent then
        and ``seq`` does not advance.
        """
        with self._lock:
            if self._publisher is None:
                raise LegwsError("publisher is not open (use it in a with block)")
            if not bye:
                self._ensure_key(time.monotonic())
            return self._put(axes, buttons, rotation, bye=bye)

    def _put(
        self,
        axes: Sequence[float],
        buttons: Buttons | None,
        rotation: Sequence[float] | None = None,
        *,
        bye: bool,
    ) -> JoystickMessage:
        """Under the lock: validate, tag, put, record one message of the current session."""
        assert self._publisher is not None
        data = {
            "schema": SCHEMA_VERSION,
            "seq": self._seq,
            "stamp": time.time(),
            "axes": [float(a) for a in axes],
            "buttons": buttons if buttons is not None else Buttons(),
            "source": self.source,
            "session": self._wire,
            "bye": bye,
        }
        if rotation is not None:
            data["rotation"] = [float(a) for a in rotation]
        message = validate(JoystickMessage, data, self.key)
        if self._key is not None:
            message = message.model_copy(update={"auth": auth_tag(self._key, message)})
        payload = dump(message)
        try:
            self._publisher.put(payload)
        except Exception as err:  # zenoh raises its own error types
            raise LegwsError(f"{self.key}: cannot publish: {err}") from None
        self._seq += 1
        if self._record is not None and not self._record.closed:  # closed: the disk
            self._record.write(payload.decode() + "\n")  # filled (said once)
        return message

    def goodbye(self) -> JoystickMessage:
        """The last message of every run: zero, enable released, ``bye`` (the daemon takes
        it as no input and ends this session's operator lease)."""
        return self.publish(ZERO, Buttons(enable=False), bye=True)

    def run(
        self,
        sample_fn: SampleFn,
        rate: float,
        duration: float | None = None,
        stop_event: threading.Event | None = None,
    ) -> int:
        """Call ``sample_fn`` at ``rate`` Hz and publish what it returns, until stopped.

        The loop ends when ``stop_event`` is set (by a signal handler, another thread or
        ``sample_fn`` itself) or after ``duration`` seconds, and then always publishes one
        goodbye (:meth:`goodbye`). Ticks are on a fixed schedule; ticks missed by an overrun
        are skipped, not made up in a burst. Returns the number of messages published from
        samples (without the goodbye).
        """
        period = 1.0 / _check_rate(rate)
        length = _check_duration(duration)
        stop = stop_event if stop_event is not None else threading.Event()
        start = time.monotonic()
        end = start + length
        tick = 0
        published = 0
        try:
            while not stop.is_set() and time.monotonic() < end:
                sample = sample_fn()
                if sample is not None:
                    self.publish(*sample)
                    published += 1
                tick += 1
                now = time.monotonic()
                if start + tick * period < now:  # overrun: skip to the next tick ahead
                    tick = math.ceil((now - start) / period)
                stop.wait(max(0.0, min(start + tick * period, end) - now))
        finally:
            if self._publisher is not None:
                self.goodbye()
        return published


@contextmanager
def _open_record(path: Path) -> Iterator[LineFile]:
    """The recording, appended to line by line; a full disk is one line (the file keeps
    its whole lines), a device or folder in its place is refused."""
    with open_output(path, append=True) as out:
        yield out


@contextmanager
def stop_on_signals(stop: threading.Event | None = None) -> Iterator[threading.Event]:
    """Within the block, SIGINT and SIGTERM set the yielded event instead of killing us.

    A second SIGINT while the event is already set raises :class:`KeyboardInterrupt` (a
    stuck shutdown can still be interrupted). The previous handlers are restored on exit.
    Outside the main thread no handler can be installed and the event is only yielded.
    """
    event = stop if stop is not None else threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield event
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        if signum == signal.SIGINT and event.is_set():
            raise KeyboardInterrupt
        event.set()

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield event
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
