"""The Franka bridge end to end: franka-sim as the robot, the bridge on pylibfranka.

Three processes, as on a bench: franka-sim (``bridge/franka/sim_server.py`` in
``.venv-franka-sim``: the libfranka protocol on a loopback address of its own, MuJoCo
physics at 1 kHz), the bridge (``bridge/franka_bridge.py`` in ``.venv-franka``, talking to it
through pylibfranka), and this test as the daemon: a zenoh peer on loopback (no scouting)
that sends commands made and serialised by the daemon's own contract code and validates
every state with the daemon's own parser. The transport is the deployment's: the files of
``legws secure init`` (mutual TLS on loopback, each side's access control), the test holding
the daemon's identity and the bridge its own. Nothing is faked: the simulated arm is driven by
what the bridge writes to libfranka and is measured by what libfranka reads back.

Skipped, with the reason, when the two venvs are not there (``bridge/franka/setup-venvs.sh``
builds them). Every process is killed at the end, whatever happened.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zenoh

from legws_daemon.cli.main import run as legws
from legws_daemon.formats.bridge_messages import (
    BridgeState,
    ResumeMessage,
    StopMessage,
    bridge_contract,
)
from legws_daemon.formats.messages import dump
from legws_daemon.transport.session import open_session
from tests.bridge.processes import Process
from tests.net import free_port

ROOT = Path(__file__).parents[2]
SIM_PYTHON = ROOT / ".venv-franka-sim" / "bin" / "python"
BRIDGE_PYTHON = ROOT / ".venv-franka" / "bin" / "python"
SIM_SERVER = ROOT / "bridge" / "franka" / "sim_server.py"
BRIDGE = ROOT / "bridge" / "franka_bridge.py"
ROBOT = "panda"
#: the daemon's side of the contract on the Panda: its joints and speed limits
PANDA = bridge_contract("panda")
#: The workspace the test gives the bridge (table coordinates): franka-sim's start pose
#: puts the endpoint 0.73 m above the base, above the profile's default box; and 0.554 m
#: in front of it, at x = 0.674 on the table (the base at x = 0.12), 0.046 m from the
#: box's front face (0.70 + the margin, 0.02).
WORKSPACE = ("0.2", "0.70", "-0.6", "0.6", "0.0", "0.95")
#: franka-sim's start posture (its idle hold), rad.
SIM_START = (0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785)
#: An arm at rest moves less than this in 0.5 s, rad (franka-sim's hold settles by a
#: few milliradians when a motion ends; 0.5 s at 0.3 rad/s would be 0.15 rad).
REST = 5e-3
#: Time for a process to start, s.
START_TIMEOUT = 60.0

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        not (
            (ROOT / ".venv-franka-sim" / ".legws-franka").is_file()
            and (ROOT / ".venv-franka" / ".legws-franka").is_file()
        ),
        reason="the Franka venvs are not built: run bridge/franka/setup-venvs.sh "
        "(franka-sim in .venv-franka-sim, pylibfranka in .venv-franka)",
    ),
]


def loopback_address() -> str:
    """A 127.x.y.z on which TCP 1337 and 1338 (libfranka's fixed ports) are free."""
    rng = random.Random()
    for _ in range(50):
        host = f"127.{rng.randint(100, 250)}.{rng.randint(0, 255)}.{rng.randint(1, 254)}"
        try:
            for port in (1337, 1338):
                with socket.socket() as s:
                    s.bind((host, port))
        except OSError:
            continue
        return host
    raise RuntimeError("no free loopback address for franka-sim")


@dataclass
class Daemon:
    """The daemon's side of the contract: commands, stops, resumes out; states in."""

    session: zenoh.Session
    states: list[tuple[float, BridgeState]] = field(default_factory=list)
    seq: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self.commands = self.session.declare_publisher(f"legws/{ROBOT}/bridge/command")
        self.resumes = self.session.declare_publisher(f"legws/{ROBOT}/bridge/resume")
        self.stops = self.session.declare_publisher(f"legws/{ROBOT}/stop/daemon")
        self.sub = self.session.declare_subscriber(f"legws/{ROBOT}/bridge/state", self._on_state)

    def _on_state(self, sample: zenoh.Sample) -> None:
        state = PANDA.parse_state(sample.payload.to_bytes(), "bridge state")  # the daemon's parser
        with self.lock:
            self.states.append((time.monotonic(), state))

    def latest(self) -> BridgeState:
        with self.lock:
            assert self.states, "no state from the bridge"
            return self.states[-1][1]

    def since(self, t: float) -> list[BridgeState]:
        with self.lock:
            return [s for when, s in self.states if when >= t]

    def wait(self, predicate: object, timeout: float, what: str) -> BridgeState:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                latest = self.states[-1][1] if self.states else None
            if latest is not None and predicate(latest):  # type: ignore[operator]
                return latest
            time.sleep(0.01)
        raise AssertionError(f"{what} within {timeout} s; last state: {latest}")

    def command(self, dq: list[float], ttl: float = 0.1, gripper: str | None = None) -> None:
        self.seq += 1
        message = PANDA.Command.model_validate(
            {
                "schema": 1,
                "seq": self.seq,
                "stamp": time.time(),
                "mode": "joint_velocity",
                "dq": dq,
                "ttl": ttl,
                "gripper": gripper,
            }
        )
        self.commands.put(dump(message))

    def drive(self, dq: list[float], seconds: float, rate: float = 50.0) -> float:
        """Commands at ``rate`` for ``seconds``; the time of the last one."""
        end = time.monotonic() + seconds
        last = time.monotonic()
        while time.monotonic() < end:
            self.command(dq)
            last = time.monotonic()
            time.sleep(1.0 / rate)
        return last

    def stop(self) -> None:
        self.stops.put(dump(StopMessage.model_validate({"schema": 1, "reason": "test"})))

    def resume(self) -> None:
        self.seq += 1
        message = ResumeMessage.model_validate({"schema": 1, "seq": self.seq, "stamp": 0.0})
        self.resumes.put(dump(message))


@dataclass
class Rig:
    sim: Process
    bridge: Process
    daemon: Daemon
    started: float
    #: closes the test's own session (the daemon's identity and port), for the real daemon
    release: Callable[[], None]


@contextlib.contextmanager
def running_rig(secure: Path) -> Iterator[Rig]:
    """franka-sim, the bridge and the daemon's session on the deployment files made in
    ``secure``; every process ended on the way out."""
    t0 = time.monotonic()
    host = loopback_address()
    port = free_port()
    assert legws(["secure", "init", str(secure), "--port", str(port)]) == 0
    sim = Process("franka-sim", [str(SIM_PYTHON), str(SIM_SERVER), "--host", host])
    bridge: Process | None = None
    own = contextlib.ExitStack()
    try:
        sim.wait_for_line("franka-sim ready", START_TIMEOUT)
        daemon_config = zenoh.Config.from_file(str(secure / "daemon.json5"))
        with own:
            session = own.enter_context(open_session(daemon_config))
            daemon = Daemon(session)
            bridge = Process(
                "bridge",
                [
                    str(BRIDGE_PYTHON),
                    str(BRIDGE),
                    "--robot-ip",
                    host,
                    "--realtime",
                    "ignore",
                    "--zenoh-config",
                    str(secure / "bridge.json5"),
                    "--workspace",
                    *WORKSPACE,
                ],
            )
            daemon.wait(lambda s: True, START_TIMEOUT, "a first state")
            yield Rig(sim, bridge, daemon, time.monotonic() - t0, own.close)
    finally:
        if bridge is not None:
            bridge.stop()
        sim.stop()


def moved(a: BridgeState, b: BridgeState) -> list[float]:
    return [y - x for x, y in zip(a.q, b.q, strict=True)]


def heartbeat_is_the_simulated_arm(rig: Rig) -> None:
    d = rig.daemon
    time.sleep(0.5)
    t = time.monotonic()
    time.sleep(1.0)
    states = d.since(t)
    assert len(states) >= 70, f"{len(states)} states in 1 s (100 Hz expected)"
    assert [s.seq for s in states] == sorted(s.seq for s in states)
    last = states[-1]
    assert last.enabled and not last.estop and last.stopped_by is None
    assert max(abs(q - q0) for q, q0 in zip(last.q, SIM_START, strict=True)) < 0.05
    assert last.gripper == "unknown"  # never commanded


def commands_drive_the_arm_and_it_stops_when_they_stop(rig: Rig) -> None:
    d = rig.daemon
    before = d.latest()
    last = d.drive([0.3, 0.0, 0.0, 0.0, 0.0, 0.0, -0.3], 1.0)
    assert d.latest().dq[0] == pytest.approx(0.3, abs=0.05)
    # the command's life (0.1 s) and the ramp's braking: at rest well within 0.5 s
    time.sleep(max(0.0, last + 0.5 - time.monotonic()))
    rest = d.latest()
    time.sleep(0.5)
    later = d.latest()
    step = moved(before, later)
    # 1 s at 0.3 rad/s (franka-sim's joint 7 velocity reading is off by ~0.07 rad/s at
    # rest, so its motion is judged by the angle)
    # (at most what was commanded, its last ttl and the braking; at least a third of it
    # when a loaded machine slows franka-sim's physics below real time, or the bridge's
    # tick past its target's 30 ms life, and the arm brakes and starts again)
    assert 0.1 < step[0] < 0.36, (step, rig.sim.lines[-5:])
    assert -0.36 < step[6] < -0.1, (step, rig.sim.lines[-5:])
    assert max(abs(v) for v in step[1:6]) < 0.01  # the others held
    drift = moved(rest, later)
    assert max(abs(v) for v in drift) < REST, f"still moving after its commands: {drift}"
    assert not any(s.limited for s in d.since(last - 1.0))


def the_joint_and_endpoint_speed_caps(rig: Rig) -> None:
    d = rig.daemon
    # the wrist's roll over the bridge's 0.8 rad/s (the endpoint is on its axis)
    before, t = d.latest(), time.monotonic()
    last = d.drive([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.5], 0.6)
    states = d.since(t)
    assert any("joint_speed" in s.limited for s in states)
    assert "ee_speed" not in {name for s in states for name in s.limited}
    # (at most the cap over the time it ran; at least some of it: a loaded machine slows
    # franka-sim's physics below real time — 0.15 rad of 0.48 measured with the slow tests
    # all running at once)
    assert 0.05 < moved(before, d.latest())[6] < 0.8 * (d.since(last)[0].stamp - states[0].stamp)
    time.sleep(0.5)
    # the base's turn at 0.8 rad/s moves the endpoint (0.55 m out) at 0.44 m/s: held to
    # the endpoint cap, 0.2 m/s, from the arm's Jacobian
    t = time.monotonic()
    d.drive([0.8, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.6)
    states = d.since(t)
    assert any("ee_speed" in s.limited for s in states)
    assert max(abs(s.dq[0]) for s in states) == pytest.approx(0.2 / 0.554, abs=0.04)
    time.sleep(0.5)


def the_latched_stop(rig: Rig) -> None:
    d = rig.daemon
    d.stop()
    d.wait(lambda s: s.stopped_by == "daemon", 2.0, "the stop latched")
    before = d.latest()
    d.drive([-0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.5)  # ignored while stopped
    time.sleep(0.3)
    drift = moved(before, d.latest())
    assert max(abs(v) for v in drift) < REST, f"moved while stopped: {drift}"
    d.resume()
    d.wait(lambda s: s.stopped_by is None, 2.0, "the resume")
    before, deadline = d.latest(), time.monotonic() + 3.0
    while moved(before, d.latest())[0] > -0.1:  # moves again
        assert time.monotonic() < deadline, f"did not move again: {d.latest()}"
        d.drive([-0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.1)


def the_workspace_stops_the_arm_at_its_face(rig: Rig) -> None:
    """The shoulder's pitch moves the endpoint forward (0.29 m/rad) and down: the box's
    front face is 0.046 m ahead, about 0.16 rad of joint 2."""
    d = rig.daemon
    before, t = d.latest(), time.monotonic()
    d.drive([0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0], 1.5)
    states = d.since(t)
    assert any("workspace" in s.limited for s in states)
    time.sleep(0.3)
    stopped = d.latest()
    assert 0.05 < moved(before, stopped)[1] < 0.25
    d.drive([0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0], 0.5)  # further out: refused
    time.sleep(0.3)
    assert abs(moved(stopped, d.latest())[1]) < REST
    back = d.latest()
    d.drive([0.0, -0.3, 0.0, 0.0, 0.0, 0.0, 0.0], 0.5)  # back in: allowed
    time.sleep(0.3)
    assert moved(back, d.latest())[1] < -0.1
    # and to where it was
    deadline = time.monotonic() + 3.0
    while d.latest().q[1] - before.q[1] < -0.02 and time.monotonic() < deadline:
        d.drive([0.0, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0], 0.05)
    time.sleep(0.3)


def the_franka_hand(rig: Rig) -> None:
    d = rig.daemon
    d.command([0.0] * 7, gripper="closed")
    d.wait(lambda s: s.gripper == "closed", 5.0, "the hand closed")
    d.command([0.0] * 7, gripper="open")
    d.wait(lambda s: s.gripper == "open", 5.0, "the hand open")


def the_daemon_drives_it(rig: Rig, secure: Path, folder: Path) -> None:
    """The real daemon on the Panda's bridge profile (``hw_profiles/panda.toml``: ``adapter =
    "bridge"``) in the test's place, on the deployment's transport (the daemon's identity):
    it believes the bridge (the Panda's joints, validated by its contract), an operator's
    joystick (the operator's identity) moves the simulated arm through the bridge and
    libfranka, and the arm rests when the joystick stops. Watched as an observer would:
    the daemon's status."""
    text = (ROOT / "hw_profiles" / "panda.toml").read_text()
    x0, x1, y0, y1, z0, z1 = WORKSPACE  # franka-sim's start pose is above the default box
    for old, new in (("x = [0.30, 0.90]", f"x = [{x0}, {x1}]"),
                     ("y = [-0.50, 0.50]", f"y = [{y0}, {y1}]"),
                     ("z = [0.02, 0.55]", f"z = [{z0}, {z1}]")):  # fmt: skip
        assert old in text
        text = text.replace(old, new)
    profile = folder / "panda.toml"
    profile.write_text(text)
    rig.release()  # the daemon's port and identity are the real daemon's now
    daemon = Process(
        "daemon",
        [sys.executable, "-m", "legws_daemon", "daemon", "--profile", str(profile), "--scene",
         "desk", "--allow-motion", "--zenoh-config", str(secure / "daemon.json5"),
         "--duration", "120"],
        env={**os.environ, "CI": "true"},
    )  # fmt: skip
    statuses: list[dict[str, Any]] = []
    try:
        daemon.wait_for_line("started adapter=bridge scene=desk", START_TIMEOUT)
        observer = zenoh.Config.from_file(str(secure / "observer.json5"))
        operator = zenoh.Config.from_file(str(secure / "operator.json5"))
        with open_session(observer) as obs, open_session(operator) as op:
            sub = obs.declare_subscriber(
                f"legws/{ROBOT}/status",
                lambda sample: statuses.append(json.loads(sample.payload.to_bytes())),
            )

            def height() -> float:
                deadline = time.monotonic() + 10.0
                while not statuses:
                    assert time.monotonic() < deadline, daemon.log()
                    time.sleep(0.05)
                return float(statuses[-1]["ee"]["position"][2])

            z_start = height()
            assert statuses[-1]["adapter"] == "bridge" and statuses[-1]["fallback"] is False
            deadline, seq = time.monotonic() + 20.0, 0
            while z_start - height() < 0.02:  # down at 0.8 of v_max (0.04 m/s)
                assert time.monotonic() < deadline, daemon.log()
                seq += 1
                message = {"schema": 1, "seq": seq, "stamp": 0.0, "axes": [0.0, 0.0, -0.8]}
                op.put(f"legws/{ROBOT}/joystick", json.dumps(message))
                time.sleep(0.03)
            time.sleep(1.0)  # the joystick gone: the deadman, the bridge's ttl, the ramp
            rest = height()
            time.sleep(0.5)
            assert abs(height() - rest) < 0.002, statuses[-1]["ee"]
            assert statuses[-1]["mode"] == "teleop", statuses[-1]
            sub.undeclare()  # type: ignore[no-untyped-call]
        assert daemon.stop() == 0, daemon.log()
        assert "Traceback" not in daemon.text(), daemon.log()
    finally:
        daemon.stop()


def within_libfrankas_limits_and_a_clean_exit(rig: Rig) -> None:
    """Last: franka-sim checks every command against the FCI's limits (and logs any it
    breaks, not enforced), and the bridge stops on SIGTERM with its motion ended."""
    assert rig.bridge.stop() == 0, rig.bridge.log()
    assert "franka_bridge: stopped (" in rig.bridge.log()
    assert not [line for line in rig.bridge.lines if "Traceback" in line], rig.bridge.log()
    broken = [line for line in rig.sim.lines if "motion limit violated" in line]
    assert not broken, "\n".join(broken[:10])
    print(f"set-up (franka-sim and the bridge started): {rig.started:.1f} s")
    print(json.dumps({"bridge": rig.bridge.lines[-1:], "franka-sim": rig.sim.lines[-5:]}))


def test_the_bridge_drives_franka_sim(tmp_path: Path) -> None:
    """One arm, one bridge, the phases in order (each leaves the arm at rest, near where it
    started, for the next)."""
    with running_rig(tmp_path / "deployment") as rig:
        heartbeat_is_the_simulated_arm(rig)
        the_workspace_stops_the_arm_at_its_face(rig)
        commands_drive_the_arm_and_it_stops_when_they_stop(rig)
        the_joint_and_endpoint_speed_caps(rig)
        the_latched_stop(rig)
        the_franka_hand(rig)
        the_daemon_drives_it(rig, tmp_path / "deployment", tmp_path)
        within_libfrankas_limits_and_a_clean_exit(rig)


def test_franka_sim_serves_loopback_only() -> None:
    done = subprocess.run(
        [str(SIM_PYTHON), str(SIM_SERVER), "--host", "0.0.0.0"],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    assert done.returncode == 2
    assert "--host must be a loopback address" in done.stderr


def test_the_bridge_on_a_robot_pc_runs_from_its_bundle(tmp_path: Path) -> None:
    """Run by the robot PC's Python (pylibfranka and zenoh, no legws): the script copied
    alone says in one line what it needs; from ``legws bridge bundle --arm panda`` it finds
    the guard and the Panda's tables beside it (then refuses the loopback default, as it
    should)."""
    alone = tmp_path / "alone" / "bridge"
    alone.mkdir(parents=True)
    (alone / "franka_bridge.py").write_bytes(BRIDGE.read_bytes())

    def run(script: Path) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [str(BRIDGE_PYTHON), str(script), "--robot-ip", "127.0.0.1"],
            capture_output=True,
            text=True,
            timeout=60,
            stdin=subprocess.DEVNULL,
            check=False,
        )

    missing = run(alone / "franka_bridge.py")
    assert missing.returncode == 2
    assert missing.stderr.startswith(
        "franka_bridge.py: error: legws' arm tables and bridge limits not found"
    )
    assert "legws bridge bundle --arm panda --out DIR" in missing.stderr
    assert missing.stderr.count("\n") == 1
    assert legws(["bridge", "bundle", "--arm", "panda", "--out", str(tmp_path / "b")]) == 0
    bundled = tmp_path / "b" / "bridge" / "franka_bridge.py"
    assert not (tmp_path / "b" / "bridge" / "chains").exists()  # libfranka has the model
    found = run(bundled)
    assert found.returncode == 2, found.stderr
    assert "the transport is not authenticated" in found.stderr
