"""One rate limit for the daemon's repeated events (overruns, telemetry problems, rejected
input, the dead-man state, a role's stops).

A :class:`Throttle` lets one occurrence per key pass every ``interval`` seconds on its
clock, and counts the occurrences it held back in between: the next one to pass says how
many there were (a ``stop`` event's ``repeats``). ``force`` lets one pass at once whatever
the interval (a stop that stops the robot is always announced).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)


class Throttle(Generic[K]):
    """At most one pass per key every ``interval`` seconds of ``clock``.

    Args:
        interval: seconds between two passes of one key at least.
        clock: monotonic seconds (the daemon's is :func:`time.monotonic`; tests pass their
            own).
    """

    def __init__(self, interval: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.interval = interval
        self.clock = clock
        self._last: dict[K | None, float] = {}
        self._held: dict[K | None, int] = {}

    def attempt(
        self, key: K | None = None, *, now: float | None = None, force: bool = False
    ) -> int | None:
        """An occurrence of ``key`` (at ``now``, default the clock's time): ``None`` when it
        is held back (counted), else how many were held back since the last one passed."""
        t = self.clock() if now is None else now
        if not force and t - self._last.get(key, -math.inf) < self.interval:
            self._held[key] = self._held.get(key, 0) + 1
            return None
        self._last[key] = t
        return self._held.pop(key, 0)
