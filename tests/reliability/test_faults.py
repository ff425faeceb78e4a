"""Faults (issue 7 §3) and recordings on every exit path (§6), with real processes.

Each test runs ``legws daemon`` (or, to inject a broken adapter, the daemon's service in
this process) on its own loopback port (chosen free at run time), watches status and
events from a monitor session, and injects one fault: a joystick publisher SIGKILLed
mid-motion and restarted, the robot bridge SIGKILLed and restarted, the zenoh router
restarted, an adapter raising, SIGINT during assistance, a recording path that cannot
be written or a disk that fills up. Waits are bounded; every process is stopped and every
session closed.

The daemon's ``--trace`` (one line per tick: when it began, the newest sample's receive
time, the command sent) is what the stop deadlines are checked on; both processes read
the same ``CLOCK_MONOTONIC``.
"""

from __future__ import annotations

import contextlib
import functools
import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.inputs import OperatorInput, TickRecord
from legws_daemon.core.params import Params
from legws_daemon.daemon import service as service_module
from legws_daemon.daemon.service import DaemonConfig, DaemonService
from legws_daemon.daemon.telemetry_worker import QUEUE_SIZE, TelemetryWorker
from legws_daemon.formats.profile import TransportSpec, load_profile
from legws_daemon.hardware.base import RobotState
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.scene.catalog import load_scene
from legws_daemon.telemetry.recording import read_text_log
from legws_daemon.telemetry.rerun_log import RerunLog
from legws_daemon.transport.session import config_from_spec, keys, open_session
from tests.daemon.procs import (
    LEGWS,
    REPO,
    Monitor,
    ee,
    env,
    monitor,
    ready,
    rerun_exe,
    start,
    stop,
    write_profile,
)
from tests.net import free_port

pytestmark = pytest.mark.slow

ROBOT = "sawyer_sim"
DEADMAN = 0.25  # both profiles' deadman_timeout, s
PERIOD = 0.05  # both profiles' control period, s


# --- helpers -----------------------------------------------------------------------------


