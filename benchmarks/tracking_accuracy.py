"""How well does the camera tracker measure the objects? Random layouts of the tea scene.

Each of N random feasible layouts of the scene's movable objects (uniform over the layout
constraints, method.md §5; the fixed cup and plate stay put) is rendered by the MuJoCo
stand-in's camera (:class:`~legws_daemon.tracking.sim_camera.SimCamera`, the arm at home)
and tracked (:class:`~legws_daemon.tracking.tracker.Tracker`, the camera's pose solved
from the table markers in every frame). Per object and frame: the position error (the
distance of the measured centre from the true one, mm) and the yaw error (the marker gives
a unique yaw, so it is compared with the true yaw modulo 2π, degrees). Reported: median,
95th percentile and maximum of both, the fraction of objects measured, and the frames per
second of rendering and of tracking (detection and poses), timed separately.

Usage:
    MUJOCO_GL=egl python benchmarks/tracking_accuracy.py [--layouts 100] [--seed 0]
        [--width 640] [--height 480] [--out docs/results/tracking_accuracy.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.scene import Layout, ObjectPose
from legws_daemon.tracking.sim_camera import SimCamera
from legws_daemon.tracking.tracker import Tracker, TrackFrame

SCENE = "tea"


def layouts(n: int, seed: int) -> list[Layout]:
    """``n`` random feasible layouts of the tea scene's movable objects."""
    scene = load_scene(SCENE)
    cons = LayoutConstraints.of(scene, scene.movable)
    rows = cons.sample(n, np.random.default_rng([seed, 0x7EA]))
    return [cons.to_layout(row) for row in rows]


def errors(
    frame: TrackFrame, truth: dict[str, ObjectPose], names: tuple[str, ...]
) -> tuple[list[float], list[float], int]:
    """Position errors (mm), yaw errors (deg) of the measured objects, and how many were."""
    pos, yaw = [], []
    for n in names:
        p = frame.poses.get(n)
        if p is None:
            continue
        t = truth[n]
        pos.append(1000.0 * float(np.hypot(p.x - t.x, p.y - t.y)))
        yaw.append(float(np.degrees(abs((p.yaw - t.yaw + np.pi) % (2 * np.pi) - np.pi))))
    return pos, yaw, len(pos)


def stats(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values)
    return {
        "median": float(np.median(arr)),
        "p95": float(np.percentile(arr, 95)),
        "max": float(np.max(arr)),
    }


def run(n: int, seed: int, width: int, height: int) -> dict[str, Any]:
    scene = load_scene(SCENE)
    names = tuple(scene.objects)
    with SimCamera(scene, width=width, height=height) as camera:
        tracker = Tracker(scene, camera.intrinsics)
        camera.render()  # warm-up: first frame uploads the textures
        pos: list[float] = []
        yaw: list[float] = []
        seen = total = 0
        warnings: list[str] = []
        render_s = track_s = 0.0
        for layout in layouts(n, seed):
            t0 = time.perf_counter()
            image = camera.render(layout)
            t1 = time.perf_counter()
            frame = tracker.process(image)
            t2 = time.perf_counter()
            render_s += t1 - t0
            track_s += t2 - t1
            p, y, k = errors(frame, scene.poses(layout), names)
            pos += p
            yaw += y
            seen += k
            total += len(names)
            warnings += frame.warnings
        intrinsics = camera.intrinsics
        cam_pose = camera.pose
    return {
        "scene": SCENE,
        "layouts": n,
        "seed": seed,
        "image": [width, height],
        "camera": {
            "position": [round(float(v), 4) for v in cam_pose.position],
            "fovy_deg": round(
                float(np.degrees(2 * np.arctan(height / 2 / intrinsics.matrix[1, 1]))), 3
            ),
        },
        "position_error_mm": stats(pos),
        "yaw_error_deg": stats(yaw),
        "seen_fraction": seen / total,
        "objects_measured": seen,
        "objects_total": total,
        "render_fps": n / render_s,
        "track_fps": n / track_s,
        "warnings": sorted(set(warnings)),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
    }


def markdown(r: dict[str, Any]) -> str:
    pe, ye = r["position_error_mm"], r["yaw_error_deg"]
    w, h = r["image"]
    return "\n".join(
        [
            f"Tracking accuracy, scene `{r['scene']}`, {r['layouts']} random layouts at "
            f"{w} × {h} (seed {r['seed']})",
            "",
            "| measure | median | p95 | max |",
            "|---|---|---|---|",
            f"| position error (mm) | {pe['median']:.2f} | {pe['p95']:.2f} | {pe['max']:.2f} |",
            f"| yaw error (deg) | {ye['median']:.2f} | {ye['p95']:.2f} | {ye['max']:.2f} |",
            "",
            f"Objects measured: {r['objects_measured']} of {r['objects_total']} "
            f"({100 * r['seen_fraction']:.1f} %). Render {r['render_fps']:.1f} frames/s, "
            f"tracking {r['track_fps']:.1f} frames/s.",
        ]
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--out", type=Path, default=Path("docs/results/tracking_accuracy.json"))
    args = ap.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    result = run(args.layouts, args.seed, args.width, args.height)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(markdown(result))


if __name__ == "__main__":
    main()
