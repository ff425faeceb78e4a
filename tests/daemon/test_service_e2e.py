"""End to end: the daemon and its publishers as real processes on loopback zenoh.

Each test starts ``legws daemon`` (the MuJoCo stand-in, paced to real time) on its own
loopback port (chosen free at run time), watches its status and events from a monitor
session, and stops it with SIGTERM. Recordings are real ``.rrd`` files read back and
verified with ``rerun rrd verify``.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.formats.profile import TransportSpec
from legws_daemon.telemetry.recording import entity_paths, read_text_log
from legws_daemon.transport.session import config_from_spec, keys, open_session
from tests.daemon.procs import (
    LEGWS,
    monitor,
    ready,
    rerun_exe,
    start,
    stop,
    write_profile,
)
from tests.net import free_port

ROBOT = "sawyer_sim"
pytestmark = pytest.mark.slow


def _of_the_load(event: dict[str, Any]) -> bool:
    """A warning of the machine's load, not of the task: the loop overran its period, or
    the telemetry worker fell behind (a busy CI machine may cause either at any time)."""
    detail = event.get("detail") or {}
    return event["kind"] == "warning" and ("overrun_ms" in detail or "telemetry" in detail)


def test_sim_user_commits_the_right_goal_and_the_recording_holds_it(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    rrd = tmp_path / "session.rrd"
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--rerun", f"save:{rrd}",
         "--duration", "90"],
        tmp_path / "daemon.log",
    )  # fmt: skip
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            user = subprocess.run(
                [*LEGWS, "joystick", "sim-user", "--profile", str(profile), "--goal",
                 "white_mug", "--seed", "3", "--duration", "60"],
                capture_output=True, text=True, timeout=90, check=False,
            )  # fmt: skip
            assert user.returncode == 0, user.stderr
            assert "teleop -> assist -> idle" in user.stderr
            assert m.wait_for(lambda m: "stage_done" in m.kinds(), 10)
            commits = [e for e in m.events if e["kind"] == "commit"]
            assert len(commits) == 1
            assert commits[0]["detail"]["goal"] == "white_mug"
            assert commits[0]["detail"]["p"] >= 0.9 or commits[0]["detail"]["confirmed"]
            # status throughout, in order, in every mode the pick went through, each with
            # the loop's tick (no rate asserted: the machine's load is not the daemon's)
            statuses = [s for _, s in m.status]
            seqs = [s["seq"] for s in statuses]
            assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
            assert {"teleop", "assist", "idle"} <= {s["mode"] for s in statuses}
            ticks = [s["tick"] for s in statuses]
            assert ticks == sorted(ticks) and ticks[-1] > ticks[0]
            last = m.latest()
            assert last is not None
            assert last["mode"] == "idle"
            assert last["stage"] == "done"
            assert last["gripper_closed"] is True  # the mug is in the gripper, at home
            teleop = [s for _, s in m.status if s["mode"] == "teleop"]
            assert set(teleop[-1]["posterior"]) == {"white_mug", "black_stapler", "maroon_pen_cup"}
            assert set(teleop[-1]["targets"]) == set(teleop[-1]["posterior"])
            assert teleop[-1]["certificate"] is not None
            assert next(s["committed"] for _, s in m.status if s["mode"] == "assist") == "white_mug"
            # a phase only while assisting
            assert all(s["phase"] is None for _, s in m.status if s["mode"] != "assist")
            assert {s["phase"] for _, s in m.status if s["mode"] == "assist"} >= {"grasp", "home"}
            # the stage's own ticks: from its decision's start (the daemon's first tick, here)
            # to the end of its action -- the status ticks at 20 Hz before the daemon was
            # steered are not the stage's
            done = next(e["detail"] for e in m.events if e["kind"] == "stage_done")
            commit_status = next(s for _, s in m.status if s["mode"] == "assist")
            assert 0 < done["ticks"] <= last["tick"]
            assert done["ticks"] > last["tick"] - commit_status["tick"]
            input_kinds = ("operator", "deadman", "input_rejected")
            task_events = [
                e for e in m.events if e["kind"] not in input_kinds and not _of_the_load(e)
            ]
            assert [e["kind"] for e in task_events][-2:] == ["stage_done", "task_done"], [
                (e["kind"], e["detail"]) for e in task_events[-4:]
            ]
            claim = next(e["detail"] for e in m.events if e["kind"] == "operator")
            assert claim["reason"] == "first_input"
            assert claim["operator"]["source"].startswith("sim-user:")
            ok, reply = m.command("status")
            assert ok
            assert reply["robot"] == ROBOT
            ok, reply = m.command("load_taskgraph", "x")
            assert not ok
    finally:
        code, _ = stop(daemon)
    assert code == 0
    verify = subprocess.run(
        [rerun_exe(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60
    )
    assert verify.returncode == 0, verify.stderr
    paths = entity_paths(rrd)
    for p in ("/world/ee", "/world/objects/white_mug", "/plots/posterior/white_mug", "/log"):
        assert p in paths or p.lstrip("/") in paths, sorted(paths)[:40]
    log = [text for _, _, text in read_text_log(rrd)]
    assert any(t.startswith("commit goal=white_mug") for t in log)
    assert any(t.startswith("operator sim-user:") and "first_input" in t for t in log)
    assert any(t.startswith("deadman on=False") for t in log)


def test_deadman_malformed_input_and_commands(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "90"],
        tmp_path / "daemon.log",
    )
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    key = keys(ROBOT)["joystick"]
    try:
        with monitor(port, ROBOT) as m, open_session(config_from_spec(spec)) as pub:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()

            def ee() -> np.ndarray:
                s = m.latest()
                assert s is not None
                return np.array(s["ee"]["position"])

            def push(payload: bytes, seconds: float) -> None:
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    pub.put(key, payload)
                    time.sleep(0.02)

            p0 = ee()
            good = {"schema": 1, "stamp": 0.0, "axes": [0.0, 0.8, 0.0], "source": "t"}
            end = time.monotonic() + 1.0
            seq = 0
            while time.monotonic() < end:
                seq += 1
                pub.put(key, json.dumps({**good, "seq": seq}).encode())
                time.sleep(0.02)
            time.sleep(0.4)  # deadman (0.25 s) plus a status period
            p1 = ee()
            assert p1[1] - p0[1] > 0.02  # it moved while the stick was held
            assert m.latest()["deadman"] is True  # type: ignore[index]
            time.sleep(0.5)
            np.testing.assert_array_equal(ee(), p1)  # and stopped when input stopped
            rejected0 = m.latest()["rejected"]  # type: ignore[index]
            bad = [
                b"\x00\xff garbage",
                json.dumps({**good, "seq": 10**6, "axes": ["a", 0, 0]}).encode(),
                b'{"schema": 1, "seq": 1000001, "stamp": 0, "axes": [NaN, 0, 0]}',
                b'{"schema": 1, "seq": 1000002, "stamp": 0, "axes": [Infinity, 0, 0]}',
                json.dumps({**good, "seq": 10**6 + 3, "axes": [1e300, 0, 0]}).encode(),
                json.dumps({**good, "seq": 10**6 + 4, "schema": 7}).encode(),
                b"[" * 5000,
            ]
            for payload in bad:
                push(payload, 0.1)
            time.sleep(0.3)
            np.testing.assert_array_equal(ee(), p1)  # nothing moved
            assert m.latest()["rejected"] - rejected0 >= 2 * len(bad)  # type: ignore[index]
            assert m.latest()["deadman"] is True  # type: ignore[index]

            # a tracker reports the mug next to the stapler: the daemon names the object to move
            stapler = {"x": 0.70, "y": -0.05, "yaw": 0.0}
            objects = {"schema": 1, "seq": 1, "stamp": 0.0, "objects": {"white_mug": stapler}}
            pub.put(keys(ROBOT)["objects"], json.dumps(objects).encode())
            pub.put(keys(ROBOT)["objects"], b"not json")  # rejected, ignored
            assert m.wait_for(
                lambda m: any(e["detail"].get("move") == "white_mug" for e in m.events), 5
            )

            ok, reply = m.command("stop")
            assert ok
            assert reply["mode"] == "stopped"
            push(json.dumps({**good, "seq": 2 * 10**6}).encode(), 0.5)
            np.testing.assert_array_equal(ee(), p1)  # stopped: the stick does nothing
            time.sleep(1.0)  # past the deadman timeout and the lease's grace
            ok, reply = m.command("reset")
            assert ok
            assert reply["plan"][-1] == "home"
            # the way home waits for an operator, and the reply says so
            assert reply["waiting"].startswith("the operator: nobody holds the lease")
            ok, reply = m.command("load_scene", "../../etc/passwd")
            assert not ok
            assert "catalog" in reply["error"]
            assert "stop" in m.kinds()
    finally:
        code, seconds = stop(daemon)
    assert code == 0
    assert seconds < 5.0  # measured ~0.1-0.3 s; see docs/benchmarks.md


def test_cancel_button_gives_control_back_and_the_user_recommits(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120"],
        tmp_path / "daemon.log",
    )
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            user = subprocess.run(
                [*LEGWS, "joystick", "sim-user", "--profile", str(profile), "--goal",
                 "maroon_pen_cup", "--seed", "1", "--cancel-after", "0.5", "--duration", "90"],
                capture_output=True, text=True, timeout=120, check=False,
            )  # fmt: skip
            assert user.returncode == 0, user.stderr
            assert m.wait_for(lambda m: "stage_done" in m.kinds(), 10)
            kinds = [k for k in m.kinds() if k in ("commit", "cancel", "stage_done")]
            assert kinds == ["commit", "cancel", "commit", "stage_done"]
            cancel = next(e for e in m.events if e["kind"] == "cancel")
            assert cancel["detail"]["reason"] == "button"
    finally:
        code, _ = stop(daemon)
    assert code == 0


@pytest.mark.parametrize(("base", "adapter"), [("sawyer", "sawyer"), ("panda", "bridge")])
def test_a_bridge_profile_through_the_fake_bridge_and_a_lost_heartbeat(
    tmp_path: Path, base: str, adapter: str
) -> None:
    """The real arm's profile (the Sawyer's; a Franka Panda's: ``adapter = "bridge"``, the
    Panda's joint vectors on the wire) driven through the fake bridge of the same arm."""
    port, bridge_port = free_port(), free_port()
    profile = write_profile(
        tmp_path, base, port, {"connect = []": f'connect = ["tcp/127.0.0.1:{bridge_port}"]'}
    )
    bridge = start(
        ["bridge", "fake", "--profile", str(profile), "--scene", "desk", "--listen",
         f"tcp/127.0.0.1:{bridge_port}"],
        tmp_path / "bridge.log",
    )  # fmt: skip
    daemon = None
    try:
        time.sleep(1.0)
        daemon = start(
            ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "90",
             "--allow-motion", "--insecure-transport"],
            tmp_path / "daemon.log",
        )  # fmt: skip
        spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
        key = keys(base)["joystick"]
        with monitor(port, base) as m, open_session(config_from_spec(spec)) as pub:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            s0 = m.latest()
            assert s0 is not None
            assert s0["adapter"] == adapter
            assert s0["fallback"] is False
            # a real arm on the loopback default: said in every status and as an event
            assert (s0["transport"], s0["insecure_transport"]) == ("unauthenticated", True)
            p0 = np.array(s0["ee"]["position"])
            for seq in range(50):
                msg = {"schema": 1, "seq": seq, "stamp": 0.0, "axes": [0.0, 0.0, -0.8]}
                pub.put(key, json.dumps(msg).encode())
                time.sleep(0.02)
            time.sleep(0.4)
            p1 = np.array(m.latest()["ee"]["position"])  # type: ignore[index]
            assert p0[2] - p1[2] > 0.02  # moved down through joint velocities on the bridge
            assert np.linalg.norm((p1 - p0)[:2]) < 0.01
            code, _ = stop(bridge)  # the heartbeat stops
            assert code == 0
            assert m.wait_for(lambda m: "fault" in m.kinds(), 5)
            n = len(m.status)
            time.sleep(0.6)
            assert len(m.status) - n >= 4  # status keeps publishing in the fault
            assert m.latest()["mode"] == "fault"  # type: ignore[index]
            assert "heartbeat" in m.latest()["fault"] or "state" in m.latest()["fault"]  # type: ignore[index]
            ok, reply = m.command("reset")
            assert not ok  # the robot is still gone: no reset
            assert "still failing" in reply["error"]
    finally:
        if daemon is not None:
            code, _ = stop(daemon)
            assert code == 0
        stop(bridge)
    assert "INSECURE TRANSPORT: endpoint tcp/127.0.0.1:" in (tmp_path / "daemon.log").read_text()


def test_silent_bridge_falls_back_to_the_stand_in_when_the_profile_asks(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(
        tmp_path,
        "sawyer",
        port,
        {"fallback_to_sim = false": "fallback_to_sim = true", "bridge_timeout = 3.0":
         "bridge_timeout = 1.0"},
    )  # fmt: skip
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "60",
         "--allow-motion", "--insecure-transport"],
        tmp_path / "daemon.log",
    )  # fmt: skip
    try:
        with monitor(port, "sawyer") as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            s = m.latest()
            assert s is not None
            assert s["fallback"] is True
            assert s["adapter"] == "sim"
            ok, reply = m.command("status")
            assert ok
            assert reply["fallback"] is True
    finally:
        code, _ = stop(daemon)
    assert code == 0
    log = (tmp_path / "daemon.log").read_text()
    assert "falling back" in log or "fallback" in log
