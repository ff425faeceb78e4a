"""Telemetry off the control loop: a worker thread that feeds the Rerun recording.

The loop hands each tick's snapshot to a bounded queue and goes on; the worker logs it.
When the recording cannot keep up, tick snapshots are dropped (counted), never the loop
delayed; set-up data and text-log lines (commits, faults) are never dropped.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any

#: Snapshots waiting for the recording, at most (about 2.5 s at 100 Hz).
QUEUE_SIZE = 256


class TelemetryWorker:
    """Runs ``fn(*args, **kwargs)`` calls in order on one background thread.

    Args:
        name: thread name.
    """

    def __init__(self, name: str = "legws-telemetry") -> None:
        self._queue: queue.Queue[tuple[Callable[..., Any], tuple[Any, ...], dict[str, Any]] | None]
        self._queue = queue.Queue(maxsize=QUEUE_SIZE)
        self.dropped = 0
        self.errors = 0
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(
        self, fn: Callable[..., Any], *args: Any, droppable: bool = False, **kwargs: Any
    ) -> None:
        """Queue one call; a ``droppable`` call is dropped when the queue is full."""
        item = (fn, args, kwargs)
        if droppable:
            try:
                self._queue.put_nowait(item)
            except queue.Full:
                self.dropped += 1
        else:
            self._queue.put(item)

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            fn, args, kwargs = item
            try:
                fn(*args, **kwargs)
            except Exception as err:  # a recording problem must not end telemetry
                self.errors += 1
                self.last_error = f"{type(err).__name__}: {err}"

    def close(self, timeout: float = 5.0) -> None:
        """Log what is queued, then stop the thread (idempotent)."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join(timeout)
