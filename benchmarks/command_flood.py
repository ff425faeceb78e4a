"""A burst of commands against the daemon: the control loop must not stall.

The real ``legws daemon`` (sim profile, paced to real time, ``--trace``) and one zenoh client
on loopback that sends ``--queries`` concurrent ``load_scene`` queries at once (cycling
through the catalogue's scenes), ``--waves`` times, a wave as soon as the last one is
answered, while it records the daemon's status messages. Reported:

- tick work (the trace's ``work``: everything a tick does, a swapped-in load included) p50 /
  p99 / max over the flood (from the first query to the last reply plus a second), and the
  p99 of the 3 quiet seconds before it;
- status rate: the lowest count in any 1-s window of the flood, and the longest gap;
- the replies: carried out, ``busy`` (the queue full, or not taken up within 5 s: nothing
  was done), errors; and how long the slowest reply took.

Usage:
    python benchmarks/command_flood.py [--queries 40] [--waves 15] [--repeats 3]
        [--out docs/results/command_flood.json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

REPO = Path(__file__).resolve().parents[1]
ROBOT = "sawyer_sim"
SCENES = ["breakfast_easy", "desk", "kitchen_prep", "breakfast", "meal_assembly"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def client(port: int) -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", "[]")
    config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return zenoh.open(config)


def one_run(
    tmp: Path, queries: int, waves: int, client_nice: int = 0, realtime: int = 0
) -> dict[str, Any]:
    port = free_port()
    text = (REPO / "hw_profiles" / "sim.toml").read_text()
    assert "realtime_priority = 0" in text
    text = text.replace("realtime_priority = 0", f"realtime_priority = {realtime}")
    profile = tmp / f"flood-{port}.toml"
    profile.write_text(text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}"))
    trace = tmp / f"trace-{port}.jsonl"
    env = {**os.environ, "CI": "true"}
    daemon = subprocess.Popen(
        [sys.executable, "-m", "legws_daemon", "daemon", "--profile", str(profile),
         "--scene", "desk", "--duration", "300", "--trace", str(trace)],
        env=env, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    status: list[float] = []
    replies: list[tuple[str, float]] = []
    span: dict[str, float] = {}
    granted: dict[str, int] = {}
    lock = threading.Lock()

    def run_flood() -> None:
        session = client(port)
        try:

            def on_status(sample: zenoh.Sample) -> None:
                status.append(time.monotonic())
                granted["realtime_priority"] = json.loads(sample.payload.to_bytes()).get(
                    "realtime_priority", 0
                )

            sub = session.declare_subscriber(f"legws/{ROBOT}/status", on_status)
            deadline = time.monotonic() + 60
            while len(status) < 20:
                if time.monotonic() > deadline or daemon.poll() is not None:
                    raise SystemExit("the daemon did not start")
                time.sleep(0.1)
            time.sleep(4.0)  # the quiet baseline: the 3 s before the flood

            def ask(i: int) -> None:
                body = {"schema": 1, "command": "load_scene", "argument": SCENES[i % len(SCENES)]}
                t0 = time.monotonic()
                outcome = "no reply"
                for reply in session.get(
                    f"legws/{ROBOT}/command", payload=json.dumps(body).encode(), timeout=120.0
                ):
                    if reply.ok is not None:
                        outcome = "ok"
                    else:
                        error = json.loads(reply.err.payload.to_bytes()).get("error", "")
                        outcome = "busy" if error.startswith("busy") else f"error: {error}"
                    break
                with lock:
                    replies.append((outcome, time.monotonic() - t0))

            span["start"] = time.monotonic()
            for _ in range(waves):
                threads = [threading.Thread(target=ask, args=(i,)) for i in range(queries)]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(180)
            span["end"] = time.monotonic() + 1.0
            time.sleep(2.0)
            sub.undeclare()  # type: ignore[no-untyped-call]
        finally:
            session.close()  # type: ignore[no-untyped-call]
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(30)

    if client_nice:
        # the client's own thread (and the zenoh threads it starts) at a lower priority;
        # the daemon, started above, keeps its own
        def niced() -> None:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), client_nice)
            run_flood()

        runner = threading.Thread(target=niced)
        runner.start()
        runner.join()
    else:
        run_flood()
    if "end" not in span:
        raise SystemExit("the flood did not finish")
    start, end = span["start"], span["end"]
    rows = [json.loads(line) for line in trace.read_text().splitlines() if line.strip()]
    flood = [r for r in rows if start <= r["begin"] <= end]
    work = np.array([r["work"] for r in flood]) * 1000
    # ticks that carried out a command or swapped a load in, and the others
    busy = np.array([r["work"] for r in flood if r["commands"]]) * 1000
    plain = np.array([r["work"] for r in flood if not r["commands"]]) * 1000
    quiet = np.array([r["work"] for r in rows if start - 3.0 <= r["begin"] < start]) * 1000
    times = np.array([t for t in status if start <= t <= end])
    windows = [
        int(np.sum((times >= a) & (times < a + 1.0))) for a in np.arange(start, end - 1.0, 0.1)
    ]
    outcomes: dict[str, int] = {}
    for outcome, _ in replies:
        outcomes[outcome] = outcomes.get(outcome, 0) + 1
    return {
        "queries": queries,
        "waves": waves,
        "flood_seconds": round(end - start, 2),
        "ticks": int(work.size),
        "quiet_tick_ms_p99": round(float(np.percentile(quiet, 99)), 2),
        "tick_ms_p50": round(float(np.percentile(work, 50)), 2),
        "tick_ms_p99": round(float(np.percentile(work, 99)), 2),
        "tick_ms_max": round(float(work.max()), 2),
        "ticks_with_commands": int(busy.size),
        "with_commands_ms_p50": round(float(np.percentile(busy, 50)), 2) if busy.size else None,
        "with_commands_ms_max": round(float(busy.max()), 2) if busy.size else None,
        "without_commands_ms_p99": round(float(np.percentile(plain, 99)), 2),
        "status_min_per_1s": min(windows) if windows else 0,
        "status_longest_gap_s": round(float(np.max(np.diff(times))), 3),
        "loop_realtime_priority": granted.get("realtime_priority", 0),
        "replies": outcomes,
        "slowest_reply_s": round(max(d for _, d in replies), 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=40)
    parser.add_argument("--waves", type=int, default=15)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=REPO / "docs/results/command_flood.json")
    parser.add_argument(
        "--client-nice",
        type=int,
        default=0,
        help="run the flooding client at this nice value (the daemon stays at 0): 10 plays a "
        "client on another machine, which takes no CPU from the daemon",
    )
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=0,
        help="the profile's control.realtime_priority (SCHED_FIFO for the loop; 0: normal)",
    )
    args = parser.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            run = one_run(
                Path(tmp), args.queries, args.waves, args.client_nice, args.realtime_priority
            )
            print(f"run {i + 1}: {json.dumps(run)}", flush=True)
            runs.append(run)
    summary = {
        "command": (
            f"./dev bench command_flood --queries {args.queries} --waves {args.waves} "
            f"--repeats {args.repeats}"
            + (f" --client-nice {args.client_nice}" if args.client_nice else "")
            + (f" --realtime-priority {args.realtime_priority}" if args.realtime_priority else "")
        ),
        "client_nice": args.client_nice,
        "realtime_priority": args.realtime_priority,
        "runs": runs,
        "tick_ms_p99_median": float(np.median([r["tick_ms_p99"] for r in runs])),
        "tick_ms_max_worst": max(r["tick_ms_max"] for r in runs),
        "status_min_per_1s_worst": min(r["status_min_per_1s"] for r in runs),
    }
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items() if k != "runs"}))


if __name__ == "__main__":
    main()
