"""A demo run: ``legws daemon`` (a real process, the sim profile, a Rerun recording) and a
simulated user in this process, on a private loopback port, through a whole task graph.

The user picks a goal at random (seeded) at every decision — so across seeds it takes every
branch — and steers like the paper's noisy user. The run ends when the daemon reports the
task done (or at the timeout); the daemon is stopped with SIGTERM, which flushes the
recording. The summary lists every decision: what the user went for, what the daemon
committed to and when, whether that was right, and the decision's certificate.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.errors import LegwsError
from legws_daemon.formats.files import last_line, open_output, output_folder, write_atomic
from legws_daemon.formats.profile import ProfileSpec, TransportSpec
from legws_daemon.joystick.daemon_status import StatusWatch
from legws_daemon.joystick.publisher import Publisher, Sample
from legws_daemon.joystick.sim_user import SimUser
from legws_daemon.transport.session import config_from_spec, keys

#: Longest a demo may run before it is stopped, seconds.
DEFAULT_TIMEOUT = 600.0


@dataclass(frozen=True, slots=True)
class Decision:
    """One decision of the run."""

    decision: str
    action: str
    intended: str
    committed: str
    seconds: float
    correct: bool
    confirmed: bool
    single: bool
    certificate: float | None


@dataclass
class DemoResult:
    taskgraph: str
    seed: int
    completed: bool
    seconds: float
    recording: str
    decisions: list[Decision] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out.pop("events")
        return out


def free_port() -> int:
    """A TCP port on 127.0.0.1 nobody listens on now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def zenoh_json5(port: int) -> str:
    """The daemon's zenoh configuration: loopback only, multicast scouting off."""
    return json.dumps(
        {
            "mode": "peer",
            "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
            "connect": {"endpoints": []},
            "scouting": {"multicast": {"enabled": False}},
        },
        indent=1,
    )


def summarise(events: list[dict[str, Any]], chosen: list[tuple[str, str]]) -> list[Decision]:
    """Pair the daemon's commits with what the user went for, in order."""
    wanted = iter(chosen)
    out = []
    for e in events:
        if e["kind"] != "commit":
            continue
        d = e["detail"]
        intended = d["goal"] if d["single"] else next(wanted, ("", "?"))[1]
        out.append(
            Decision(
                decision=d.get("decision", d["stage"]),
                action=d["action"],
                intended=intended,
                committed=d["goal"],
                seconds=float(d["seconds"]),
                correct=intended == d["goal"],
                confirmed=bool(d["confirmed"]),
                single=bool(d["single"]),
                certificate=d.get("certificate"),
            )
        )
    return out


def markdown(result: DemoResult) -> str:
    lines = [
        f"# Demo `{result.taskgraph}`, seed {result.seed}",
        "",
        f"{'Completed' if result.completed else 'NOT completed'} in {result.seconds:.1f} s; "
        f"recording `{result.recording}` (open it with `rerun {result.recording}`).",
        "",
        "| decision | action | user went for | committed | commit after | correct | certificate |",
        "|---|---|---|---|---|---|---|",
    ]
    for d in result.decisions:
        how = " (no inference)" if d.single else " (confirmed)" if d.confirmed else ""
        cert = f"{d.certificate:.3f}" if d.certificate is not None else "—"
        lines.append(
            f"| {d.decision} | {d.action} | {d.intended} | {d.committed}{how} | "
            f"{d.seconds:.2f} s | {'yes' if d.correct else 'NO'} | {cert} |"
        )
    return "\n".join(lines) + "\n"


def run_demo(
    taskgraph: str,
    profile: ProfileSpec,
    out: Path,
    *,
    seed: int = 0,
    timeout: float = DEFAULT_TIMEOUT,
    plan: Path | None = None,
    log: Any = None,
    web: str | None = None,
) -> DemoResult:
    """Run the daemon and a simulated user through ``taskgraph``; write the recording, the
    daemon's log and the summary (JSON and Markdown) into ``out``. ``web`` (``web`` or
    ``web:[HOST:]PORT``) also serves the session to the Rerun web viewer."""
    output_folder(out)
    port = free_port()
    cfg_path = out / "zenoh.json5"
    write_atomic(cfg_path, zenoh_json5(port).encode())
    recording = out / "recording.rrd"
    args = [sys.executable, "-m", "legws_daemon", "daemon", "--profile", profile.name,
            "--taskgraph", taskgraph, "--rerun", f"save:{recording}", "--zenoh-config",
            str(cfg_path), "--duration", str(timeout), "--robot", profile.arm]  # fmt: skip
    # the plan made here, or none (the daemon would plan a task graph by default)
    args += ["--plan", str(plan) if plan is not None else "none"]
    if web is not None:
        args += ["--rerun", web]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    t0 = time.monotonic()
    with open_output(out / "daemon.log") as daemon_log:
        daemon = subprocess.Popen(
            args, stdout=daemon_log.fileno(), stderr=subprocess.STDOUT, env=env
        )
        try:
            result = _drive(taskgraph, profile, port, seed, timeout, daemon, log)
        finally:
            if daemon.poll() is None:
                daemon.send_signal(signal.SIGTERM)
            try:
                code = daemon.wait(30)
            except subprocess.TimeoutExpired:
                daemon.kill()
                code = daemon.wait(10)
    if code != 0:
        tail = last_line(out / "daemon.log").split()
        raise LegwsError(f"the daemon exited with {code}: {' '.join(tail)}")
    result.seconds = time.monotonic() - t0
    result.recording = str(recording)
    write_atomic(out / "summary.json", (json.dumps(result.to_json(), indent=1) + "\n").encode())
    write_atomic(out / "summary.md", markdown(result).encode())
    return result


def _drive(
    taskgraph: str,
    profile: ProfileSpec,
    port: int,
    seed: int,
    timeout: float,
    daemon: subprocess.Popen[bytes],
    log: Any,
) -> DemoResult:
    k = keys(profile.robot)
    spec = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    events: list[dict[str, Any]] = []
    done = threading.Event()
    watch = StatusWatch(k["status"])
    user = SimUser([], 0.03, profile.control.v_max, np.random.default_rng(seed))

    def on_event(sample: Any) -> None:
        e = json.loads(sample.payload.to_bytes())
        events.append(e)
        if log is not None:
            log(e)
        if e["kind"] in ("task_done", "shutdown", "fault"):
            done.set()

    with Publisher(config_from_spec(spec), k["joystick"], source=f"demo-user:{os.getpid()}") as pub:
        subs = [
            pub.session.declare_subscriber(
                k["status"], lambda s: watch.offer(s.payload.to_bytes())
            ),
            pub.session.declare_subscriber(k["events"], on_event),
        ]
        stop = threading.Event()

        def sample() -> Sample | None:
            if done.is_set() or daemon.poll() is not None:
                stop.set()
                return None
            now = time.monotonic()
            return user.sample(watch.latest(now), now)

        try:
            pub.run(sample, profile.control.rate_hz, timeout, stop)
        finally:
            for s in subs:
                s.undeclare()  # type: ignore[no-untyped-call]
    completed = any(e["kind"] == "task_done" for e in events)
    result = DemoResult(taskgraph, seed, completed, 0.0, "", summarise(events, user.chosen), events)
    return result