@functools.cache
def verify(rrd: Path) -> None:
    """``rerun rrd verify`` passes on the recording."""
    out = subprocess.run(
        [rerun_exe(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr[-2000:]


def kill(proc: subprocess.Popen[bytes]) -> float:
    """SIGKILL (no clean-up of any kind); returns the monotonic time of the kill."""
    t = time.monotonic()
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    return t


def stop_quietly(proc: subprocess.Popen[bytes] | None) -> None:
    """End a helper process whatever state it is in (for ``finally`` blocks)."""
    if proc is not None and proc.poll() is None:
        with contextlib.suppress(subprocess.TimeoutExpired):
            stop(proc, timeout=10)
    if proc is not None and proc.poll() is None:
        proc.kill()
        proc.wait(5)


def sim_user(profile: Path, log: Path, *args: str) -> subprocess.Popen[bytes]:
    """``legws joystick sim-user`` (at most 120 s)."""
    return start(
        ["joystick", "sim-user", "--profile", str(profile), "--duration", "120", *args], log
    )


class Stick:
    """The test's own joystick: validated messages at 50 Hz from a loopback session."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.session = session
        self.key = keys(robot)["joystick"]
        self.seq = 0

    def push(self, axes: list[float], seconds: float) -> None:
        """Hold the stick at ``axes`` for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            msg = {"schema": 1, "seq": self.seq, "stamp": time.time(), "axes": axes}
            self.seq += 1
            self.session.put(self.key, json.dumps(msg).encode())
            time.sleep(0.02)


def rises(m: Monitor, pub: Stick, metres: float = 0.02, within: float = 4.0) -> bool:
    """Hold the stick up until the EE has risen ``metres`` (``within`` seconds at most).

    The daemon, the bridge and the status each add a tick of latency, so on a loaded
    machine a fixed one-second push can end just short of a fixed distance.
    """
    z0 = ee(m)[2]
    end = time.monotonic() + within
    while time.monotonic() < end:
        pub.push([0.0, 0.0, 0.8], 0.25)
        if ee(m)[2] - z0 > metres:
            return True
    return False


@contextlib.contextmanager
def stick(port: int, robot: str) -> Iterator[Stick]:
    """A :class:`Stick` connected to the daemon on ``port``."""
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    with open_session(config_from_spec(spec)) as session:
        yield Stick(session, robot)


def trace_rows(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def check_stop(rows: list[dict[str, Any]], killed: float, until: float) -> dict[str, float]:
    """The ticks between a publisher's kill and ``until``: moving up to the last sample,
    zero velocity once the deadman expired, the last motion sent within the deadman plus
    one period of the last sample received. Returns the figures (s after the sample)."""
    window = [r for r in rows if killed - 2.0 <= r["begin"] < until]
    received = [r["received"] for r in window if r["received"] is not None]
    assert received, "no sample in the window"
    last = max(received)
    # What was already on its way (in the router, in the daemon's socket) may still arrive
    # after the kill, later under load: the stop is measured from the last sample received,
    # and the ticks after it (``late``) must show no sample at all.
    assert killed - 2.0 <= last < until
    moving = [r for r in window if np.linalg.norm(r["command"]) > 1e-4]
    assert any(last - 0.5 <= r["begin"] <= last + DEADMAN for r in moving), "not moving"
    late = [r for r in window if r["begin"] > last + DEADMAN]
    assert late and late[-1]["begin"] > last + DEADMAN + 5 * PERIOD  # the loop went on
    assert all(np.linalg.norm(r["command"]) == 0.0 for r in late)
    assert all(r["seq"] is None for r in late)
    last_motion = max(r["sent"] for r in moving)
    assert last_motion <= last + DEADMAN + PERIOD
    return {"last_motion_after_sample": last_motion - last, "killed_after_sample": killed - last}


def wait_moving(m: Monitor, mode: str, timeout: float) -> bool:
    """Until two consecutive status messages in ``mode`` show the EE moving (> 2 mm)."""

    def moving(m: Monitor) -> bool:
        with m._lock:
            recent = [s for _, s in m.status[-2:]]
        if len(recent) < 2 or any(s["mode"] != mode or "ee" not in s for s in recent):
            return False
        a, b = (np.array(s["ee"]["position"]) for s in recent)
        return bool(np.linalg.norm(b - a) > 0.002)

    return m.wait_for(moving, timeout)


def still_after(m: Monitor, t0: float) -> np.ndarray:
    """EE positions of the status messages received after ``t0``."""
    with m._lock:
        return np.array([s["ee"]["position"] for t, s in m.status if t > t0])


def commits_in_log(log: Path) -> list[str]:
    return [line for line in log.read_text().splitlines() if "daemon: commit goal=" in line]


# --- a joystick publisher killed, and restarted -----------------------------------------------


def test_publisher_killed_mid_motion_stops_the_robot_and_a_new_one_carries_on(
    tmp_path: Path,
) -> None:
    """SIGKILL the sim user in teleop and again during assistance: the robot stops within
    the deadman plus one tick of the last sample; a new publisher (a restarted zenoh peer)
    carries on: exactly one commit for the decision, the stage done. SIGTERM at the end: a
    valid recording."""
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    trace, rrd = tmp_path / "trace.jsonl", tmp_path / "run.rrd"
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--trace", str(trace),
         "--rerun", f"save:{rrd}", "--duration", "150"],
        tmp_path / "daemon.log",
    )  # fmt: skip
    users: list[subprocess.Popen[bytes]] = []
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            home = ee(m)
            # 1. killed while steering (teleop)
            users.append(sim_user(profile, tmp_path / "user1.log", "--goal", "white_mug"))
            assert wait_moving(m, "teleop", 30), (tmp_path / "user1.log").read_text()
            assert np.linalg.norm(ee(m) - home) > 0.002
            killed1 = kill(users[-1])
            time.sleep(1.5)
            rest = still_after(m, killed1 + DEADMAN + 0.2)
            assert len(rest) >= 8 and np.ptp(rest, axis=0).max() == 0.0  # not a micrometre
            assert m.latest()["deadman"] is True  # type: ignore[index]
            restart1 = time.monotonic()
            # 2. a new publisher: steers on; killed during the assisted motion
            users.append(sim_user(profile, tmp_path / "user2.log", "--goal", "white_mug",
                                  "--seed", "2"))  # fmt: skip
            assert m.wait_for(lambda m: "commit" in m.kinds(), 60)
            assert wait_moving(m, "assist", 10)
            killed2 = kill(users[-1])
            time.sleep(1.5)
            rest = still_after(m, killed2 + DEADMAN + 0.2)
            assert len(rest) >= 8 and np.ptp(rest, axis=0).max() == 0.0
            assert m.latest()["mode"] == "assist"  # type: ignore[index]  # paused, not lost
            restart2 = time.monotonic()
            # 3. another publisher: assistance resumes, no second commit
            users.append(sim_user(profile, tmp_path / "user3.log", "--goal", "white_mug",
                                  "--seed", "3"))  # fmt: skip
            assert m.wait_for(lambda m: "stage_done" in m.kinds(), 60)
            assert users[-1].wait(30) == 0  # the user saw the task done
            commits = [e for e in m.events if e["kind"] == "commit"]
            assert len(commits) == 1
            assert commits[0]["detail"]["goal"] == "white_mug"
    finally:
        for u in users:
            stop_quietly(u)
        code, seconds = stop(daemon)
    assert code == 0 and seconds < 5.0
    assert len(commits_in_log(tmp_path / "daemon.log")) == 1
    rows = trace_rows(trace)
    first = check_stop(rows, killed1, restart1)
    second = check_stop(rows, killed2, restart2)
    print(f"publisher killed: teleop {first}, assist {second}")
    verify(rrd)
    log = [text for _, _, text in read_text_log(rrd)]
    assert sum(t.startswith("commit goal=white_mug") for t in log) == 1


# --- the robot bridge killed and restarted ---------------------------------------------------


def test_bridge_killed_and_restarted_fault_then_reset_recovers(tmp_path: Path) -> None:
    port, bridge_port = free_port(), free_port()
    profile = write_profile(
        tmp_path, "sawyer", port, {"connect = []": f'connect = ["tcp/127.0.0.1:{bridge_port}"]'}
    )
    bridge_args = ["bridge", "fake", "--profile", str(profile), "--scene", "desk", "--listen",
                   f"tcp/127.0.0.1:{bridge_port}"]  # fmt: skip
    bridge: subprocess.Popen[bytes] | None = start(bridge_args, tmp_path / "bridge1.log")
    daemon = None
    try:
        time.sleep(1.0)
        daemon = start(
            ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120",
             "--allow-motion", "--insecure-transport"],
            tmp_path / "daemon.log",
        )  # fmt: skip
        with monitor(port, "sawyer") as m, stick(port, "sawyer") as pub:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()

            assert rises(m, pub)  # moving through the bridge
            assert bridge is not None
            killed = kill(bridge)  # the robot side vanishes: no goodbye, the heartbeat stops
            bridge = None
            assert m.wait_for(lambda m: "fault" in m.kinds(), 5)
            fault_after = time.monotonic() - killed
            n = len(m.status)
            pub.push([0.0, 0.0, 0.8], 1.0)  # the stick does nothing in the fault
            assert len(m.status) - n >= 8  # status keeps publishing
            assert m.latest()["mode"] == "fault"  # type: ignore[index]
            ok, reply = m.command("reset")
            assert not ok and "still failing" in reply["error"]

            bridge = start(bridge_args, tmp_path / "bridge2.log")  # the robot is back
            back = time.monotonic()

            def reset_accepted(m: Monitor) -> bool:
                ok, _ = m.command("reset")
                return ok

            assert m.wait_for(reset_accepted, 30), (tmp_path / "daemon.log").read_text()
            reset_after = time.monotonic() - back
            # the reset plan (home) runs with the dead-man held, then control is back
            deadline = time.monotonic() + 30
            while "recovered" not in m.kinds() and time.monotonic() < deadline:
                pub.push([0.0, 0.0, 0.0], 0.5)
            assert "recovered" in m.kinds()
            recovered_after = time.monotonic() - back
            assert m.kinds().count("fault") == 1
            assert m.wait_for(lambda m: m.latest()["mode"] == "teleop", 5)  # type: ignore[index]
            assert rises(m, pub)  # it moves again
            times = [t for t, _ in m.status]
            assert max(np.diff(times)) < 0.5  # status never paused, fault or not
            print(
                f"bridge: fault {fault_after:.2f} s after the kill; restarted: reset accepted "
                f"after {reset_after:.2f} s, recovered after {recovered_after:.2f} s; "
                f"longest status gap {max(np.diff(times)):.3f} s"
            )
    finally:
        code = None
        if daemon is not None:
            code, _ = stop(daemon)
        stop_quietly(bridge)
    assert code == 0


# --- the zenoh router restarted ----------------------------------------------------------------


@contextlib.contextmanager
def router(port: int, log: Path) -> Iterator[subprocess.Popen[bytes]]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.reliability.zenoh_router", f"tcp/127.0.0.1:{port}"],
        stdout=log.open("wb"), stderr=subprocess.STDOUT, env=env(), cwd=REPO,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 20
        while b"ready" not in log.read_bytes() and time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.05)
        assert b"ready" in log.read_bytes()
        yield proc
    finally:
        stop_quietly(proc)


