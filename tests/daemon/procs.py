"""Real processes for end-to-end tests: the daemon, publishers, a monitor session.

Everything runs on loopback with explicit endpoints and multicast scouting off; every
process is bounded in time and every session is closed.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from legws_daemon.formats.profile import TransportSpec
from legws_daemon.telemetry.rrd_file import rerun_cli
from legws_daemon.transport.session import config_from_spec, keys, open_session

REPO = Path(__file__).parents[2]
LEGWS = [sys.executable, "-m", "legws_daemon"]


def write_profile(tmp: Path, base: str, port: int, replace: dict[str, str] | None = None) -> Path:
    """A copy of ``hw_profiles/<base>.toml`` listening on ``port`` (and other text edits)."""
    text = (REPO / "hw_profiles" / f"{base}.toml").read_text()
    text = text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
    for old, new in (replace or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    path = tmp / f"{base}-{port}.toml"
    path.write_text(text)
    return path


def env() -> dict[str, str]:
    e = dict(os.environ)
    e["CI"] = "true"  # no Rerun analytics
    e["PYTHONUNBUFFERED"] = "1"
    return e


def start(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    out = log.open("wb")
    return subprocess.Popen([*LEGWS, *args], stdout=out, stderr=subprocess.STDOUT, env=env())


def stop(proc: subprocess.Popen[bytes], timeout: float = 10.0) -> tuple[int, float]:
    """SIGTERM and wait; returns the exit code and how long the exit took."""
    t0 = time.monotonic()
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        code = proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
        raise
    return code, time.monotonic() - t0


class Monitor:
    """A loopback session that records a robot's status and events and sends commands."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.session = session
        self.keys = keys(robot)
        self.status: list[tuple[float, dict[str, Any]]] = []
        self.events: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._subs = [
            session.declare_subscriber(self.keys["status"], self._on_status),
            session.declare_subscriber(self.keys["events"], self._on_event),
        ]

    def _on_status(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.status.append((time.monotonic(), json.loads(sample.payload.to_bytes())))

    def _on_event(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.events.append(json.loads(sample.payload.to_bytes()))

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()  # type: ignore[no-untyped-call]

    def latest(self) -> dict[str, Any] | None:
        with self._lock:
            return self.status[-1][1] if self.status else None

    def kinds(self) -> list[str]:
        with self._lock:
            return [e["kind"] for e in self.events]

    def wait_for(self, what: Callable[[Monitor], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if what(self):
                return True
            time.sleep(0.05)
        return what(self)

    def command(
        self, command: str, argument: str | None = None, plan: str | None = None
    ) -> tuple[bool, dict[str, Any]]:
        body: dict[str, Any] = {"schema": 1, "command": command}
        if argument is not None:
            body["argument"] = argument
        if plan is not None:
            body["plan"] = plan
        for reply in self.session.get(
            self.keys["command"], payload=json.dumps(body).encode(), timeout=10.0
        ):
            if reply.ok is not None:
                return True, json.loads(reply.ok.payload.to_bytes())
            assert reply.err is not None
            return False, json.loads(reply.err.payload.to_bytes())
        raise AssertionError("no reply to the command")


@contextmanager
def monitor(port: int, robot: str) -> Iterator[Monitor]:
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    with open_session(config_from_spec(spec)) as session:
        m = Monitor(session, robot)
        try:
            yield m
        finally:
            m.close()


def rerun_exe() -> str:
    """The ``rerun`` executable the daemon itself uses (``rerun rrd verify`` runs headless)."""
    return rerun_cli()


def ready(m: Monitor) -> bool:
    """The daemon's loop has ticked (a status with ``tick > 0`` arrived)."""
    s = m.latest()
    return s is not None and s["tick"] > 0


def ee(m: Monitor) -> np.ndarray:
    """The EE position in the latest status."""
    s = m.latest()
    assert s is not None
    return np.array(s["ee"]["position"])
