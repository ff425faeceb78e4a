"""A fixed-rate loop timer that reports overruns and stalls and keeps tick-time statistics.

A *stall* is the loop standing still far longer than any tick takes: the process was paused
(SIGSTOP, a swap storm, a debugger). :meth:`Ticker.standstill`, called once per tick right
before the robot is read, tells one from the time since its previous call: more than
:func:`stall_threshold` (:data:`STALL_PERIODS` periods and :data:`STALL_SECONDS`).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

import numpy as np

#: A stall is a gap between two ticks of more than this many control periods ...
STALL_PERIODS = 10
#: ... and more than this many seconds (the default heartbeat timeout).
STALL_SECONDS = 0.5


def stall_threshold(period: float) -> float:
    """The longest gap between two ticks that is not a stall, s."""
    return max(STALL_PERIODS * period, STALL_SECONDS)


class Ticker:
    """Deadline scheduling at ``rate_hz``: tick ``k`` starts at ``start + k / rate_hz``.

    A tick whose work ends after its successor's deadline is an *overrun*: the schedule is
    re-anchored at the current time (ticks are skipped, never bunched up to catch up). A
    *stall* (:meth:`standstill`) re-anchors it too, and is not an overrun.

    Args:
        rate_hz: loop rate.
        paced: sleep until each deadline (``False``: run as fast as possible, for tests
            and benchmarks; deadlines still define overruns).
        clock / sleep: injectable for tests.
        window: how many recent tick durations are kept for percentiles.
    """

    def __init__(
        self,
        rate_hz: float,
        *,
        paced: bool = True,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        window: int = 4096,
    ) -> None:
        self.period = 1.0 / rate_hz
        self.paced = paced
        self._clock = clock
        self._sleep = sleep
        self.ticks = 0
        self.overruns = 0
        self._durations: deque[float] = deque(maxlen=window)
        self._next = clock()
        self._started: float | None = None
        #: gaps between two ticks longer than this are stalls, s
        self.stall_after = stall_threshold(self.period)
        self.stalls = 0
        self.last_stall: float | None = None  # the latest stall's gap, s
        self._alive: float | None = None  # the last standstill() call

    def restart(self) -> None:
        """Start the schedule now (call right before the first tick)."""
        self._next = self._clock()
        self._alive = None

    def standstill(self) -> float | None:
        """Call once per tick, right before the robot is read: the gap since the previous
        call if it is a stall (longer than :attr:`stall_after`), else ``None``.

        After a stall the schedule and the tick's work start from now (a stall is no
        overrun). Wherever the pause fell — in the sleep, in this tick before this call, in
        the previous tick after it — the gap holds it.
        """
        now = self._clock()
        last, self._alive = self._alive, now
        if last is None or now - last <= self.stall_after:
            return None
        self.stalls += 1
        self.last_stall = now - last
        self._next = now
        self._started = now
        return self.last_stall

    def begin(self) -> float:
        """Mark the start of a tick's work; returns the time."""
        now = self._clock()
        self._started = now
        return now

    def end(self) -> bool:
        """Mark the end of the tick's work and wait for the next deadline.

        Returns ``True`` when this tick overran its period.
        """
        now = self._clock()
        work = now - self._started if self._started is not None else 0.0
        self._durations.append(work)
        self.ticks += 1
        self._next += self.period
        # paced: the work ran past the next deadline; unpaced: the work took over a period
        overrun = now > self._next if self.paced else work > self.period
        if overrun:
            self.overruns += 1
            self._next = now
        elif self.paced:
            self._sleep(self._next - now)
        return overrun

    @property
    def last_duration(self) -> float | None:
        return self._durations[-1] if self._durations else None

    def percentiles(self, *qs: float) -> list[float]:
        """Percentiles (0..100) of the recent tick work durations, seconds."""
        if not self._durations:
            return [float("nan")] * len(qs)
        arr = np.fromiter(self._durations, dtype=np.float64)
        return [float(v) for v in np.percentile(arr, qs)]
