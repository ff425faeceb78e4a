"""What a publisher knows of the daemon it steers: its status, checked and shown.

Every ``legws joystick`` publisher subscribes to the daemon's ``legws/<robot>/status`` on
its own session (:class:`StatusWatch`):

- at start it waits for the first status (:func:`wait_for_status`); none within the wait is
  bad input, one line saying where it looked (the key and the endpoints dialled) — a wrong
  profile, port or robot name, or no daemon — instead of publishing into nothing;
- while it runs, one line in the terminal says what the daemon does with the input
  (:func:`status_text`: mode, the top goal and its probability, the commit, the phase, who
  holds the operator lease, the deadman), rewritten in place on a terminal and printed on
  each change otherwise (a log file gets a line per change, not ten per second).

The formatting is pure; :class:`StatusLine` is the one part that writes. Every name a
status carries (stage, goals, commit, phase, the operator's source, a fault) comes from
whoever publishes on the key and is shown terminal-safe
(:func:`~legws_daemon.formats.printable.safe_text`): an escape sequence, a line break or a
bidirectional control in it is written as a visible escape, on a terminal and through a
pipe alike.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from typing import TextIO

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import StatusMessage, parse
from legws_daemon.formats.printable import safe_text

#: A status older than this is not used to steer, seconds.
STATUS_STALE = 0.5
#: How long a publisher waits for the daemon's first status by default, seconds (a
#: daemon started at the same moment takes ~5-10 s to load its robot model).
STATUS_WAIT = 20.0
#: After this long without a status the publisher says it waits, and where, seconds.
STATUS_NOTE = 2.0
#: How often the terminal line is rewritten at most, seconds.
LINE_PERIOD = 0.2
#: Longest a name of the status is shown, characters (a label is at most 64, escapes
#: make it longer).
NAME_LIMIT = 80
#: Longest the fault's text is shown, characters.
FAULT_LIMIT = 200


class StatusWatch:
    """The newest valid status of one robot (fed by a zenoh subscriber callback).

    Attributes:
        key: the status key expression; modes_seen: each mode once per change, in order;
        done: set when a status says ``idle`` (the task is done).
    """

    def __init__(self, key: str) -> None:
        self.key = key
        self._lock = threading.Lock()
        self._status: StatusMessage | None = None
        self._received = -math.inf
        self._first = threading.Event()
        self.modes_seen: list[str] = []
        self.done = threading.Event()

    def offer(self, payload: bytes) -> None:
        """A status payload as it arrived; one that does not validate is ignored."""
        try:
            status = parse(StatusMessage, payload, self.key)
        except InputError:
            return
        with self._lock:
            self._status, self._received = status, time.monotonic()
            if not self.modes_seen or self.modes_seen[-1] != status.mode:
                self.modes_seen.append(status.mode)
        self._first.set()
        if status.mode == "idle":
            self.done.set()

    def latest(self, now: float) -> StatusMessage | None:
        """The newest status if it is fresh at ``now`` (``time.monotonic``), else ``None``."""
        with self._lock:
            if now - self._received > STATUS_STALE:
                return None
            return self._status

    @property
    def newest(self) -> StatusMessage | None:
        """The newest status, however old (``None`` before the first)."""
        with self._lock:
            return self._status

    @property
    def received(self) -> float:
        """When the newest status arrived (``time.monotonic``)."""
        with self._lock:
            return self._received

    def wait_first(self, timeout: float) -> StatusMessage | None:
        """Wait up to ``timeout`` s for the first status; it, or ``None``."""
        self._first.wait(timeout)
        return self.newest


def wait_for_status(
    watch: StatusWatch,
    timeout: float,
    where: Sequence[str],
    note: Callable[[str], None] | None = None,
) -> StatusMessage:
    """The daemon's first status, waited for up to ``timeout`` s.

    Args:
        where: the endpoints the session dials (for the message).
        note: told once, after :data:`STATUS_NOTE` s without a status, that it waits and
            where it looks (``None``: nothing is said).

    Raises:
        InputError: none came — one line naming the key and the endpoints.
    """
    dialled = ", ".join(where) if where else "the zenoh configuration's endpoints"
    status = watch.wait_first(min(timeout, STATUS_NOTE) if note is not None else timeout)
    if status is None and note is not None and timeout > STATUS_NOTE:
        note(f"waiting up to {timeout:g} s for the daemon's status on {watch.key} (dialled "
             f"{dialled})")  # fmt: skip
        status = watch.wait_first(timeout - STATUS_NOTE)
    if status is None:
        raise InputError(
            f"no status from the daemon on {watch.key} within {timeout:g} s (dialled "
            f"{dialled}): is it running, for this robot, listening there?"
        )
    return status


def top_goal(status: StatusMessage) -> tuple[str, float] | None:
    """The most probable goal and its probability (``None``: no inference runs)."""
    if not status.posterior:
        return None
    goal = max(sorted(status.posterior), key=lambda g: status.posterior[g])
    return goal, status.posterior[goal]


def status_text(status: StatusMessage, session: str | None = None) -> str:
    """One line of what the daemon does: ``teleop · stage choose_tea · top green_tea 0.72 ·
    commit - · phase - · operator keyboard:4242 (you) · deadman off``.

    ``session``: this publisher's session id — the lease holder is marked ``(you)`` when it
    is this one, ``(not you)`` otherwise. Every name is terminal-safe, at most
    :data:`NAME_LIMIT` characters (the fault :data:`FAULT_LIMIT`).
    """

    def name(text: str) -> str:
        return safe_text(text, NAME_LIMIT)

    top = top_goal(status)
    parts: list[str] = [name(status.mode)]
    if status.stage:
        parts.append(f"stage {name(status.stage)}")
    parts.append(f"top {name(top[0])} {top[1]:.2f}" if top is not None else "top -")
    parts.append(f"commit {name(status.committed or '-')}")
    parts.append(f"phase {name(status.phase or '-')}")
    if status.operator is None:
        parts.append("operator none")
    else:
        mine = session is not None and status.operator.session == session
        who = " (you)" if mine else " (not you)" if session is not None else ""
        parts.append(f"operator {name(status.operator.source)}{who}")
    parts.append(f"deadman {'on' if status.deadman else 'off'}")
    if status.fault:
        parts.append(f"fault {safe_text(status.fault, FAULT_LIMIT)}")
    return " · ".join(parts)


def fit(line: str, stream: TextIO) -> str:
    """``line`` cut to one row of the terminal ``stream`` is (a wrapped line cannot be
    rewritten in place: ``\\r`` goes back to the start of its last row only)."""
    try:
        width = os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return line  # not a terminal (or it does not say): the whole line
    if width <= 1 or len(line) < width:
        return line  # (a pseudo-terminal nobody sized says 0)
    return line[: width - 2] + "…"


def change_key(status: StatusMessage) -> tuple[object, ...]:
    """What a line per change changes on: everything :func:`status_text` shows but the
    probability's digits (they change every status)."""
    top = top_goal(status)
    holder = status.operator.session if status.operator is not None else None
    return (status.mode, status.stage, top[0] if top else None, status.committed,
            status.phase, holder, status.deadman, status.fault)  # fmt: skip


