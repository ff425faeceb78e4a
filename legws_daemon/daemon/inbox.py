"""The newest joystick sample, shared between the transport thread and the control loop.

The transport calls :meth:`JoystickInbox.offer` with raw payloads as they arrive; the
loop asks :meth:`JoystickInbox.latest` once per tick. A payload that does not validate is
counted and dropped — it is never used and it does not refresh the deadman, so bad input
stops the robot like no input. A sample older than the deadman timeout is no input.
"""

from __future__ import annotations

import threading
from collections import Counter
from dataclasses import dataclass

import numpy as np

from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import JoystickMessage, parse


@dataclass(frozen=True, slots=True)
class Sample:
    """A validated joystick message and the local monotonic time it arrived."""

    message: JoystickMessage
    received: float

    @property
    def operator(self) -> OperatorInput:
        """The sample as the controller takes it."""
        m = self.message
        return OperatorInput(
            np.array(m.axes, dtype=np.float64), m.buttons.confirm, m.buttons.cancel,
            self.received, m.seq, m.stamp,
        )  # fmt: skip


class JoystickInbox:
    """Thread-safe slot holding the newest valid joystick sample.

    Args:
        key: the key expression the samples come from (named in rejection reasons).
    """

    def __init__(self, key: str = "joystick") -> None:
        self.key = key
        self._lock = threading.Lock()
        self._sample: Sample | None = None
        self._last_seq: dict[str, int] = {}
        self.accepted = 0
        self.rejected = 0
        self.reasons: Counter[str] = Counter()
        self.last_error: str | None = None

    def offer(self, payload: bytes, now: float) -> Sample | None:
        """Validate one payload received at ``now``; keep it if valid and newer.

        Returns the stored sample, or ``None`` when the payload was rejected (bad) or
        superseded (an older ``seq`` of the same source arriving late).
        """
        try:
            message = parse(JoystickMessage, payload, self.key)
        except InputError as err:
            with self._lock:
                self.rejected += 1
                self.reasons[err.field or "payload"] += 1
                self.last_error = str(err)
            return None
        with self._lock:
            last = self._last_seq.get(message.source)
            if last is not None and message.seq <= last and last - message.seq < 1000:
                # out of order or repeated; a large jump back is a restarted publisher
                self.reasons["stale_seq"] += 1
                return None
            self._last_seq[message.source] = message.seq
            sample = Sample(message, now)
            self._sample = sample
            self.accepted += 1
            return sample

    def latest(self, now: float, timeout: float) -> Sample | None:
        """The newest valid sample if it arrived within ``timeout`` of ``now``, else ``None``."""
        with self._lock:
            sample = self._sample
        if sample is None or now - sample.received > timeout or now < sample.received - 1.0:
            return None
        return sample

    def clear(self) -> None:
        """Forget the current sample (e.g. after a stop: the user must move the stick again)."""
        with self._lock:
            self._sample = None