def client_config(tmp: Path, port: int) -> Path:
    path = tmp / "client.json5"
    path.write_text(json.dumps({
        "mode": "client",
        "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}},
    }))  # fmt: skip
    return path


def test_router_restarted_everyone_reconnects_and_nothing_commits_twice(tmp_path: Path) -> None:
    """Daemon, publisher and monitor are zenoh clients of a router; the router is
    SIGKILLed mid-motion and restarted. The robot stops while the router is gone (no
    input), everyone reconnects, the user finishes, exactly one commit."""
    port, unused = free_port(), free_port()  # the router's; the daemon listens on nothing
    daemon_profile = write_profile(
        tmp_path, "sim", unused,
        {'mode = "peer"': 'mode = "client"', f'listen = ["tcp/127.0.0.1:{unused}"]': "listen = []",
         "connect = []": f'connect = ["tcp/127.0.0.1:{port}"]'},
    )  # fmt: skip
    zcfg = client_config(tmp_path, port)
    trace = tmp_path / "trace.jsonl"
    daemon = user = None
    with router(port, tmp_path / "router1.log") as first_router:
        daemon = start(
            ["daemon", "--profile", str(daemon_profile), "--scene", "desk", "--trace",
             str(trace), "--duration", "150"],
            tmp_path / "daemon.log",
        )  # fmt: skip
        try:
            with open_session(zenoh.Config.from_file(str(zcfg))) as session:
                m = Monitor(session, ROBOT)
                try:
                    assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
                    user = start(
                        ["joystick", "sim-user", "--profile", str(daemon_profile),
                         "--zenoh-config", str(zcfg), "--goal", "white_mug", "--duration",
                         "120"],
                        tmp_path / "user.log",
                    )  # fmt: skip
                    assert wait_moving(m, "teleop", 30), (tmp_path / "user.log").read_text()
                    killed = kill(first_router)
                    time.sleep(1.5)  # no router: no input reaches the daemon
                    restarted = time.monotonic()
                    with router(port, tmp_path / "router2.log"):
                        assert m.wait_for(lambda m: m.status[-1][0] > time.monotonic() - 0.5, 30)
                        back = m.status[-1][0]
                        assert m.wait_for(lambda m: "stage_done" in m.kinds(), 90)
                        assert user.wait(30) == 0
                        commits = [e for e in m.events if e["kind"] == "commit"]
                        assert len(commits) == 1
                        assert commits[0]["detail"]["goal"] == "white_mug"
                finally:
                    m.close()
        finally:
            stop_quietly(user)
            code, _ = stop(daemon)
    assert code == 0
    assert len(commits_in_log(tmp_path / "daemon.log")) == 1  # every event, even unseen
    rows = trace_rows(trace)
    figures = check_stop(rows, killed, restarted)
    gone = [r for r in rows if killed < r["begin"] < restarted]
    assert gone  # the loop ran on without the router (how often: the machine's load)
    print(f"router restart: {figures}, status back {back - killed:.2f} s after the kill")