class StatusLine:
    """Shows :func:`status_text` of the newest status on ``stream``, from its own thread.

    On a terminal the line is rewritten in place (at most every :data:`LINE_PERIOD`); on
    anything else (a pipe, a log file) a line is printed when :func:`change_key` changes.
    A context manager: the thread runs inside the ``with`` block.
    """

    def __init__(
        self,
        watch: StatusWatch,
        stream: TextIO,
        session: str | Callable[[], str | None] | None = None,
        prefix: str = "",
    ) -> None:
        self.watch = watch
        self.stream = stream
        #: the publisher's public session id, or how to read it now (a publisher keys a
        #: fresh session when a daemon restarts under it)
        self.session = session
        self.prefix = prefix
        self.terminal = stream.isatty()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="status-line", daemon=True)
        self._shown: object = None
        self.lines = 0  # lines written (changes, or rewrites on a terminal)

    def __enter__(self) -> StatusLine:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        if self.terminal and self.lines:
            self.stream.write("\n")
            self.stream.flush()

    def show(self) -> None:
        """Write the line if it changed (one step of the thread; callable directly)."""
        status = self.watch.newest
        if status is None:
            return
        session = self.session() if callable(self.session) else self.session
        line = safe_text(self.prefix + status_text(status, session))
        if self.terminal:
            if line == self._shown:
                return
            self._shown = line
            self.stream.write("\r" + fit(line, self.stream) + "\x1b[K")
        else:
            key = change_key(status)
            if key == self._shown:
                return
            self._shown = key
            self.stream.write(line + "\n")
        self.stream.flush()
        self.lines += 1

    def _run(self) -> None:
        while not self._stop.wait(LINE_PERIOD):
            self.show()
