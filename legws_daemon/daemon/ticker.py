"""A fixed-rate loop timer that reports overruns and keeps tick-time statistics."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

import numpy as np


class Ticker:
    """Deadline scheduling at ``rate_hz``: tick ``k`` starts at ``start + k / rate_hz``.

    A tick whose work ends after its successor's deadline is an *overrun*: the schedule is
    re-anchored at the current time (ticks are skipped, never bunched up to catch up).

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

    def restart(self) -> None:
        """Start the schedule now (call right before the first tick)."""
        self._next = self._clock()

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
