"""Background threads step aside while the control loop runs a tick.

The loop's tick lets go of Python's interpreter lock whenever it calls into zenoh (a
status put, a query reply, a command to the bridge). A background thread doing Python work
(a load being prepared, a world being freed) takes the lock then, and the tick waits up to
the interpreter's switch interval (5 ms) to get it back — each time. Measured with a
tick-like probe that lets go ten times: p99 27 ms beside a load preparer.

A :class:`LoopGate` fixes that cooperatively. The loop :meth:`~LoopGate.close`\\ s it for
the tick's work and :meth:`~LoopGate.open`\\ s it after; a background thread that called
:meth:`~LoopGate.enter_thread` waits at its next Python or C function call while the gate
is closed. The probe's p99 went back to 6.8 ms while the preparer still made 98 % of its
loads. A C call already running when the gate closes runs to its end.

A background thread waits at most once per closing, and at most :data:`MAX_WAIT`: should
the loop itself wait for something the paused thread holds (a lock: the logging module's,
say), the thread goes on after :data:`MAX_WAIT` and lets go of it; it does not pause again
before the gate has opened. So the gate can delay the loop by :data:`MAX_WAIT` at worst,
never dead-lock it.
"""

from __future__ import annotations

import sys
import threading
from types import FrameType
from typing import Any

#: Longest a background thread waits for the gate to open, once per closing, s (a tick's
#: work takes 2-3 ms).
MAX_WAIT = 0.02
_WAIT_EVENTS = frozenset({"call", "c_call"})


class LoopGate:
    """Open while the control loop is between ticks."""

    def __init__(self) -> None:
        self._open = threading.Event()
        self._open.set()
        self._closings = 0  # how many times it closed (tells one closing from the next)

    def close(self) -> None:
        """A tick begins: background threads pause at their next call."""
        self._closings += 1
        self._open.clear()

    def open(self) -> None:
        """The tick's work is done: background threads go on."""
        self._open.set()

    @property
    def is_open(self) -> bool:
        return self._open.is_set()

    def wait(self) -> None:
        """Wait (at most :data:`MAX_WAIT`) for the tick running now to end: for a thread
        that is not a background thread but whose work can wait that long (a command
        arriving on a zenoh thread)."""
        if not self._open.is_set():
            self._open.wait(MAX_WAIT)

    def enter_thread(self) -> None:
        """Make the calling thread a background thread: paused at its calls while the gate
        is closed. Its scheduling stays what it inherited: started by a real-time loop it
        runs at the loop's priority (:mod:`~legws_daemon.daemon.scheduling` says why), and
        never below normal (a low-priority thread holding a lock the loop needs would hold
        up the loop whenever the CPU is busy)."""
        waited = [-1]  # the closing this thread last waited in

        def hook(frame: FrameType, event: str, arg: Any) -> None:
            if event in _WAIT_EVENTS and not self._open.is_set():
                closing = self._closings
                if waited[0] != closing:
                    waited[0] = closing
                    self._open.wait(MAX_WAIT)

        sys.setprofile(hook)