# --- SIGINT during assistance --------------------------------------------------------------------


def test_sigint_during_assistance_stops_and_leaves_a_valid_recording(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    rrd = tmp_path / "sigint.rrd"
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--rerun", f"save:{rrd}",
         "--duration", "120"],
        tmp_path / "daemon.log",
    )  # fmt: skip
    user = None
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            user = sim_user(profile, tmp_path / "user.log", "--goal", "white_mug")
            assert m.wait_for(lambda m: "commit" in m.kinds(), 60)
            assert wait_moving(m, "assist", 10)
            t0 = time.monotonic()
            daemon.send_signal(signal.SIGINT)
            code = daemon.wait(10)
            seconds = time.monotonic() - t0
            assert m.wait_for(lambda m: "shutdown" in m.kinds(), 2)
            last = m.latest()
            assert last is not None and last["mode"] == "assist"
    finally:
        stop_quietly(user)
        if daemon.poll() is None:
            stop(daemon)
    assert code == 0 and seconds < 5.0
    print(f"SIGINT during assistance: exit 0 after {seconds:.2f} s")
    verify(rrd)
    log = [text for _, _, text in read_text_log(rrd)]
    assert any(t.startswith("commit goal=white_mug") for t in log)
    assert any(t.startswith("shutdown") for t in log)


