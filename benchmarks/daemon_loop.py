"""Daemon timing on the sim profile: tick time, highest sustained rate, input latency.

Runs the real processes on loopback: ``legws daemon --trace`` (one JSON line per tick) and
``legws joystick sim-user`` at the same rate, and reads the trace back.

1. Tick work p50/p99 at the profile's 20 Hz over a whole episode (commit, assistance),
   without and with a Rerun recording (``--rerun save:``).
2. Highest sustained rate: the daemon at increasing ``--rate`` for a few seconds each;
   *sustained* when the achieved tick rate is >= 98 % of the nominal and fewer than 1 %
   of tick intervals exceed 1.5 periods.
3. Latency of joystick input (the user publishing at 1.07x the loop rate, so the phase
   between the two sweeps), from the publisher's ``put`` (its wall-clock stamp) to the
   command leaving for the robot, for every tick that used a new sample; split into
   transport (publish -> received by the daemon), the wait for the next tick (a fixed-rate
   loop samples its input once per period: up to one period), and the tick's own work.
4. Shutdown: SIGTERM to exit with a Rerun recording open (the file then passes
   ``rerun rrd verify``), five runs.

Usage:
    python benchmarks/daemon_loop.py [--rates 50,100,200,400,800] [--seconds 8]
        [--out docs/results/daemon_loop.json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.telemetry.rrd_file import rerun_cli

REPO = Path(__file__).resolve().parents[1]
PORT = 17790
#: The user publishes at a rate unrelated to the loop's, so that the wait for the next tick
#: sweeps the whole period instead of locking to one phase.
USER_RATE = 1.07


def profile_file(tmp: Path) -> Path:
    text = (REPO / "hw_profiles" / "sim.toml").read_text()
    path = tmp / "bench.toml"
    path.write_text(text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{PORT}"))
    return path


def run_pair(
    tmp: Path, rate: float, seconds: float, rerun: bool, goal: str = "white_mug"
) -> list[dict[str, Any]]:
    """Daemon + simulated user at ``rate`` for ``seconds``; returns the trace rows."""
    profile = profile_file(tmp)
    trace = tmp / f"trace-{rate:g}-{int(rerun)}.jsonl"
    env = {**os.environ, "CI": "true"}
    args = [sys.executable, "-m", "legws_daemon", "daemon", "--profile", str(profile),
            "--rate", str(rate), "--duration", str(seconds + 4), "--trace", str(trace)]  # fmt: skip
    if rerun:
        args += ["--rerun", f"save:{tmp / 'bench.rrd'}"]
    daemon = subprocess.Popen(args, env=env, stderr=subprocess.DEVNULL)
    time.sleep(3.0)  # start-up: imports, the MuJoCo model, the session
    user = subprocess.run(
        [sys.executable, "-m", "legws_daemon", "joystick", "sim-user", "--profile", str(profile),
         "--goal", goal, "--rate", str(rate * USER_RATE), "--duration", str(seconds),
         "--forever"],
        env=env, capture_output=True, timeout=seconds + 60, check=False,
    )  # fmt: skip
    daemon.wait(timeout=seconds + 60)
    if user.returncode != 0 or daemon.returncode != 0:
        raise SystemExit(f"run failed: {user.stderr.decode()[-500:]}")
    rows = [json.loads(line) for line in trace.read_text().splitlines()]
    return rows


def tick_stats(rows: list[dict[str, Any]], rate: float) -> dict[str, Any]:
    """Work percentiles, achieved rate and late intervals over the ticks with input."""
    active = [r for r in rows if r["seq"] is not None]
    work = np.array([r["work"] for r in active]) * 1e3
    begins = np.array([r["begin"] for r in active])
    gaps = np.diff(begins)
    span = begins[-1] - begins[0]
    return {
        "rate_hz": rate,
        "ticks": len(active),
        "work_ms_p50": float(np.percentile(work, 50)),
        "work_ms_p99": float(np.percentile(work, 99)),
        "work_ms_max": float(work.max()),
        "achieved_hz": float((len(active) - 1) / span) if span > 0 else 0.0,
        "late_fraction": float(np.mean(gaps > 1.5 / rate)) if len(gaps) else 0.0,
    }


def latency_stats(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Publish -> command latency for ticks that used a sample they had not used before."""
    seen: set[int] = set()
    total, transport, wait, work = [], [], [], []
    for r in rows:
        if r["seq"] is None or r["seq"] in seen:
            continue
        seen.add(r["seq"])
        total.append(r["wall_sent"] - r["stamp"])
        transport.append(r["wall_received"] - r["stamp"])
        wait.append(r["begin"] - r["received"])
        work.append(r["sent"] - r["begin"])
    out: dict[str, float] = {}
    for name, values in (("total", total), ("transport", transport), ("wait", wait),
                         ("work", work)):  # fmt: skip
        arr = np.array(values) * 1e3
        out[f"{name}_ms_p50"] = float(np.percentile(arr, 50))
        out[f"{name}_ms_p99"] = float(np.percentile(arr, 99))
    out["samples"] = float(len(total))
    return out


def shutdown_seconds(tmp: Path, runs: int) -> list[float]:
    """SIGTERM to exit of a running daemon with a Rerun recording, seconds, per run."""
    profile = profile_file(tmp)
    out = []
    for k in range(runs):
        rrd = tmp / f"shutdown-{k}.rrd"
        args = [sys.executable, "-m", "legws_daemon", "daemon", "--profile", str(profile),
                "--rerun", f"save:{rrd}"]  # fmt: skip
        proc = subprocess.Popen(args, env={**os.environ, "CI": "true"}, stderr=subprocess.PIPE)
        assert proc.stderr is not None
        for line in proc.stderr:  # wait until the loop runs
            if b"keys legws/" in line:
                break
        time.sleep(2.0)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=30)
        out.append(time.monotonic() - t0)
        verify = subprocess.run([rerun_cli(), "rrd", "verify",
                                 str(rrd)], capture_output=True, check=False)  # fmt: skip
        if code != 0 or verify.returncode != 0:
            raise SystemExit(f"shutdown run {k}: exit {code}, verify {verify.returncode}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", default="50,100,200,400,800")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "results" / "daemon_loop.json")
    a = ap.parse_args()
    results: dict[str, Any] = {"rates": []}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for rerun in (False, True):
            rows = run_pair(tmp, 20.0, 20.0, rerun)
            key = "at_20hz_rerun" if rerun else "at_20hz"
            results[key] = {**tick_stats(rows, 20.0), "latency": latency_stats(rows)}
            print(key, json.dumps(results[key], indent=1), flush=True)
        best = None
        for rate in (float(r) for r in a.rates.split(",")):
            rows = run_pair(tmp, rate, a.seconds, rerun=False)
            stats = {**tick_stats(rows, rate), "latency": latency_stats(rows)}
            stats["sustained"] = stats["achieved_hz"] >= 0.98 * rate and (
                stats["late_fraction"] < 0.01
            )
            results["rates"].append(stats)
            print(json.dumps(stats), flush=True)
            if stats["sustained"]:
                best = rate
        results["highest_sustained_hz"] = best
        stops = shutdown_seconds(tmp, 5)
        results["shutdown_s"] = {"median": float(np.median(stops)), "max": max(stops)}
        print("shutdown", results["shutdown_s"], flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"highest sustained rate: {best} Hz; wrote {a.out}")


if __name__ == "__main__":
    main()
