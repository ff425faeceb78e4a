"""Soak: the daemon under joystick input at 50 Hz for minutes, with resets and stage changes.

Real processes on loopback: ``legws daemon --rate 50 --rerun save: --trace`` (the MuJoCo
stand-in paced to real time), ``legws joystick sim-user --forever --rate 50`` (random
goals at every decision, steering by the daemon's status), and this script as the
operator: a ``reset`` every ``--reset-every`` seconds and, every ``--load-every`` seconds,
a stage change — ``load_taskgraph`` tea, feeding, lego and ``load_scene`` desk in turn.

Measured:

- memory: the daemon's resident set (``VmRSS`` of ``/proc/<pid>/status``) every 5 s; growth
  is the end against the value after the warm-up, which ends 10 s after the first stage
  change (a load swaps the MuJoCo world: the resident set settles only then; at most a
  quarter of the run), plus the growth over the second half of the run and the slope of a
  line fitted to the samples after the warm-up;
- deadline misses: the daemon's own overrun count (a tick whose work ends after its
  deadline, ``ticker.py``) over its ticks, from its ``shutdown`` event; and from the trace,
  ticks whose work exceeded the period, split into ticks that carried out an operator
  command (a load rebuilds the MuJoCo world: the robot is stopped first, by design) and
  the others, and tick starts more than 1.5 periods apart;
- the recording: ``rerun rrd verify`` on the ``.rrd`` at the end; its size, and how long the
  daemon took to finish it at exit (its log line ``recording … finished in``);
- that nothing crashed: both processes exit 0, every command answered.

Usage:
    python benchmarks/soak.py [--minutes 10] [--rate 50] [--reset-every 30]
        [--load-every 60] [--port 17795] [--out docs/results/soak.json] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from legws_daemon.telemetry.rrd_file import rerun_cli

REPO = Path(__file__).resolve().parents[1]
LEGWS = [sys.executable, "-m", "legws_daemon"]
ROBOT = "sawyer_sim"
#: Stage changes, in turn: (command, argument).
LOADS = (
    ("load_taskgraph", "tea"),
    ("load_taskgraph", "feeding"),
    ("load_taskgraph", "lego"),
    ("load_scene", "desk"),
)
#: Seconds between memory samples.
RSS_EVERY = 5.0
#: The daemon's log line when its recording was finished at exit (``rerun_log.py``).
FINISHED = re.compile(r"finished in (?P<s>[0-9.]+) s \((?P<raw>[0-9.]+) MiB raw")


def profile_file(tmp: Path, port: int) -> Path:
    """The sim profile on ``port``."""
    text = (REPO / "hw_profiles" / "sim.toml").read_text()
    path = tmp / "soak.toml"
    path.write_text(text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}"))
    return path


def rss_kib(pid: int) -> int | None:
    """Resident set of a process, KiB (``None`` once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


class Operator:
    """A loopback session: records events and the daemon's status count, sends commands."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.events: list[dict[str, Any]] = []
        self.statuses = 0
        self.last_status: dict[str, Any] | None = None
        self._lock = threading.Lock()
        base = f"legws/{ROBOT}"
        self.command_key = f"{base}/command"
        self._subs = [
            session.declare_subscriber(f"{base}/events", self._on_event),
            session.declare_subscriber(f"{base}/status", self._on_status),
        ]

    def _on_event(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.events.append(json.loads(sample.payload.to_bytes()))

    def _on_status(self, sample: zenoh.Sample) -> None:
        status = json.loads(sample.payload.to_bytes())
        with self._lock:
            self.statuses += 1
            self.last_status = status

    def command(self, command: str, argument: str | None = None) -> tuple[bool, float]:
        """Send one command; returns whether it succeeded and how long the reply took."""
        body: dict[str, Any] = {"schema": 1, "command": command}
        if argument is not None:
            body["argument"] = argument
        t0 = time.monotonic()
        for reply in self.session.get(
            self.command_key, payload=json.dumps(body).encode(), timeout=10.0
        ):
            return reply.ok is not None, time.monotonic() - t0
        return False, time.monotonic() - t0

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()  # type: ignore[no-untyped-call]


def operator_config(port: int) -> zenoh.Config:
    """A loopback peer that connects to the daemon on ``port`` (no listening, no scouting)."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", "[]")
    cfg.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return cfg