# --- recordings that cannot be written --------------------------------------------------------


@pytest.mark.parametrize(
    ("where", "expected"),
    [
        ("/proc/legws.rrd", "No such file or directory"),
        ("/sys/legws.rrd", "cannot write"),
        ("/dev/full", "is a character device; refusing to write over it"),
        ("{tmp}/a-file/x.rrd", "is not a folder"),
        ("{tmp}/no-such-folder/x.rrd", "does not exist"),
    ],
)
def test_an_unwritable_recording_path_is_a_one_line_error_at_start(
    tmp_path: Path, where: str, expected: str
) -> None:
    (tmp_path / "a-file").write_text("x")
    profile = write_profile(tmp_path, "sim", free_port())
    path = where.format(tmp=tmp_path)
    out = subprocess.run(
        [*LEGWS, "daemon", "--profile", str(profile), "--rerun", f"save:{path}",
         "--duration", "5"],
        capture_output=True, text=True, timeout=60, env=env(),
    )  # fmt: skip
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("legws: error: --rerun: ") and expected in lines[0]


def test_a_disk_that_fills_up_is_reported_and_control_continues(
    tmp_path: Path, small_disk: Path
) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--rerun",
         f"save:{small_disk / 'full.rrd'}", "--trace", str(small_disk / "trace.jsonl"),
         "--duration", "120"],
        tmp_path / "daemon.log",
    )  # fmt: skip
    try:
        with monitor(port, ROBOT) as m, stick(port, ROBOT) as pub:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()

            def telemetry_warning(m: Monitor) -> bool:
                return any("telemetry" in e["detail"] for e in m.events if e["kind"] == "warning")

            deadline = time.monotonic() + 60
            up = True
            while not telemetry_warning(m) and time.monotonic() < deadline:
                pub.push([0.0, 0.0, 0.8 if up else -0.8], 1.0)  # up and down: fills the disk
                up = not up
            assert telemetry_warning(m), (tmp_path / "daemon.log").read_text()[-3000:]
            warning = next(e for e in m.events if "telemetry" in e["detail"])
            assert warning["kind"] == "warning"
            problem = warning["detail"]["telemetry"]
            assert "no space left" in problem or "nearly full" in problem, warning
            assert warning["detail"]["control"] == "continues"
            assert m.wait_for(lambda m: any("trace" in e["detail"] for e in m.events), 30)
            # the robot still answers the stick, status still flows
            p0 = ee(m)
            pub.push([0.0, 0.0, 0.8], 1.0)
            time.sleep(0.2)
            assert ee(m)[2] - p0[2] > 0.02
            # status at 10 Hz keeps flowing (over 3 s, so a loaded CI machine's pauses average out)
            n = len(m.status)
            time.sleep(3.0)
            assert len(m.status) - n >= 20
            assert m.latest()["mode"] == "teleop"  # type: ignore[index]
            assert "fault" not in m.kinds()
    finally:
        code, seconds = stop(daemon)
    assert code == 0 and seconds < 5.0
    log = (tmp_path / "daemon.log").read_text()
    assert "telemetry" in log and ("no space left" in log or "nearly full" in log)
    assert "Traceback" not in log
    # the trace stopped at the full disk with whole lines only (issue 16: a partial last line)
    trace = (small_disk / "trace.jsonl").read_text()
    assert trace == "" or trace.endswith("\n")
    assert all(json.loads(line)["tick"] >= 0 for line in trace.splitlines())


