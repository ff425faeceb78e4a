"""The loop gate: background threads pause while a tick runs, and never dead-lock it."""

from __future__ import annotations

import threading
import time

import pytest

from legws_daemon.daemon.gate import MAX_WAIT, LoopGate


def _work() -> int:
    return sum(range(10))


class Background:
    """A thread behind the gate that counts its calls (optionally holding ``lock``)."""

    def __init__(self, gate: LoopGate, lock: threading.Lock | None = None) -> None:
        self.count = 0
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._lock = lock
        self._gate = gate
        self.thread = threading.Thread(target=self._run)
        self.thread.start()
        assert self._ready.wait(5.0)

    def _run(self) -> None:
        self._gate.enter_thread()
        self._ready.set()
        while not self._stop.is_set():
            if self._lock is not None:
                with self._lock:
                    for _ in range(100):
                        _work()
                        self.count += 1
            else:
                _work()
                self.count += 1

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5.0)
        assert not self.thread.is_alive()


def test_a_background_thread_pauses_while_the_gate_is_closed() -> None:
    gate = LoopGate()
    bg = Background(gate)
    try:
        time.sleep(0.02)
        assert bg.count > 0
        paused = []
        for _ in range(20):
            gate.close()
            time.sleep(0.002)  # the thread reaches its next call and waits
            before = bg.count
            time.sleep(0.008)  # well within MAX_WAIT
            paused.append(bg.count - before)
            gate.open()
            time.sleep(0.005)
        # it made no call in 8 ms of each closing (it ran freely in between)
        assert sorted(paused)[len(paused) // 2] == 0, paused
        running = bg.count
        time.sleep(0.02)
        assert bg.count > running
    finally:
        bg.close()


def test_the_loop_waiting_on_a_paused_threads_lock_is_freed_within_max_wait() -> None:
    """The loop (here: this thread) closes the gate, then needs a lock the paused thread
    holds: the thread waits once, at most MAX_WAIT, then goes on and lets go of it."""
    gate = LoopGate()
    lock = threading.Lock()
    bg = Background(gate, lock)
    try:
        waits = []
        for _ in range(10):
            time.sleep(0.003)
            gate.close()
            t0 = time.monotonic()
            with lock:
                waits.append(time.monotonic() - t0)
            gate.open()
        # MAX_WAIT, then the rest of its 100 calls (a busy machine may add scheduling delay)
        assert sorted(waits)[len(waits) // 2] < MAX_WAIT + 0.05, waits
        assert max(waits) < 1.0, waits
    finally:
        bg.close()


@pytest.mark.parametrize("closed", [False, True])
def test_a_thread_outside_the_gate_is_not_paused(closed: bool) -> None:
    gate = LoopGate()
    if closed:
        gate.close()
    t0 = time.monotonic()
    for _ in range(10_000):
        _work()
    assert time.monotonic() - t0 < 1.0  # no profile hook on this thread
    assert gate.is_open is not closed
