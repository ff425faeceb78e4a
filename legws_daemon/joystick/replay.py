"""``legws joystick replay``: republish a recorded session with its original timing.

A recording is what ``--record`` writes: a JSONL file, one joystick message per line.
Every line is validated on load (errors name ``file:line`` and the field). Messages are
republished with fresh ``seq`` and ``stamp`` at the recorded intervals (from ``stamp``),
divided by ``--speed``. A file may hold several recordings appended one after the other:
where ``seq`` does not increase a new recording begins, and the pause between the two is
one nominal interval instead of the wall-clock time that passed between them.
"""

from __future__ import annotations

import itertools
import math
import statistics
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from legws_daemon.errors import InputError
from legws_daemon.formats.files import read_lines
from legws_daemon.formats.messages import JoystickMessage, parse
from legws_daemon.joystick.publisher import Publisher

#: Fastest replay accepted (a factor on the recorded timing).
MAX_SPEED = 1000.0
#: Most messages in one file: two hours at 20 Hz (read in ~2 s, ~270 MiB held).
MAX_MESSAGES = 150_000


def load_recording(path: Path) -> list[JoystickMessage]:
    """Every message of a JSONL recording; blank lines are skipped.

    Raises :class:`InputError` naming ``file:line`` and the field for a line that does not
    validate, for a ``stamp`` earlier than its predecessor's within one recording, for more
    than :data:`MAX_MESSAGES` messages, and for a file without messages.
    """
    lines: list[tuple[int, str]] = []
    for number, line in read_lines(path, "joystick log"):  # within the file's size limit
        if not line.strip():
            continue
        if len(lines) >= MAX_MESSAGES:
            # refused before a line is parsed: a file of too many messages costs a read,
            # not the seconds of validating the first 150,000
            raise InputError(
                f"more than {MAX_MESSAGES:,} messages (two hours at 20 Hz): split the file",
                source=f"{path}:{number}",
            )
        lines.append((number, line))
    messages: list[JoystickMessage] = []
    for number, line in lines:
        where = f"{path}:{number}"
        message = parse(JoystickMessage, line, where)
        if messages and _continues(messages[-1], message) and message.stamp < messages[-1].stamp:
            raise InputError(
                f"{message.stamp!r} is earlier than the previous message's "
                f"{messages[-1].stamp!r} (seq {messages[-1].seq} -> {message.seq})",
                source=where,
                field="stamp",
            )
        messages.append(message)
    if not messages:
        raise InputError("no joystick messages in the file", source=str(path))
    return messages


def _continues(previous: JoystickMessage, message: JoystickMessage) -> bool:
    """Whether ``message`` follows ``previous`` in the same recording (``seq`` increases)."""
    return message.seq > previous.seq


def nominal_interval(messages: Sequence[JoystickMessage], default: float) -> float:
    """The median positive interval between consecutive messages of one recording.

    ``default`` (e.g. the control period) when there is none.
    """
    gaps = [
        b.stamp - a.stamp
        for a, b in itertools.pairwise(messages)
        if _continues(a, b) and b.stamp > a.stamp
    ]
    return statistics.median(gaps) if gaps else default


def schedule(messages: Sequence[JoystickMessage], gap: float) -> list[float]:
    """When each message is due, s after the first, at speed 1.

    Consecutive messages of one recording keep their recorded interval; where a new
    recording begins (``seq`` does not increase) the pause is ``gap``.
    """
    offsets = [0.0]
    for a, b in itertools.pairwise(messages):
        step = b.stamp - a.stamp if _continues(a, b) else gap
        offsets.append(offsets[-1] + max(0.0, step))
    return offsets


def replay(
    publisher: Publisher,
    messages: Sequence[JoystickMessage],
    *,
    gap: float,
    speed: float = 1.0,
    loop: bool = False,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
) -> int:
    """Republish ``messages`` on their :func:`schedule`, ``speed`` times faster.

    With ``loop`` the file starts over ``gap`` after its last message. Ends at the end of
    the file (without ``loop``), after ``duration`` s or when ``stop_event`` is set, and
    then always says goodbye (:meth:`Publisher.goodbye`). Returns the number of recorded
    messages republished (without the goodbye).
    """
    if not (math.isfinite(speed) and 0.0 < speed <= MAX_SPEED):
        raise InputError(f"must be in (0, {MAX_SPEED:g}], got {speed!r}", field="speed")
    if not (math.isfinite(gap) and gap > 0.0):
        raise InputError(f"must be a positive number of seconds, got {gap!r}", field="gap")
    if duration is not None and not duration > 0.0:
        raise InputError(
            f"must be a positive number of seconds, got {duration!r}", field="duration"
        )
    if not messages:
        raise InputError("nothing to replay", field="messages")
    stop = stop_event if stop_event is not None else threading.Event()
    offsets = schedule(messages, gap)
    cycle = offsets[-1] + gap
    start = time.monotonic()
    end = start + duration if duration is not None else math.inf
    published = 0
    base = 0.0
    try:
        while True:
            for offset, message in zip(offsets, messages, strict=True):
                due = start + (base + offset) / speed
                if not _wait_until(due, end, stop):
                    return published
                publisher.publish(message.axes, message.buttons)
                published += 1
            if not loop:
                return published
            base += cycle
    finally:
        publisher.goodbye()


def _wait_until(due: float, end: float, stop: threading.Event) -> bool:
    """Sleep until ``due``; False if ``stop`` was set or ``end`` comes first."""
    while True:
        if stop.is_set():
            return False
        now = time.monotonic()
        if now >= end:
            return False
        if now >= due:
            return True
        stop.wait(min(due, end) - now)
