"""The bench transport under floods (the daemon in its own process, zenoh loopback):
16 MiB joystick messages are refused from their size, counted, move nothing, and leave
the daemon's memory flat; a flood of stops stops at once and is announced once a second per
role."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from legws_daemon.formats.bridge_messages import stop_key
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.transport.session import config_from_spec, keys, open_session
from tests.daemon.procs import Monitor, ee, monitor, ready, start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer_sim"
pytestmark = pytest.mark.slow


def rss_mib(pid: int) -> float:
    """The process's resident memory, MiB (Linux: /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def test_huge_payloads_and_a_stop_flood(tmp_path: Path) -> None:
    """One daemon: 16 MiB joystick messages are refused, counted, move nothing and leave
    its memory flat; then a flood of stops stops it at once and is announced once a second
    per role."""
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "90"],
        tmp_path / "daemon.log",
    )
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    try:
        with monitor(port, ROBOT) as m, open_session(config_from_spec(spec)) as pub:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            huge_payloads(m, pub, daemon.pid)
            seconds = stop_flood(m, pub)
    finally:
        code, _ = stop(daemon)
    assert code == 0
    log = (tmp_path / "daemon.log").read_text()
    assert log.count("legws daemon: stop ") <= 2 * (seconds + 1)


def huge_payloads(m: Monitor, pub: zenoh.Session, pid: int) -> None:
    time.sleep(1.0)
    before, p0 = rss_mib(pid), ee(m)
    invalid0 = m.latest()["rejections"]["invalid"]  # type: ignore[index]
    steer = {"schema": 1, "stamp": 0.0, "axes": [0.0, 1.0, 0.0], "source": "big"}
    huge = json.dumps({**steer, "seq": 1, "pad": "x" * (16 << 20)}).encode()
    for _ in range(20):  # 320 MiB in all (blocking: on a busy machine none is dropped)
        pub.put(keys(ROBOT)["joystick"], huge, congestion_control=zenoh.CongestionControl.BLOCK)
        time.sleep(0.05)
    assert m.wait_for(
        lambda m: m.latest()["rejections"]["invalid"] >= invalid0 + 20,  # type: ignore[index]
        30,
    ), (invalid0, m.latest()["rejections"])  # type: ignore[index]
    time.sleep(1.0)
    after = rss_mib(pid)
    np.testing.assert_array_equal(ee(m), p0)  # nothing moved
    assert after - before < 64, (before, after)  # measured: +9.5 MiB


def stop_flood(m: Monitor, pub: zenoh.Session) -> float:
    """~2000 stops of two roles in 3 s; how long the flood took."""
    body = json.dumps({"schema": 1, "source": "flood", "reason": "test"}).encode()
    started = time.monotonic()
    sent = 0
    while time.monotonic() - started < 3.0:
        for role in ("observer", "safety"):
            pub.put(stop_key(ROBOT, role), body)
            sent += 1
        time.sleep(0.003)
    seconds = time.monotonic() - started
    assert m.wait_for(lambda m: m.latest()["mode"] == "stopped", 5)  # type: ignore[index]
    time.sleep(1.5)  # the last announced
    stops = [e["detail"] for e in m.events if e["kind"] == "stop"]
    for role in ("observer", "safety"):
        mine = [d for d in stops if d["by"] == role]
        assert 1 <= len(mine) <= seconds + 1, (role, len(mine))
        assert mine[0]["repeats"] == 0
        assert sum(d["repeats"] for d in mine) + len(mine) <= sent
    assert sum(d["repeats"] for d in stops) > 100  # the flood was carried out, quietly
    return seconds
