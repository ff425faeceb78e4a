"""The robot side of a person's session: the daemon processes a study starts, and the one
client that hears them.

Every trial runs in a daemon process of its own (``legws daemon``): its layout
(``--layout``, or a task graph's plan with ``--plan``), its assistance policy, the
participant's operator file (every certificate for their model), and its own recording
(``--rerun save:``), so a trial's data is one file that is finished when the trial is. The
calibration is ``legws operator calibrate``, a process the same way. The participant steers
with their own publisher (``legws joystick keyboard``, ``evdev``, ``can``, a gamepad): it
keeps publishing between trials and reaches each new daemon on the same endpoints (zenoh
reconnects), as it would a daemon restarted by hand.

Processes run with the profile given (``--allow-motion`` passed on for a real arm, which the
daemon otherwise refuses to move), are stopped with SIGTERM (the robot stops; the recording
is finished) and killed only when they do not exit within :data:`STOP_GRACE`; their output
goes to a log beside the recordings, and an early exit is an error quoting its last line.
A process leads its own process group (a Ctrl-C at the session's terminal reaches the
session, which stops it) and gets SIGTERM from Linux if the session itself dies: no daemon
outlives the session that started it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from legws_daemon.client.client import Client
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import safe_text
from legws_daemon.telemetry.web_viewer import die_with_parent

#: Seconds a process gets to exit after SIGTERM/SIGINT before it is killed.
STOP_GRACE = 15.0
#: The command that runs legws in a child process (this interpreter, this package).
LEGWS = (sys.executable, "-m", "legws_daemon")


@dataclass(frozen=True)
class RigSpec:
    """How a session reaches the robot.

    Attributes:
        profile: the hardware profile (a name in hw_profiles/ or a .toml path).
        zenoh_config: a zenoh configuration file for a real network (``None``: the
            profile's loopback).
        robot: the profile's robot name (the keys the client listens on).
        arm: ``--robot`` of the daemon (``None``: the profile's).
        allow_motion: pass ``--allow-motion`` (a profile that drives real hardware).
        insecure_transport: pass ``--insecure-transport``.
        viewer: the gRPC URL of a Rerun web viewer every process also logs into (``None``:
            none).
    """

    profile: str
    zenoh_config: Path | None = None
    robot: str = "sawyer_sim"
    arm: str | None = None
    allow_motion: bool = False
    insecure_transport: bool = False
    viewer: str | None = None

    def common(self) -> list[str]:
        args = ["--profile", self.profile]
        if self.zenoh_config is not None:
            args += ["--zenoh-config", str(self.zenoh_config)]
        if self.allow_motion:
            args.append("--allow-motion")
        if self.insecure_transport:
            args.append("--insecure-transport")
        return args

    def rerun(self, recording: Path) -> list[str]:
        args = ["--rerun", f"save:{recording}"]
        if self.viewer is not None:
            args += ["--rerun", f"connect:{self.viewer}"]
        return args

    def daemon_args(
        self,
        task_kind: str,
        source: str,
        assist: str,
        recording: Path,
        *,
        layout: Path | None = None,
        plan: Path | None = None,
        operator: Path | None = None,
    ) -> list[str]:
        """``legws daemon`` for one trial."""
        args = ["daemon", *self.common(), f"--{task_kind}", source, "--assist", assist]
        if self.arm is not None:
            args += ["--robot", self.arm]
        if layout is not None:
            args += ["--layout", str(layout)]
        if task_kind == "taskgraph":
            args += ["--plan", str(plan) if plan is not None else "none"]
        if operator is not None:
            args += ["--operator", str(operator)]
        return args + self.rerun(recording)

    def calibrate_args(
        self, out: Path, name: str, scene: str, targets: int, seed: int, recording: Path,
        *, trace: Path | None = None,
    ) -> list[str]:  # fmt: skip
        """``legws operator calibrate`` of the participant (``trace``: where the reaches'
        trace goes; default NAME.trace.jsonl beside ``out``)."""
        args = ["operator", "calibrate", *self.common(), "--out", str(out), "--name", name]
        args += ["--scene", scene, "--targets", str(targets), "--seed", str(seed)]
        if trace is not None:
            args += ["--trace", str(trace)]
        return args + self.rerun(recording)

    def client(self) -> Client:
        if self.zenoh_config is not None:
            return Client.from_config(self.zenoh_config, self.robot)
        return Client.from_profile(self.profile)


class Child:
    """One legws process of the session (a trial's daemon, the calibration)."""

    def __init__(self, args: Sequence[str], log: Path, what: str) -> None:
        self.what = what
        self.log = log
        env = dict(os.environ)
        env["PYTHONUNBUFFERED"] = "1"
        with log.open("ab") as out:
            self._proc = subprocess.Popen(
                [*LEGWS, *args], stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                env=env, start_new_session=True, preexec_fn=die_with_parent(),
            )  # fmt: skip

    @property
    def pid(self) -> int:
        return self._proc.pid

    def poll(self) -> int | None:
        return self._proc.poll()

    def last_line(self) -> str:
        """The log's last line (why a process ended), terminal-safe."""
        try:
            with self.log.open("rb") as f:
                f.seek(max(0, self.log.stat().st_size - 4096))
                lines = [ln for ln in f.read().decode(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return ""
        return safe_text(lines[-1], 300) if lines else ""

    def stop(self, sig: signal.Signals = signal.SIGTERM, grace: float = STOP_GRACE) -> int:
        """Send ``sig`` (the robot stops, the recording is finished) and wait; killed after
        ``grace`` s. Returns the exit code."""
        if self._proc.poll() is None:
            self._proc.send_signal(sig)
        try:
            return self._proc.wait(grace)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            return self._proc.wait(5.0)

    def failed(self) -> InputError:
        """The error of a process that exited before it should have."""
        code = self._proc.poll()
        return InputError(
            f"{self.what} exited (code {code}): {self.last_line() or 'no output'}",
            source=str(self.log),
        )
