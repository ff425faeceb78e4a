"""One operator at a time, seen from outside: the daemon in its own process, publishers that
are plain zenoh clients writing the JSON of docs/messages.md (no legws code on their side,
but for the ``take_control`` of legws' own publisher).

- two publishers steer toward different goals: the daemon follows the first, commits to its
  goal, status names it as the operator, the second is counted ``not_operator`` and
  reported in an ``input_rejected`` event;
- the operator's publisher restarts (goodbye, a new session): the first tick after the new
  session's first message uses it;
- a replayed message of the operator's session moves nothing.
"""

from __future__ import annotations

import json
import secrets
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from legws_daemon.formats.messages import public_session_id as public
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.joystick.publisher import Publisher
from legws_daemon.transport.session import config_from_spec
from tests.daemon.procs import LEGWS, Monitor, monitor, ready, start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer_sim"
KEY = f"legws/{ROBOT}/joystick"
PERIOD = 0.05  # the sim profile's control period, s
pytestmark = pytest.mark.slow


@contextmanager
def raw_session(port: int) -> Iterator[zenoh.Session]:
    """A zenoh client of our own: loopback peer, no scouting, no listening."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", "[]")
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    session = zenoh.open(config)
    try:
        yield session
    finally:
        session.close()  # type: ignore[no-untyped-call]


class Operator:
    """A publisher session steering toward a target at ``rate`` Hz from its own thread."""

    def __init__(self, session: zenoh.Session, name: str, rate: float) -> None:
        self.session, self.name, self.rate = session, name, rate
        self.id = secrets.token_hex(8)
        self.seq = 0
        self.sent: list[dict[str, Any]] = []
        self.first_sent: float | None = None  # monotonic
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def put(self, axes: list[float], **extra: Any) -> None:
        msg = {"schema": 1, "seq": self.seq, "stamp": time.time(), "axes": axes,
               "source": self.name, "session": self.id, **extra}  # fmt: skip
        if self.first_sent is None:
            self.first_sent = time.monotonic()
        self.session.put(KEY, json.dumps(msg).encode())
        self.sent.append(msg)
        self.seq += 1

    def steer(self, toward: Callable[[], list[float]]) -> Operator:
        def loop() -> None:
            while not self._stop.is_set():
                self.put(toward())
                self._stop.wait(1.0 / self.rate)

        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()
        return self

    def goodbye(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.put([0.0, 0.0, 0.0], buttons={"enable": False}, bye=True)


def toward(m: Monitor, target: np.ndarray, speed: float = 0.8) -> Callable[[], list[float]]:
    def axes() -> list[float]:
        s = m.latest()
        assert s is not None
        if s["mode"] != "teleop":
            return [0.0, 0.0, 0.0]  # the arm completes the motion: hold still (enabled)
        d = target - np.array(s["ee"]["position"])
        n = float(np.linalg.norm(d))
        return [0.0, 0.0, 0.0] if n < 1e-3 else (speed * d / max(n, 1e-9)).tolist()

    return axes


def trace_rows(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def test_two_publishers_the_daemon_follows_the_first_and_a_restart_steers_at_once(
    tmp_path: Path,
) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    trace = tmp_path / "trace.jsonl"
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120",
         "--trace", str(trace)],
        tmp_path / "daemon.log",
    )  # fmt: skip
    try:
        with monitor(port, ROBOT) as m, raw_session(port) as one, raw_session(port) as two:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            s0 = m.latest()
            assert s0 is not None and s0["operator"] is None
            targets = {k: np.array(v) for k, v in s0["targets"].items()}
            mine = "white_mug"
            other = max(targets, key=lambda g: float(np.linalg.norm(targets[g] - targets[mine])))
            assert other != mine

            first = Operator(one, "operator-pad", 20.0).steer(toward(m, targets[mine]))
            assert m.wait_for(lambda m: (m.latest() or {}).get("operator") is not None, 5)
            intruder = Operator(two, "intruder", 100.0).steer(toward(m, targets[other], 1.0))
            time.sleep(2.0)
            s1 = m.latest()
            assert s1 is not None
            assert s1["operator"] == {"source": "operator-pad", "session": public(first.id)}
            assert s1["rejections"]["not_operator"] > 0  # every one counted, none steered
            assert s1["mode"] == "teleop"
            intruder.goodbye()

            # the operator's publisher restarts: goodbye, then a new session at once
            first.goodbye()
            restarted = Operator(one, "operator-pad", 20.0).steer(toward(m, targets[mine]))
            assert m.wait_for(lambda m: "commit" in m.kinds(), 60), (m.kinds(), m.latest())
            commit = next(e["detail"] for e in m.events if e["kind"] == "commit")
            assert commit["goal"] == mine and not commit["confirmed"]
            assert 0.0 < commit["seconds"] < 60.0
            at_commit = m.latest()
            assert at_commit is not None
            assert at_commit["operator"] == {
                "source": "operator-pad", "session": public(restarted.id)
            }  # fmt: skip
            assert m.wait_for(lambda m: "stage_done" in m.kinds(), 60)
            restarted.goodbye()
            assert m.wait_for(lambda m: (m.latest() or {}).get("operator") is None, 5)

            # a replay of the operator's last steering message (same session, old seq)
            replay = dict(restarted.sent[-2])
            one.put(KEY, json.dumps(replay).encode())
            assert m.wait_for(lambda m: (m.latest() or {})["rejections"]["stale_seq"] >= 1, 5)
            events = list(m.events)
    finally:
        code, _ = stop(daemon)
    assert code == 0

    changes = [(e["detail"]["operator"], e["detail"]["reason"]) for e in events
               if e["kind"] == "operator"]  # fmt: skip
    expect = [public(first.id), None, public(restarted.id), None]
    assert [(c or {}).get("session") for c, _ in changes] == expect
    assert [r for _, r in changes] == ["first_input", "goodbye", "first_input", "goodbye"]
    rejected = [e["detail"] for e in events if e["kind"] == "input_rejected"]
    assert any(
        r["reason"] == "not_operator" and r["session"] == public(intruder.id) for r in rejected
    )
    assert any(
        r["reason"] == "stale_seq" and r["session"] == public(restarted.id) for r in rejected
    )
    assert [e["detail"]["on"] for e in events if e["kind"] == "deadman"][:1] == [False]

    # the first tick that began after the restarted session's first message used it
    rows = trace_rows(trace)
    assert restarted.first_sent is not None
    after = [
        i for i, r in enumerate(rows) if r["received"] and r["received"] >= restarted.first_sent
    ]
    i = after[0]
    assert rows[i]["seq"] == 0  # the new session's first message, nothing lost
    assert rows[i - 1]["begin"] < rows[i]["received"] <= rows[i]["begin"]
    assert rows[i]["begin"] - rows[i]["received"] <= PERIOD + 0.02


def test_take_control_and_release_move_the_lease_and_a_killed_publisher_loses_it(
    tmp_path: Path,
) -> None:

    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "90"],
        tmp_path / "daemon.log",
    )
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    try:
        with monitor(port, ROBOT) as m, raw_session(port) as one:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()

            def operator() -> dict[str, Any] | None:
                s = m.latest()
                return None if s is None else s["operator"]

            holder = Operator(one, "first", 20.0).steer(lambda: [0.0, 0.3, 0.0])
            assert m.wait_for(lambda m: operator() is not None, 5)
            with Publisher(config_from_spec(spec), KEY, source="second") as pub:
                reply = pub.take_control()
                assert reply["ok"] and reply["operator"]["session"] == pub.session_id
                assert m.wait_for(lambda m: (operator() or {}).get("session") == pub.session_id, 5)
                n = m.latest()["rejections"]["not_operator"]  # type: ignore[index]
                for _ in range(10):
                    pub.publish((0.0, -0.3, 0.0))
                    time.sleep(0.05)
                assert m.latest()["deadman"] is False  # type: ignore[index]
                assert m.latest()["rejections"]["not_operator"] > n  # type: ignore[index]
                ok, reply = m.command("release")
                assert ok and reply["operator"] is None
                # the first session steers on: with the lease free it takes it back
                assert m.wait_for(
                    lambda m: (operator() or {}).get("session") == public(holder.id), 5
                )
            # "killed": the holder stops without a goodbye; the lease ends after 0.75 s
            holder._stop.set()
            t0 = time.monotonic()
            assert m.wait_for(lambda m: operator() is None, 5)
            assert time.monotonic() - t0 >= 0.5

            # the command line: a publisher started with --take-control while another steers
            other = Operator(one, "other", 20.0).steer(lambda: [0.0, 0.3, 0.0])
            assert m.wait_for(lambda m: (operator() or {}).get("session") == public(other.id), 5)
            recording = tmp_path / "rec.jsonl"
            lines = [
                {"schema": 1, "seq": i, "stamp": 0.05 * i, "axes": [0.0, -0.2, 0.0]}
                for i in range(20)
            ]
            recording.write_text("".join(json.dumps(x) + "\n" for x in lines))
            replay = subprocess.run(
                [*LEGWS, "joystick", "replay", str(recording), "--profile", str(profile),
                 "--take-control"],
                capture_output=True, text=True, timeout=60, check=False,
            )  # fmt: skip
            assert replay.returncode == 0, replay.stderr
            other.goodbye()
            events, statuses = list(m.events), list(m.status)
    finally:
        code, _ = stop(daemon)
    assert code == 0
    reasons = [e["detail"]["reason"] for e in events if e["kind"] == "operator"]
    assert reasons[:5] == ["first_input", "take_control", "release", "first_input", "timeout"]
    assert reasons[5:7] == ["first_input", "take_control"]
    taken = [e["detail"] for e in events if e["kind"] == "operator"][6]
    assert taken["operator"]["source"] == "(not heard yet)"  # asked for before it published
    assert taken["previous"]["session"] == public(other.id)
    holders = [s["operator"] for _, s in statuses if s["operator"]]
    replayer = next(h for h in holders if h["source"].startswith("replay:"))
    assert replayer["session"] == taken["operator"]["session"]