# --- in this process: a broken adapter, an exception in the loop ------------------------------


class _Flaky(SimAdapter):
    """The stand-in, with a read_state that raises a non-legws error while ``broken``."""

    broken = threading.Event()

    def _read_state(self) -> RobotState:
        if self.broken.is_set():
            raise ZeroDivisionError("injected: a bug in the adapter")
        return super()._read_state()


@contextlib.contextmanager
def in_process_daemon(
    tmp_path: Path, port: int, rrd: Path
) -> Iterator[tuple[DaemonService, threading.Event, list[BaseException], threading.Thread]]:
    """The daemon's service on a thread of this process, recording to ``rrd``."""
    profile = load_profile(write_profile(tmp_path, "sim", port))
    scene = load_scene("desk")
    params = Params(v_max=profile.control.v_max, dt=1.0 / profile.control.rate_hz)
    config = DaemonConfig(
        profile, scene, scene.default_layout(), params, config_from_spec(profile.transport),
        telemetry=RerunLog(f"save:{rrd}", robot=profile.robot), duration=120.0,
    )  # fmt: skip
    service = DaemonService(config)
    stop_event = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            service.run(stop_event)
        except BaseException as err:
            errors.append(err)

    thread = threading.Thread(target=run, name="daemon-under-test")
    thread.start()
    try:
        yield service, stop_event, errors, thread
    finally:
        stop_event.set()
        thread.join(15)
        assert not thread.is_alive()


