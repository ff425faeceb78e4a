"""Loopback ports for the tests, chosen at run time.

No test hard-codes a port: every zenoh endpoint, router and benchmark a test starts listens
on a port the kernel reports free just before, on 127.0.0.1 only. So two checkouts can
run the suite side by side, and pytest-xdist workers can run it in parallel.
"""

from __future__ import annotations

import os
import random
import socket
import threading

#: The ports the tests take: below Linux's ephemeral range (32768-60999 by default), from
#: which the kernel draws the source ports of outgoing connections and the ports of
#: ``bind(0)``, so no connection of any process takes one of them.
PORTS = range(20000, 32000)

_lock = threading.Lock()
_given: set[int] = set()


def worker_ports() -> range:
    """This pytest-xdist worker's share of :data:`PORTS` (all of them outside xdist): two
    workers never pick the same port. (``bind(0)`` in each worker once did: one worker's
    daemon, unable to listen on a port the other's had taken a moment before, left the
    test's client connected to the other's session — a gripper command from one test
    reached another test's fake bridge.)"""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    index = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    width = len(PORTS) // max(count, 1)
    start = PORTS.start + (index % max(count, 1)) * width
    return range(start, start + width)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now, never the same twice per process
    and never another worker's (:func:`worker_ports`).

    The socket that checks it is closed before the caller binds, so the caller should use
    it at once; the share is walked from a random place (another checkout running the
    suite side by side starts elsewhere), skipping what is taken.
    """
    ports = worker_ports()
    with _lock:
        offset = random.randrange(len(ports))
        for i in range(len(ports)):
            port = ports[(offset + i) % len(ports)]
            if port in _given:
                continue
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    continue
            _given.add(port)
            return port
    raise RuntimeError(f"no free loopback port in {ports.start}-{ports.stop - 1}")


def free_port_pair() -> int:
    """A port whose next one is free too (the Rerun web viewer's page and stream)."""
    while True:
        port = free_port()
        if port + 1 not in worker_ports():
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
        with _lock:
            _given.add(port + 1)
        return port
