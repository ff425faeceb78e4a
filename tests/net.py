"""Loopback ports for the tests, chosen at run time.

No test hard-codes a port: every zenoh endpoint, router and benchmark a test starts listens
on a port the kernel reports free just before, on 127.0.0.1 only. So two checkouts can
run the suite side by side, and pytest-xdist workers can run it in parallel.
"""

from __future__ import annotations

import socket
import threading

_lock = threading.Lock()
_given: set[int] = set()


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now, never the same twice per process.

    The kernel picks it (a bind to port 0); the socket is closed before the caller binds,
    so the caller should use it at once. Linux draws ``bind(0)`` ports at random from the
    ephemeral range, preferring other ports than those of outgoing connections, which
    makes a clash with another process unlikely.
    """
    with _lock:
        while True:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
                s.bind(("127.0.0.1", 0))
                port: int = s.getsockname()[1]
            if port not in _given:
                _given.add(port)
                return port


def free_port_pair() -> int:
    """A port whose next one is free too (the Rerun web viewer's page and stream)."""
    while True:
        port = free_port()
        if port >= 65535:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
        with _lock:
            _given.add(port + 1)
        return port
