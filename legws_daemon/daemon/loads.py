"""The load pipeline: ``load_scene`` and ``load_taskgraph`` prepared off the control loop.

A load (files, a new MuJoCo world, a plan) takes longer than a tick, so it is prepared on a
thread of its own while the robot goes on: one at a time, in the order asked, at most
:data:`LOAD_QUEUE` waiting (more are answered ``busy``). The loop installs a prepared load
at the start of a tick (the robot stops there, as for any load); what it replaces, and a
load prepared but cancelled, are freed on the preparer's thread, handed over only once the
tick's own work is done (:meth:`LoadPipeline.hand_over`: a tick never shares the
interpreter with a world being built or freed). A cancelled load (a stop came after it,
the daemon shuts down) is answered with why at once and never installed.
"""

from __future__ import annotations

import contextlib
import functools
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from legws_daemon.autonomy.controller import PreparedLoad
from legws_daemon.daemon.commands import PendingCommand
from legws_daemon.errors import LegwsError
from legws_daemon.formats.messages import CommandRequest

#: Loads that may wait for the preparer (beyond the one being prepared).
LOAD_QUEUE = 4
#: Longest the shutdown waits for a load being prepared, to free it, s.
SHUTDOWN_WAIT = 30.0


@dataclass
class _Load:
    """A load being prepared."""

    pending: PendingCommand
    future: Future[PreparedLoad]
    cancelled: str | None = None  # why it will not be installed


class LoadPipeline:
    """Loads from the request to the reply: queued, prepared by ``prepare`` on the
    preparer's thread (started with ``initializer``), installed by the loop with
    ``install`` (the reply's detail, and what it replaced: freed with ``dispose``)."""

    def __init__(
        self,
        prepare: Callable[[CommandRequest], PreparedLoad],
        install: Callable[[PreparedLoad], tuple[dict[str, Any], Any]],
        dispose: Callable[[Any], None],
        initializer: Callable[[], None] | None = None,
    ) -> None:
        self._prepare, self._install, self._dispose = prepare, install, dispose
        self._waiting: deque[PendingCommand] = deque()
        self._current: _Load | None = None
        self._preparer = ThreadPoolExecutor(
            max_workers=1, thread_name_prefix="legws-load", initializer=initializer
        )
        self._after_tick: list[Callable[[], object]] = []

    @property
    def busy(self) -> bool:
        """A load is being prepared or waits."""
        return self._current is not None or bool(self._waiting)

    def offer(self, pending: PendingCommand) -> None:
        """Queue a load (the loop's thread), or answer ``busy`` when :data:`LOAD_QUEUE`
        wait already; the preparer starts on it after this tick."""
        if len(self._waiting) >= LOAD_QUEUE:
            pending.fail(f"busy: {LOAD_QUEUE} loads are waiting; nothing was done")
            return
        self._waiting.append(pending)
        if self._current is None:
            self._after_tick.append(self._start_next)

    def install_finished(self) -> int:
        """The loop, at a tick's start: install the load whose preparation finished (1),
        or nothing (0). Its reply is sent; a cancelled one is freed instead."""
        load = self._current
        if load is None or not load.future.done():
            return 0
        self._current = None
        if self._waiting:
            self._after_tick.append(self._start_next)
        try:
            prepared = load.future.result()
        except LegwsError as err:
            if load.cancelled is None:
                load.pending.fail(str(err))
            return 1
        if load.cancelled is not None:
            self.off_loop(prepared.discard)
            return 1
        try:
            detail, old = self._install(prepared)
        except LegwsError as err:
            self.off_loop(prepared.discard)
            load.pending.fail(str(err))
            return 1
        load.pending.finish({"ok": True, "command": load.pending.request.command, **detail})
        if old is not None:
            self.off_loop(self._dispose, old)
        return 1

    def cancel(self, why: str) -> None:
        """Answer every load not installed yet with ``why``; none of them will be."""
        while self._waiting:
            self._waiting.popleft().fail(why)
        load = self._current
        if load is not None and load.cancelled is None:
            load.cancelled = why
            load.pending.fail(why)

    def off_loop(self, fn: Callable[..., object], *args: object) -> None:
        """Run ``fn(*args)`` on the preparer's thread, handed over after this tick's work."""
        self._after_tick.append(functools.partial(self._preparer.submit, fn, *args))

    def hand_over(self) -> None:
        """The tick's own work is done: give the preparer its work."""
        work, self._after_tick = self._after_tick, []
        for job in work:
            job()

    def _start_next(self) -> None:
        if self._current is not None or not self._waiting:
            return
        pending = self._waiting.popleft()
        future = self._preparer.submit(self._prepare, pending.request)
        self._current = _Load(pending, future)

    def shutdown(self) -> None:
        """Answer the loads not installed (the daemon is shutting down), free one being
        prepared, and stop the preparer's thread once its work is done."""
        self.cancel("the daemon is shutting down")
        load, self._current = self._current, None
        if load is not None:
            with contextlib.suppress(Exception):
                load.future.result(timeout=SHUTDOWN_WAIT).discard()
        self._preparer.shutdown(wait=True, cancel_futures=True)
