"""Plain helpers of the joystick tests: loopback transports and a collecting subscriber.

zenoh on loopback only, scouting off, sessions always closed; each test takes its port
from :func:`tests.net.free_port`.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import JoystickMessage, parse
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.transport.session import config_from_spec, open_session

ROBOT = "test_robot"
KEY = f"legws/{ROBOT}/joystick"


def listen_spec(port: int) -> TransportSpec:
    """The daemon side: listen on a loopback port."""
    return TransportSpec(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False)


def dial_spec(port: int) -> TransportSpec:
    """The publisher side: connect to a loopback port, listen on nothing."""
    return TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False)


class Inbox:
    """Joystick messages received by a subscriber (thread-safe), with bounded waits."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.messages: list[JoystickMessage] = []
        self.rejected: list[str] = []

    def offer(self, payload: bytes) -> None:
        try:
            message = parse(JoystickMessage, payload, KEY)
        except InputError as err:
            with self._cond:
                self.rejected.append(str(err))
                self._cond.notify_all()
            return
        with self._cond:
            self.messages.append(message)
            self._cond.notify_all()

    def wait_for(self, count: int, timeout: float = 10.0) -> list[JoystickMessage]:
        """At least ``count`` messages, or AssertionError after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while len(self.messages) < count:
                left = deadline - time.monotonic()
                assert left > 0, f"got {len(self.messages)} of {count} messages in {timeout} s"
                self._cond.wait(left)
            return list(self.messages)

    def wait_until(
        self, done: Callable[[list[JoystickMessage]], bool], timeout: float = 10.0
    ) -> list[JoystickMessage]:
        """The messages once ``done(messages)`` holds, or AssertionError after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not done(self.messages):
                left = deadline - time.monotonic()
                assert left > 0, f"condition not met in {timeout} s: {self.messages[-3:]}"
                self._cond.wait(left)
            return list(self.messages)

    def snapshot(self) -> list[JoystickMessage]:
        with self._cond:
            return list(self.messages)


def status(seq: int, **fields: Any) -> bytes:
    """A valid status of the test robot (teleop, nobody steering), ``fields`` over it."""
    data = {"schema": 1, "robot": ROBOT, "seq": seq, "stamp": time.time(), "mode": "teleop",
            "adapter": "sim", **fields}  # fmt: skip
    return json.dumps(data).encode()


@contextmanager
def daemon_side(
    port: int, key: str = KEY, *, status_fields: dict[str, Any] | None = None
) -> Iterator[Inbox]:
    """A listening session on ``port`` with a subscriber on ``key`` and a status published
    at 10 Hz beside it (every publisher waits for the daemon's status; ``status_fields``
    over :func:`status`, ``None``: no status at all); closed on exit."""
    inbox = Inbox()
    stop = threading.Event()
    with open_session(config_from_spec(listen_spec(port))) as session:

        def on_sample(sample: Any) -> None:
            inbox.offer(sample.payload.to_bytes())

        def publish_status() -> None:
            seq = 0
            while not stop.wait(0.1):
                seq += 1
                session.put(key.rsplit("/", 1)[0] + "/status", status(seq, **status_fields or {}))

        session.declare_subscriber(key, on_sample)
        thread = threading.Thread(target=publish_status, daemon=True)
        if status_fields is not None:
            thread.start()
        try:
            yield inbox
        finally:
            stop.set()
            if thread.is_alive():
                thread.join(2.0)