def wait_ready(op: Operator, proc: subprocess.Popen[bytes], timeout: float) -> None:
    """Until the daemon's status shows its loop running."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"the daemon exited at start with {proc.returncode}")
        if op.last_status is not None and op.last_status["tick"] > 0:
            return
        time.sleep(0.1)
    raise SystemExit("the daemon did not come up")


def drive(
    op: Operator,
    daemon: subprocess.Popen[bytes],
    seconds: float,
    reset_every: float,
    load_every: float,
) -> tuple[list[tuple[float, int]], list[dict[str, Any]]]:
    """Run the schedule for ``seconds``; returns RSS samples and the commands sent."""
    t0 = time.monotonic()
    samples: list[tuple[float, int]] = []
    commands: list[dict[str, Any]] = []
    next_rss, next_reset, next_load, k = t0, t0 + reset_every, t0 + load_every, 0
    while (now := time.monotonic()) < t0 + seconds and daemon.poll() is None:
        if now >= next_rss:
            kib = rss_kib(daemon.pid)
            if kib is not None:
                samples.append((now - t0, kib))
            next_rss += RSS_EVERY
        if now >= next_load:
            name, arg = LOADS[k % len(LOADS)]
            k += 1
            ok, took = op.command(name, arg)
            commands.append({"t": now - t0, "command": f"{name} {arg}", "ok": ok, "s": took})
            next_load += load_every
            next_reset = max(next_reset, time.monotonic() + reset_every / 2)
        elif now >= next_reset:
            ok, took = op.command("reset")
            commands.append({"t": now - t0, "command": "reset", "ok": ok, "s": took})
            next_reset += reset_every
        time.sleep(0.05)
    return samples, commands


def memory_stats(samples: list[tuple[float, int]], warmup: float) -> dict[str, Any]:
    """RSS after the warm-up against the end, and the fitted slope after the warm-up."""
    t = np.array([s[0] for s in samples])
    kib = np.array([s[1] for s in samples], dtype=np.float64)
    after = t >= warmup
    if after.sum() < 2:
        raise SystemExit("too few memory samples after the warm-up")
    start, end = kib[after][0], kib[-1]
    slope = np.polyfit(t[after] / 60.0, kib[after] / 1024.0, 1)[0]
    middle = kib[t >= t[-1] / 2][0]
    return {
        "warmup_s": warmup,
        "rss_mib_start": float(kib[0] / 1024),
        "rss_mib_after_warmup": float(start / 1024),
        "rss_mib_end": float(end / 1024),
        "rss_mib_max": float(kib.max() / 1024),
        "growth_after_warmup": float((end - start) / start),
        "slope_mib_per_min": float(slope),
        "growth_second_half": float((end - middle) / middle),
        "samples": [[round(float(a), 1), int(b)] for a, b in zip(t, kib, strict=True)],
    }


def deadline_stats(
    rows: list[dict[str, Any]], rate: float, shutdown: dict[str, Any]
) -> dict[str, Any]:
    """Overruns (the daemon's count) and the trace's view of them (see the module doc)."""
    period = 1.0 / rate
    work = np.array([r["work"] for r in rows])
    with_command = np.array([r.get("commands", 0) > 0 for r in rows])
    over = work > period
    begins = np.array([r["begin"] for r in rows])
    gaps = np.diff(begins)
    ticks = int(shutdown.get("ticks", len(rows)))
    overruns = int(shutdown.get("overruns", -1))
    return {
        "rate_hz": rate,
        "ticks": ticks,
        "overruns": overruns,
        "overrun_fraction": overruns / ticks if ticks and overruns >= 0 else None,
        "work_over_period": int(over.sum()),
        "work_over_period_with_command": int((over & with_command).sum()),
        "work_over_period_without_command": int((over & ~with_command).sum()),
        "miss_fraction_without_command": float((over & ~with_command).sum() / len(rows)),
        "late_starts": int((gaps > 1.5 * period).sum()),
        "work_ms_p50": float(np.percentile(work, 50) * 1e3),
        "work_ms_p99": float(np.percentile(work, 99) * 1e3),
        "work_ms_p999": float(np.percentile(work, 99.9) * 1e3),
        "work_ms_max": float(work.max() * 1e3),
        "work_ms_max_without_command": float(work[~with_command].max() * 1e3),
    }


def soak(
    tmp: Path,
    *,
    seconds: float,
    rate: float,
    reset_every: float,
    load_every: float,
    port: int,
    record: bool = True,
) -> dict[str, Any]:
    """One soak run in ``tmp``; returns the figures (raises SystemExit on a failure).

    ``record=False`` runs without the Rerun recording (to tell its share of the memory).
    """
    profile = profile_file(tmp, port)
    rrd, trace = tmp / "soak.rrd", tmp / "trace.jsonl"
    env = {**os.environ, "CI": "true", "PYTHONUNBUFFERED": "1"}
    daemon_log = (tmp / "daemon.log").open("wb")
    recording = ["--rerun", f"save:{rrd}"] if record else []
    daemon = subprocess.Popen(
        [*LEGWS, "daemon", "--profile", str(profile), "--rate", str(rate), *recording,
         "--trace", str(trace), "--duration", str(seconds + 15)],
        env=env, stderr=daemon_log, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    user = None
    try:
        with zenoh.open(operator_config(port)) as session:
            op = Operator(session)
            try:
                wait_ready(op, daemon, 60)
                user_log = (tmp / "user.log").open("wb")
                user = subprocess.Popen(
                    [*LEGWS, "joystick", "sim-user", "--profile", str(profile), "--rate",
                     str(rate), "--forever", "--seed", "7", "--duration", str(seconds)],
                    env=env, stderr=user_log, stdout=subprocess.DEVNULL,
                )  # fmt: skip
                samples, commands = drive(op, daemon, seconds, reset_every, load_every)
                user_code = user.wait(60)
                daemon_code = daemon.wait(60)
                time.sleep(0.5)  # the last events
                events = list(op.events)
                statuses = op.statuses
            finally:
                op.close()
    finally:
        for proc in (user, daemon):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait(10)
    if daemon_code != 0 or user_code != 0:
        tail = (tmp / "daemon.log").read_text()[-2000:]
        raise SystemExit(f"daemon exit {daemon_code}, user exit {user_code}:\n{tail}")
    verify = None
    if record:
        verify = subprocess.run(
            [rerun_cli(), "rrd", "verify", str(rrd)],
            capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
    rows = [json.loads(line) for line in trace.read_text().splitlines()]
    kinds = [e["kind"] for e in events]
    shutdown: dict[str, Any] = next((e["detail"] for e in events if e["kind"] == "shutdown"), {})
    warmup = min(load_every + 10.0, seconds / 4) if load_every < seconds else min(60.0, seconds / 4)
    finished = FINISHED.search((tmp / "daemon.log").read_text()) if record else None
    telemetry = [
        e["detail"] for e in events if e["kind"] == "warning" and "telemetry" in e["detail"]
    ]
    return {
        "seconds": seconds,
        "reset_every_s": reset_every,
        "load_every_s": load_every,
        "memory": memory_stats(samples, warmup),
        "deadlines": deadline_stats(rows, rate, shutdown),
        "recording": None
        if verify is None
        else {
            "verified": verify.returncode == 0,
            "verify_output": (verify.stdout + verify.stderr).strip()[-500:],
            "mib": rrd.stat().st_size / 2**20,
            "raw_mib": float(finished["raw"]) if finished else None,
            "finish_s": float(finished["s"]) if finished else None,
        },
        "commands": {
            "sent": len(commands),
            "failed": [c for c in commands if not c["ok"]],
            "reply_s_max": max((c["s"] for c in commands), default=0.0),
            "resets": sum(c["command"] == "reset" for c in commands),
            "loads": sum(c["command"] != "reset" for c in commands),
        },
        "events": {k: kinds.count(k) for k in sorted(set(kinds))},
        "telemetry_warnings": telemetry,
        "statuses": statuses,
        "exit": {"daemon": daemon_code, "user": user_code},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=50.0, help="loop and joystick rate, Hz")
    ap.add_argument("--reset-every", type=float, default=30.0, help="seconds")
    ap.add_argument("--load-every", type=float, default=60.0, help="seconds")
    ap.add_argument("--port", type=int, default=17795)
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "results" / "soak.json")
    ap.add_argument("--keep", type=Path, help="keep the recording, trace and logs here")
    ap.add_argument("--no-rerun", action="store_true", help="run without the recording")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="legws-soak-") as d:
        tmp = a.keep or Path(d)
        tmp.mkdir(parents=True, exist_ok=True)
        result = soak(
            tmp,
            seconds=a.minutes * 60.0,
            rate=a.rate,
            reset_every=a.reset_every,
            load_every=a.load_every,
            port=a.port,
            record=not a.no_rerun,
        )
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    mem, dl, rec = result["memory"], result["deadlines"], result["recording"]
    verdict = "none" if rec is None else "verified" if rec["verified"] else "NOT verified"
    print(
        f"soak {a.minutes:g} min at {a.rate:g} Hz: memory {mem['rss_mib_after_warmup']:.1f} -> "
        f"{mem['rss_mib_end']:.1f} MiB ({100 * mem['growth_after_warmup']:+.2f} %), "
        f"overruns {dl['overruns']}/{dl['ticks']}, "
        f"misses without a command {dl['work_over_period_without_command']}, recording "
        f"{verdict}; wrote {a.out}"
    )
    if (rec is not None and not rec["verified"]) or result["commands"]["failed"]:
        sys.exit(1)


if __name__ == "__main__":
    main()
