"""Shared pieces of the hardware tests: a pair of loopback zenoh peers, bounded polling,
a log of the bridge's state stream."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import zenoh

from legws_daemon.errors import InputError
from legws_daemon.formats.bridge_messages import BridgeState, bridge_contract, bridge_keys
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.hardware.fake_bridge import FakeBridge
from legws_daemon.transport.session import config_from_spec, open_session
from tests.net import free_port

_STATE_KEY = bridge_keys("sawyer")["state"]


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


class Held:
    """A monotonic clock the test sets."""

    def __init__(self) -> None:
        self.now = 50.0

    def __call__(self) -> float:
        return self.now


@contextmanager
def ticking(fake: FakeBridge, period: float = 0.005) -> Iterator[None]:
    """A started fake bridge on a held clock (``start(thread=False)``) ticked every
    ``period`` of real time: its state keeps coming (the adapter's heartbeat), and it moves
    only as far as the test moves the clock."""
    fake.start(thread=False)
    done = threading.Event()

    def run() -> None:
        while not done.wait(period):
            fake.tick()

    thread = threading.Thread(target=run, name="ticker", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(2.0)


def wait_for(condition: Callable[[], bool], timeout: float = 3.0) -> bool:
    """Poll ``condition`` every 10 ms for at most ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


class StateLog:
    """Every state message received on the daemon side, validated."""

    def __init__(self, session: zenoh.Session) -> None:
        self.states: list[BridgeState] = []
        self.errors: list[str] = []
        self._lock = threading.Lock()
        self.subscriber = session.declare_subscriber(_STATE_KEY, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            state = bridge_contract("sawyer").parse_state(sample.payload.to_bytes(), _STATE_KEY)
        except InputError as err:
            with self._lock:
                self.errors.append(str(err))
            return
        with self._lock:
            self.states.append(state)

    def count(self) -> int:
        with self._lock:
            return len(self.states)

    def last(self) -> BridgeState:
        with self._lock:
            return self.states[-1]

    def limited(self) -> set[str]:
        """Every limit any state reported."""
        with self._lock:
            return {limit for state in self.states for limit in state.limited}
