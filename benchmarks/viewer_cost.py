"""What watching costs: the daemon's tick with a live Rerun web viewer, and recording sizes.

Real processes on loopback, the sim profile at 20 Hz: ``legws daemon --trace`` and
``legws joystick sim-user`` reaching for one object again and again (``--forever``: commit,
assistance, back home), for ``--seconds`` of steering in each of three set-ups:

1. no telemetry;
2. a recording (``--rerun save:``);
3. a recording and the web viewer (``--rerun save: --rerun web:PORT``) with a real browser
   (Debian's Chromium, headless, software WebGL) showing the page the whole time: the
   browser is connected and has drawn the arm (red pixels in the 3D view) before the user
   starts.

It reports the tick work (p50 / p99 / max, from the trace), the recording's size per minute
of session (the arm's meshes are a fixed part, sent once: reported apart), and the daemon's
peak memory.

Usage:
    python benchmarks/viewer_cost.py [--seconds 60] [--out docs/results/viewer_cost.json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.daemon_loop import tick_stats  # noqa: E402
from tests.net import free_port, free_port_pair  # noqa: E402

RATE = 20.0
#: Start-up of the daemon (imports, the MuJoCo model, the session), s.
STARTUP = 4.0


def _profile(tmp: Path, port: int, priority: int) -> Path:
    text = (REPO / "hw_profiles" / "sim.toml").read_text()
    text = text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
    text = re.sub(r"(?m)^realtime_priority = 0", f"realtime_priority = {priority}", text)
    path = tmp / "bench.toml"
    path.write_text(text)
    return path


def _red_pixels(rgb: np.ndarray) -> int:
    h, w, _ = rgb.shape
    view = rgb[: int(h * 0.75), : int(w * 0.6)].astype(int)
    return int(((view[..., 0] > 140) & (view[..., 1] < 70) & (view[..., 2] < 70)).sum())


class Browser:
    """Chromium showing ``url`` on its own thread until :meth:`close`; ``ready`` is set
    once the arm is drawn."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.ready = threading.Event()
        self.error: str | None = None
        self._stop = threading.Event()
        self.seconds_to_ready: float | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import io

        from PIL import Image
        from playwright.sync_api import sync_playwright

        from tests.browser import CHROMIUM, FLAGS

        t0 = time.monotonic()
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                            args=FLAGS)  # fmt: skip
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                page.goto(self.url, wait_until="load", timeout=120_000)
                while not self._stop.is_set():
                    if not self.ready.is_set():
                        png = page.screenshot(timeout=60_000)
                        rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
                        if _red_pixels(rgb) > 3000:
                            self.seconds_to_ready = time.monotonic() - t0
                            (Path(tempfile.gettempdir()) / "viewer_cost.png").write_bytes(png)
                            self.ready.set()
                    self._stop.wait(2.0)
                browser.close()
        except Exception as exc:  # reported by the caller
            self.error = f"{type(exc).__name__}: {exc}"
            self.ready.set()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(30)


def run(tmp: Path, seconds: float, setup: str, priority: int) -> dict[str, Any]:
    port = free_port()
    profile = _profile(tmp, port, priority)
    trace = tmp / f"trace-{setup}.jsonl"
    rrd = tmp / f"{setup}.rrd"
    web_port = free_port_pair()
    budget = STARTUP + seconds + (150.0 if setup == "web" else 0.0) + 10.0
    args = [sys.executable, "-m", "legws_daemon", "daemon", "--profile", str(profile),
            "--rate", str(RATE), "--duration", str(budget), "--trace", str(trace)]  # fmt: skip
    if setup in ("save", "web"):
        args += ["--rerun", f"save:{rrd}"]
    if setup == "web":
        args += ["--rerun", f"web:{web_port}"]
    env = {**os.environ, "CI": "true", "RERUN_TELEMETRY_ENABLED": "false"}
    daemon = subprocess.Popen(args, env=env, stderr=subprocess.DEVNULL)
    browser = None
    result: dict[str, Any] = {"setup": setup, "realtime_priority": priority}
    try:
        time.sleep(STARTUP)
        if setup == "web":
            from legws_daemon.telemetry.web_viewer import parse_web_target

            browser = Browser(parse_web_target(str(web_port)).page_url)
            if not browser.ready.wait(150.0) or browser.error:
                raise SystemExit(f"the browser never showed the arm: {browser.error}")
            result["browser_ready_s"] = browser.seconds_to_ready
        t0 = time.monotonic()
        user = subprocess.run(
            [sys.executable, "-m", "legws_daemon", "joystick", "sim-user", "--profile",
             str(profile), "--goal", "white_mug", "--rate", str(RATE * 1.07), "--duration",
             str(seconds), "--forever"],
            env=env, capture_output=True, timeout=seconds + 60, check=False,
        )  # fmt: skip
        steered = time.monotonic() - t0
        if user.returncode != 0:
            raise SystemExit(f"sim-user failed: {user.stderr.decode()[-400:]}")
    finally:
        if browser is not None:
            browser.close()
        daemon.terminate()
        daemon.wait(60)
    rows = [json.loads(line) for line in trace.read_text().splitlines()]
    result.update(tick_stats(rows, RATE))
    result["steered_s"] = steered
    if rrd.exists():
        size = rrd.stat().st_size
        result["recording_mib"] = size / 2**20
        ticks = len(rows)
        result["recording_minutes"] = ticks / RATE / 60
    return result


def _mesh_mib() -> float:
    """The arm's meshes alone, as logged (a recording of the set-up and nothing else)."""
    from legws_daemon.robot.visual import robot_visual
    from legws_daemon.robot.world import World
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.telemetry.rerun_log import RerunLog

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "meshes.rrd"
        with RerunLog(f"save:{path}", robot="sawyer") as log:
            log.log_robot(robot_visual(World(load_scene("tea"))))
        return path.stat().st_size / 2**20


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--setups", default="none,save,web")
    ap.add_argument(
        "--priorities",
        default="0,50",
        help="the loop's SCHED_FIFO priorities to measure (0: normal; needs CAP_SYS_NICE)",
    )
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "results" / "viewer_cost.json")
    a = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for priority in (int(x) for x in a.priorities.split(",")):
            for setup in a.setups.split(","):
                r = run(Path(tmp), a.seconds, setup, priority)
                results.append(r)
                print(json.dumps(r), flush=True)
    meshes = _mesh_mib()
    for r in results:
        if "recording_mib" in r:
            # per minute of steering (the file less the meshes, which it holds once)
            r["per_minute_mib"] = (r["recording_mib"] - meshes) / (r["steered_s"] / 60)
    report = {
        "rate_hz": RATE,
        "seconds": a.seconds,
        "mesh_mib": meshes,
        "load": os.getloadavg(),
        "max_rss_children_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
        "runs": results,
    }
    a.out.write_text(json.dumps(report, indent=1) + "\n")
    print("| set-up | loop priority | tick p50 / p99 / max (ms) | late | recording per minute |")
    for r in results:
        size = f"{r['per_minute_mib']:.2f} MiB" if "per_minute_mib" in r else "—"
        print(f"| {r['setup']} | {r['realtime_priority']} | {r['work_ms_p50']:.2f} / "
              f"{r['work_ms_p99']:.2f} / {r['work_ms_max']:.1f} | "
              f"{100 * r['late_fraction']:.1f} % | {size} |")  # fmt: skip
    print(f"arm meshes (once per recording): {meshes:.2f} MiB")


if __name__ == "__main__":
    main()