def test_an_adapter_exception_is_a_safe_stop_and_status_keeps_publishing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(service_module, "SimAdapter", _Flaky)
    _Flaky.broken.clear()
    port = free_port()
    rrd = tmp_path / "adapter.rrd"
    with (
        in_process_daemon(tmp_path, port, rrd) as (service, _, errors, _thread),
        monitor(port, ROBOT) as m,
        stick(port, ROBOT) as pub,
    ):
        assert m.wait_for(ready, 30)

        pub.push([0.0, 0.0, 0.8], 0.5)
        _Flaky.broken.set()  # mid-motion
        assert m.wait_for(lambda m: "fault" in m.kinds(), 5)
        fault = next(e for e in m.events if e["kind"] == "fault")
        assert "ZeroDivisionError" in fault["detail"]["error"]
        n = len(m.status)
        pub.push([0.0, 0.0, 0.8], 1.0)
        assert len(m.status) - n >= 8  # status keeps publishing
        assert m.latest()["mode"] == "fault"  # type: ignore[index]
        assert m.latest()["fault"] is not None  # type: ignore[index]
        ok, reply = m.command("reset")
        assert not ok and "still failing" in reply["error"]
        _Flaky.broken.clear()
        ok, _ = m.command("reset")
        assert ok
        deadline = time.monotonic() + 30
        while "recovered" not in m.kinds() and time.monotonic() < deadline:
            pub.push([0.0, 0.0, 0.0], 0.5)
        assert "recovered" in m.kinds()
        assert m.kinds().count("fault") == 1
        assert not errors and service.controller is not None
        assert service.controller.mode == "teleop"
    assert not errors
    verify(rrd)
    log = [text for _, _, text in read_text_log(rrd)]
    assert any("ZeroDivisionError" in t for t in log) and any("recovered" in t for t in log)


def test_an_exception_in_the_loop_still_stops_the_robot_and_closes_the_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_tick = Controller.tick
    crash = threading.Event()

    def tick(self: Controller, sample: OperatorInput | None) -> TickRecord:
        if crash.is_set():
            raise RuntimeError("injected: a bug in the loop")
        return real_tick(self, sample)

    monkeypatch.setattr(Controller, "tick", tick)
    port = free_port()
    rrd = tmp_path / "crash.rrd"
    with (
        in_process_daemon(tmp_path, port, rrd) as (service, _, errors, thread),
        monitor(port, ROBOT) as m,
    ):
        assert m.wait_for(ready, 30)
        crash.set()
        thread.join(30)
        assert not thread.is_alive()
        assert m.wait_for(lambda m: "shutdown" in m.kinds(), 5)
        assert m.kinds()[-2:] == ["fault", "shutdown"]
        assert "daemon loop: RuntimeError" in m.events[-2]["detail"]["error"]
    assert len(errors) == 1 and isinstance(errors[0], RuntimeError)
    c = service.controller
    assert c is not None
    adapter = c.adapter
    assert isinstance(adapter, SimAdapter) and adapter.world is None  # disconnected
    verify(rrd)
    log = [text for _, _, text in read_text_log(rrd)]
    assert any("daemon loop: RuntimeError" in t for t in log)
    assert log[-1].startswith("shutdown")


# --- the telemetry worker: a stuck recording never holds the loop -----------------------------


def test_a_stuck_recording_never_blocks_the_loop_and_its_problems_are_reported() -> None:
    gate = threading.Event()
    done: list[int] = []
    worker = TelemetryWorker(check=lambda: "the recording does not take data", check_every=0.05)
    worker.submit(lambda: gate.wait(30))  # the worker hangs in a call (a sink that blocks)

    def loop_side() -> None:
        for i in range(QUEUE_SIZE + 100):
            worker.submit(functools.partial(done.append, i), droppable=True)
        for _ in range(1000):
            worker.submit(lambda: done.append(-1))  # commits, faults: never dropped

    submitter = threading.Thread(target=loop_side)
    submitter.start()
    submitter.join(10)
    assert not submitter.is_alive(), "submit blocked while the worker was stuck"
    assert worker.dropped == 100
    assert worker.take_report() is None  # nothing checked while stuck
    gate.set()
    deadline = time.monotonic() + 10
    while (report := worker.take_report()) is None and time.monotonic() < deadline:
        time.sleep(0.01)  # the next health check (every 0.05 s) reports the problem
    assert worker.close(10)
    assert len(done) == QUEUE_SIZE + 1000 and done.count(-1) == 1000
    assert report is not None and report.new >= 1
    assert report.last_error == "the recording does not take data"
    assert report.dropped == 100
    assert worker.take_report() is None  # reported once
