"""Telemetry off the control loop: a worker thread that feeds the Rerun recording.

The loop hands each tick's snapshot to the worker and goes on; the worker logs it. When
the recording cannot keep up, tick snapshots are dropped (counted), never the loop
delayed: only droppable snapshots are bounded (:data:`QUEUE_SIZE`); set-up data and
text-log lines (commits, faults) are never dropped and never make the loop wait.

Problems are recorded, not reported, here: a call that raises and a failed health check
(``check``, run on the worker thread every ``check_every`` seconds, e.g. a recording
whose file can no longer be written) are counted, and the loop thread collects them with
:meth:`TelemetryWorker.take_report` and reports them itself (the worker never publishes).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

#: Droppable snapshots waiting for the recording, at most (about 5 s at 50 Hz).
QUEUE_SIZE = 256
#: Seconds between health checks after a failed one (a failing sink may block its check).
FAILED_CHECK_EVERY = 10.0

#: A queued call (with its arguments bound: the caller's types are checked where it binds
#: them), and whether it is droppable.
_Item = tuple[Callable[[], object], bool]


@dataclass(frozen=True, slots=True)
class TelemetryReport:
    """Telemetry problems since the previous report.

    Attributes:
        errors: problems so far (calls that raised, failed checks, errors recorded by the
            loop thread), in total.
        new: how many of them are new since the previous report.
        last_error: the newest problem.
        dropped: tick snapshots dropped so far because the queue was full.
    """

    errors: int
    new: int
    last_error: str
    dropped: int


class TelemetryWorker:
    """Runs ``fn(*args, **kwargs)`` calls in order on one background thread.

    Args:
        name: thread name.
        check: a health check run on the worker thread: ``None`` when all is well, else
            the problem (one line).
        check_every: seconds between checks (while the check passes).
    """

    def __init__(
        self,
        name: str = "legws-telemetry",
        *,
        check: Callable[[], str | None] | None = None,
        check_every: float = 2.0,
    ) -> None:
        self._queue: queue.Queue[_Item | None] = queue.Queue()
        self._droppable = 0  # droppable items in the queue
        self._lock = threading.Lock()
        self.dropped = 0
        self.errors = 0
        self.last_error: str | None = None
        self._reported = 0
        self._check = check
        self._check_every = check_every
        self._next_check = time.monotonic() + check_every
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Callable[[], object], *, droppable: bool = False) -> None:
        """Queue one call, its arguments bound (``lambda: log.log_tick(snapshot)``); a
        ``droppable`` call is dropped when :data:`QUEUE_SIZE` droppable calls are already
        waiting. Never blocks."""
        if droppable:
            with self._lock:
                if self._droppable >= QUEUE_SIZE:
                    self.dropped += 1
                    return
                self._droppable += 1
        self._queue.put((job, droppable))

    def record_error(self, error: str) -> None:
        """Count a telemetry problem found elsewhere (e.g. preparing a snapshot on the loop
        thread); it is reported like the worker's own."""
        with self._lock:
            self.errors += 1
            self.last_error = error

    def take_report(self) -> TelemetryReport | None:
        """The problems since the previous call, or ``None`` when there are none (cheap:
        meant to be called by the loop thread every tick)."""
        if self.errors == self._reported:
            return None
        with self._lock:
            new = self.errors - self._reported
            self._reported = self.errors
            return TelemetryReport(self.errors, new, self.last_error or "", self.dropped)

    def _run(self) -> None:
        while True:
            wait = None if self._check is None else max(0.0, self._next_check - time.monotonic())
            try:
                item = self._queue.get(timeout=wait)
            except queue.Empty:
                self._maybe_check()  # nothing to log: time for a check
                continue
            if item is None:
                return
            self._call(item)
            self._maybe_check()

    def _call(self, item: _Item) -> None:
        job, droppable = item
        if droppable:
            with self._lock:
                self._droppable -= 1
        try:
            job()
        except Exception as err:  # a recording problem must not end telemetry
            self.record_error(f"{type(err).__name__}: {err}")

    def _maybe_check(self) -> None:
        check = self._check
        if check is None or time.monotonic() < self._next_check:
            return
        try:
            problem = check()
        except Exception as err:
            problem = f"{type(err).__name__}: {err}"
        if problem is not None:
            self.record_error(problem)
        every = self._check_every if problem is None else max(self._check_every, FAILED_CHECK_EVERY)
        self._next_check = time.monotonic() + every

    @property
    def alive(self) -> bool:
        """Whether the worker thread still runs."""
        return self._thread.is_alive()

    def close(self, timeout: float = 5.0) -> bool:
        """Log what is queued, then stop the thread (idempotent).

        Returns:
            ``True`` when the thread ended within ``timeout`` seconds.
        """
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join(timeout)
        return not self._thread.is_alive()
