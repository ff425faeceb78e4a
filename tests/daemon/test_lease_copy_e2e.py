"""The bench transport (a real arm's profile on the loopback default, ``--insecure-transport``)
with a real daemon and the fake bridge in their own processes, one pair for the module:

- a legws publisher holds the lease; an attacker on the same loopback copies everything it
  can see — the status, the holder's own messages with their ``session`` and ``auth`` — and
  publishes copies with a higher ``seq`` and a large deflection: the arm does not move, the
  holder keeps the lease, the daemon counts each copy (``auth``, ``stale_seq``,
  ``not_operator``), and asking for the holder's key is refused;
- the daemon SIGSTOPped for 2 s: on SIGCONT it reports a ``stall``, does not blame the
  bridge (no ``bridge heartbeat lost``), and the holder steers on; the bridge SIGSTOPped
  for longer than the heartbeat timeout still faults.
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from legws_daemon.formats.bridge_messages import bridge_keys
from legws_daemon.formats.messages import Buttons
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.joystick.publisher import Publisher, Sample
from legws_daemon.transport.session import config_from_spec, keys, open_session
from tests.daemon.procs import Monitor, ee, monitor, ready, start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer"
KEYS = keys(ROBOT)
RATE = 20.0  # the sawyer profile's control rate, Hz
pytestmark = pytest.mark.slow


@dataclass
class Bench:
    port: int
    daemon: subprocess.Popen[bytes]
    bridge: subprocess.Popen[bytes]
    m: Monitor
    log: Path

    def spec(self, *also: int) -> TransportSpec:
        """A session that connects to the daemon (and to the ports ``also``)."""
        ports = [self.port, *also]
        return TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{p}" for p in ports])


def wait_for_bridge(port: int, timeout: float = 30.0) -> None:
    """Until the fake bridge publishes a joint state (it is up)."""
    got = threading.Event()
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    with open_session(config_from_spec(spec)) as s:
        sub = s.declare_subscriber(bridge_keys(ROBOT)["state"], lambda _: got.set())
        try:
            assert got.wait(timeout), "the fake bridge published no state"
        finally:
            sub.undeclare()  # type: ignore[no-untyped-call]


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    tmp = tmp_path_factory.mktemp("bench")
    port, bridge_port = free_port(), free_port()
    profile = write_profile(
        tmp, "sawyer", port, {"connect = []": f'connect = ["tcp/127.0.0.1:{bridge_port}"]'}
    )
    bridge = start(
        ["bridge", "fake", "--profile", str(profile), "--scene", "desk", "--listen",
         f"tcp/127.0.0.1:{bridge_port}"],
        tmp / "bridge.log",
    )  # fmt: skip
    daemon = None
    try:
        wait_for_bridge(bridge_port)
        daemon = start(
            ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120",
             "--allow-motion", "--insecure-transport"],
            tmp / "daemon.log",
        )  # fmt: skip
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp / "daemon.log").read_text()
            yield Bench(port, daemon, bridge, m, tmp / "daemon.log")
    finally:
        for proc in (daemon, bridge):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGCONT)  # (a test that failed while it was stopped)
        if daemon is not None:
            code, _ = stop(daemon)
            assert code == 0, (tmp / "daemon.log").read_text()[-3000:]
        stop(bridge)


class Holder:
    """A legws publisher holding the lease: enable held, the stick where :attr:`axes` says,
    at the control rate, from its own thread."""

    def __init__(self, bench: Bench, *also: int) -> None:
        config = config_from_spec(bench.spec(*also))
        self.pub = Publisher(config, KEYS["joystick"], source="operator")
        self.axes: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self) -> Sample:
        return self.axes, Buttons(enable=True)

    def _run(self) -> None:
        self.pub.run(self._sample, RATE, 60.0, self._stop)

    def __enter__(self) -> Holder:
        self.pub.__enter__()
        assert self.pub.wait_matched(10.0)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.pub.close()

    def me(self) -> dict[str, str]:
        return {"source": "operator", "session": self.pub.session_id}


def operator(m: Monitor) -> dict[str, Any] | None:
    s = m.latest()
    return None if s is None else s["operator"]


def counts(m: Monitor) -> dict[str, int]:
    s = m.latest()
    assert s is not None
    return dict(s["rejections"])


class Attacker:
    """A zenoh session of its own that hears the holder's messages and sends copies."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.heard: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(KEYS["joystick"], self._on_joystick)

    def _on_joystick(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.heard.append(json.loads(sample.payload.to_bytes()))

    def newest(self, session: str | None = None) -> dict[str, Any]:
        """The last message heard (of ``session``: zenoh delivers a session's own puts to
        its own subscribers too, so the attacker hears its copies beside the holder's)."""
        with self._lock:
            return dict(next(h for h in reversed(self.heard) if session in (None, h["session"])))

    def put(self, message: dict[str, Any]) -> None:
        self.session.put(KEYS["joystick"], json.dumps(message).encode(),
                         congestion_control=zenoh.CongestionControl.BLOCK)  # fmt: skip

    def hello(self, session: str) -> dict[str, Any]:
        body = json.dumps({"schema": 1, "command": "hello", "argument": session}).encode()
        for reply in self.session.get(KEYS["command"], payload=body, timeout=10.0):
            raw = reply.ok.payload if reply.ok is not None else reply.err.payload  # type: ignore[union-attr]
            return dict(json.loads(raw.to_bytes()))
        raise AssertionError("no reply to hello")

    def close(self) -> None:
        self._sub.undeclare()  # type: ignore[no-untyped-call]


def test_a_copy_of_the_holders_session_neither_steers_nor_takes_the_lease(bench: Bench) -> None:
    """The attacker sees all the holder sends: the holder's publisher dials it too (a peer
    of the daemon's does not forward another's messages; a router or a capture would)."""
    m = bench.m
    seen_at = free_port()
    spec = TransportSpec(
        listen=[f"tcp/127.0.0.1:{seen_at}"], connect=[f"tcp/127.0.0.1:{bench.port}"]
    )
    with open_session(config_from_spec(spec)) as raw, Holder(bench, seen_at) as holder:
        attacker = Attacker(raw)
        try:
            assert m.wait_for(lambda m: operator(m) == holder.me(), 10), operator(m)
            assert m.wait_for(lambda m: len(attacker.heard) >= 5, 10)
            time.sleep(0.5)
            before, p0, t0 = counts(m), ee(m), time.monotonic()
            seen = attacker.newest()
            assert seen["session"] == holder.pub.wire_session and seen["auth"]
            shown = operator(m)  # what status shows of the holder: its public id only
            assert shown is not None and shown["session"] != seen["session"]
            assert bench.log.read_text().count(seen["session"]) == 0  # nor the log
            # the key of the holder's session: refused (it has one, and holds the lease)
            refused = attacker.hello(seen["session"])
            assert refused["ok"] is False and "key" not in refused
            sent = {"auth": 0, "stale_seq": 0, "not_operator": 0}
            for i in range(40):  # 2 s at the control rate
                h = attacker.newest(seen["session"])
                push = {**h, "seq": h["seq"] + 1000 + i, "axes": [0.0, 0.9, 0.0],
                        "buttons": {"enable": True}}  # fmt: skip
                attacker.put(push)  # its tag, copied: wrong for this content
                attacker.put({k: v for k, v in push.items() if k != "auth"})  # no tag
                sent["auth"] += 2
                attacker.put(h)  # the holder's own message again: seen already
                sent["stale_seq"] += 1
                # the session as status shows it: another session, and the lease is held
                attacker.put({**push, "session": shown["session"], "auth": None})
                sent["not_operator"] += 1
                time.sleep(1.0 / RATE)
            want = {r: before[r] + n for r, n in sent.items()}
            assert m.wait_for(lambda m: all(counts(m)[r] >= n for r, n in want.items()), 10), (
                counts(m), want, [(e["kind"], e["detail"]) for e in m.events
                                  if e["kind"] in ("operator", "stall", "input_rejected")],
            )  # fmt: skip
            time.sleep(0.5)
            p1, t1 = ee(m), time.monotonic()
            moved = float(np.linalg.norm(p1 - p0))
            assert moved < 0.002, moved  # a copy that steered: 0.045 m/s for 2 s, ~9 cm
            after = counts(m)
            assert after["auth"] - before["auth"] == sent["auth"]  # each copy counted once
            assert after["stale_seq"] - before["stale_seq"] == sent["stale_seq"]
            # the holder kept the lease all along
            held = [s["operator"] for t, s in list(m.status) if t0 <= t <= t1]
            assert held and all(h == holder.me() for h in held), held[-3:]
            changes = [e["detail"] for e in m.events if e["kind"] == "operator"]
            assert [c["reason"] for c in changes] == ["first_input"]
            rejected = [e["detail"] for e in m.events if e["kind"] == "input_rejected"]
            assert any(r["reason"] == "auth" and r["session"] == shown["session"]
                       for r in rejected)  # fmt: skip
            # ... and steers on: its own deflection moves the arm
            holder.axes = (0.0, 0.8, 0.0)
            assert m.wait_for(lambda m: ee(m)[1] - p1[1] > 0.01, 10), ee(m) - p1
        finally:
            attacker.close()
    assert m.wait_for(lambda m: operator(m) is None, 5)  # its goodbye
    print(f"attack: EE moved {1000 * moved:.2f} mm; refused {sent}")


def test_a_paused_daemon_reports_a_stall_not_a_silent_bridge(bench: Bench) -> None:
    m = bench.m
    with Holder(bench) as holder:
        assert m.wait_for(lambda m: operator(m) == holder.me(), 10), operator(m)
        assert m.latest()["mode"] == "teleop"  # type: ignore[index]
        events0 = len(m.events)
        bench.daemon.send_signal(signal.SIGSTOP)
        time.sleep(2.0)
        bench.daemon.send_signal(signal.SIGCONT)
        assert m.wait_for(lambda m: "stall" in m.kinds(), 10), m.kinds()[-10:]
        assert m.wait_for(lambda m: operator(m) == holder.me(), 5), operator(m)
        time.sleep(1.0)  # the heartbeat timeout (0.5 s) twice over since the resume
        s = m.latest()
        assert s is not None
        assert s["mode"] == "teleop" and s["fault"] is None, s["fault"]
        news = m.events[events0:]
        assert not [e for e in news if e["kind"] == "fault"], news
        stall = next(e["detail"] for e in news if e["kind"] == "stall")
        assert stall["seconds"] >= 1.5 and stall["threshold"] == 0.5 and stall["stalls"] == 1
        changes = [e["detail"] for e in news if e["kind"] == "operator"]
        # the holder kept the lease through the daemon's pause: nobody could race for it
        assert changes == [], changes
        holder.axes = (0.0, -0.8, 0.0)  # it steers again
        p = ee(m)
        assert m.wait_for(lambda m: p[1] - ee(m)[1] > 0.01, 10), ee(m) - p
        holder.axes = (0.0, 0.0, 0.0)

        # the bridge really silent, for longer than the heartbeat timeout: a fault
        bench.bridge.send_signal(signal.SIGSTOP)
        try:
            assert m.wait_for(lambda m: "fault" in m.kinds()[events0:], 10), m.kinds()[-5:]
        finally:
            bench.bridge.send_signal(signal.SIGCONT)
        fault = next(e["detail"]["error"] for e in m.events[events0:] if e["kind"] == "fault")
        assert "bridge heartbeat lost" in fault, fault
        assert m.kinds().count("stall") == 1  # the daemon ran all along: no stall
    assert "bridge heartbeat lost" not in bench.log.read_text().split("stall seconds=")[0]
