"""Shared pieces of the hardware tests: a pair of loopback zenoh peers, bounded polling."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import zenoh

from legws_daemon.formats.profile import TransportSpec
from legws_daemon.transport.session import config_from_spec, open_session
from tests.net import free_port


@contextmanager
def peers() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """(daemon side listening on a free loopback port, robot side connecting to it), both
    closed after."""
    port = free_port()
    listen = TransportSpec(listen=[f"tcp/127.0.0.1:{port}"])
    dial = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    with (
        open_session(config_from_spec(listen)) as daemon,
        open_session(config_from_spec(dial)) as robot,
    ):
        yield daemon, robot


def wait_for(condition: Callable[[], bool], timeout: float = 3.0) -> bool:
    """Poll ``condition`` every 10 ms for at most ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()
