"""``legws daemon --assist blend`` as a lab runs it: a foreign zenoh client (the raw
configuration and JSON of docs/messages.md, no legws code) steers; the arm moves toward the
likely goal faster than the stick alone moves it before any commit, and the stick held
against the committed goal hands control back — an ``override`` event, the velocity
changing by at most the documented bound per tick (the daemon's ``--trace``)."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from legws_daemon.autonomy.override import HANDBACK_ACCELERATION
from tests.daemon.procs import start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer_sim"
V_MAX = 0.05
DT = 0.05


class ForeignClient:
    """A plain zenoh peer: status and events in, joystick JSON out (docs/messages.md)."""

    def __init__(self, port: int) -> None:
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"peer"')
        cfg.insert_json5("listen/endpoints", "[]")
        cfg.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("scouting/gossip/enabled", "false")
        self.session = zenoh.open(cfg)
        self.status: dict[str, Any] | None = None
        self.events: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._subs = [
            self.session.declare_subscriber(f"legws/{ROBOT}/status", self._on_status),
            self.session.declare_subscriber(f"legws/{ROBOT}/events", self._on_event),
        ]
        self._pub = self.session.declare_publisher(f"legws/{ROBOT}/joystick")
        self.seq = 0

    def _on_status(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.status = json.loads(sample.payload.to_bytes())

    def _on_event(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.events.append(json.loads(sample.payload.to_bytes()))

    def latest(self) -> dict[str, Any] | None:
        with self._lock:
            return self.status

    def kinds(self) -> list[str]:
        with self._lock:
            return [e["kind"] for e in self.events]

    def event(self, kind: str) -> dict[str, Any]:
        with self._lock:
            return next(e for e in self.events if e["kind"] == kind)

    def stick(self, axes: np.ndarray, confirm: bool = False) -> None:
        self.seq += 1
        msg = {"schema": 1, "seq": self.seq, "stamp": time.time(),
               "axes": [float(a) for a in axes], "source": "foreign", "session": "foreign-1",
               "buttons": {"enable": True, "confirm": confirm}}  # fmt: skip
        self._pub.put(json.dumps(msg).encode())

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()  # type: ignore[no-untyped-call]
        self._pub.undeclare()  # type: ignore[no-untyped-call]
        self.session.close()  # type: ignore[no-untyped-call]


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


@pytest.mark.slow
def test_blend_helps_before_the_commit_and_an_override_hands_back_without_a_jump(
    tmp_path: Path,
) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    trace = tmp_path / "trace.jsonl"
    goal = "white_mug"
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--assist", "blend",
         "--trace", str(trace), "--duration", "150"],
        tmp_path / "daemon.log",
    )  # fmt: skip
    client = ForeignClient(port)
    try:
        deadline = time.monotonic() + 60
        while (s := client.latest()) is None or s["tick"] == 0:
            assert time.monotonic() < deadline, "no status from the daemon"
            time.sleep(0.05)
        assert s["assist"] == "blend"  # status says what help to expect
        # steer toward the mug until the daemon commits (confirm on arrival)
        while (s := client.latest()) is not None and s["mode"] == "teleop":
            assert time.monotonic() < deadline, f"no commit: {s}"
            to = np.array(s["targets"][goal]) - np.array(s["ee"]["position"])
            arrived = float(np.linalg.norm(to)) < 0.01
            client.stick(np.zeros(3) if arrived else _unit(to), confirm=arrived)
            time.sleep(DT)
        commit = client.event("commit")
        assert commit["detail"]["goal"] == goal
        # the approach under way, push the other way until control comes back
        for _ in range(30):
            client.stick(np.zeros(3))
            time.sleep(DT)
        while "override" not in client.kinds():
            assert time.monotonic() < deadline, "no override"
            s = client.latest()
            assert s is not None
            away = -(np.array(s["targets"][goal]) - np.array(s["ee"]["position"]))
            client.stick(0.9 * _unit(away))
            time.sleep(DT)
        for _ in range(20):  # keep pushing: the hand-back
            client.stick(0.9 * _unit(away))
            time.sleep(DT)
        override = client.event("override")
        assert override["detail"]["goal"] == goal and override["detail"]["during"] == "assist"
    finally:
        client.close()
        code, _ = stop(daemon)
    assert code == 0
    rows = [json.loads(line) for line in trace.read_text().splitlines()]
    speeds = [float(np.linalg.norm(r["command"])) for r in rows]
    modes = [r["mode"] for r in rows]
    first_assist = modes.index("assist")
    # before any commit the arm moved faster than the stick alone can move it
    assert max(speeds[:first_assist]) > 1.3 * V_MAX
    # the hand-back: from the last assisted tick, no step above the bound
    back = next(i for i in range(first_assist, len(modes)) if modes[i] == "teleop")
    steps = [
        float(np.linalg.norm(np.subtract(rows[i + 1]["command"], rows[i]["command"])))
        for i in range(back - 1, min(back + 20, len(rows) - 1))
    ]  # fmt: skip
    assert speeds[back - 1] > 0.0  # it was moving when control came back
    assert max(steps) <= HANDBACK_ACCELERATION * DT + 1e-6
