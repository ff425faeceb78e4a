"""Reachability map: build time, lookup speed, and agreement with the full grasp check.

* Build (or load from the cache) the default map; with ``--rebuild`` the build is timed
  afresh (wall and CPU seconds, BLAS limited to one thread).
* Lookup speed: ``ReachabilityMap.screen`` over 10^5 layouts of ``cluttered`` (M = 8)
  and ``meal_assembly`` (M = 5): random feasible layouts (``--distinct`` of them, repeated
  to 10^5; the cost of a lookup does not depend on which layout it is), medians over
  repeats, with and without computing the grasp poses.
* Agreement, per grasp, on random feasible layouts of ``meal_assembly`` and ``desk``:
  the screen against the full :func:`~legws_daemon.robot.feasibility.check_grasps` (IK from
  home and restarts, no contact with the table or any other object), and against the
  same check with every object moved away ("reach": IK and the table only, what the map
  stands for). Counts: both feasible, neither, screen-only (the screen passes a grasp
  the check rejects), full-only (the screen rejects a feasible grasp).

Usage:
    python benchmarks/reachability.py [--rebuild] [--layouts 300] [--seed 0]
        [--out docs/results/reachability.json]
"""

from __future__ import annotations

import os

# one core: numpy's BLAS must not spread the batched IK over threads (read at import)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
from timing import median_seconds
from tqdm import tqdm

from legws_daemon.robot import reachability
from legws_daemon.robot.assets import assets_dir
from legws_daemon.robot.feasibility import check_grasps
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.reachability import DEFAULT_GRID, ReachabilityMap
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.grasps import GRASP_KINDS
from legws_daemon.scene.scene import ObjectPose, Scene

LOOKUP_SCENES = ("cluttered", "meal_assembly")
AGREEMENT_SCENES = ("meal_assembly", "desk")


def world_of(name: str) -> tuple[World, np.ndarray]:
    sc = load_scene(name)
    w = World(sc)
    return w, home_configuration(w, sc.home.position, sc.home.rotation).q


def goal_poses(sc: Scene, cons: LayoutConstraints, poses: np.ndarray) -> np.ndarray:
    """``(B, M, 3)`` poses of the scene's goals out of layouts of the movable objects."""
    cols = [cons.names.index(n) for n in sc.goal_names]
    return poses[:, cols]


def tally(a: np.ndarray, b: np.ndarray) -> dict[str, Any]:
    """Per-grasp comparison of two verdicts (``a`` the screen or the cheaper check)."""
    n = int(a.size)
    both, neither = int((a & b).sum()), int((~a & ~b).sum())
    return {
        "grasps": n,
        "both_feasible": both,
        "neither": neither,
        "first_only": int((a & ~b).sum()),
        "second_only": int((~a & b).sum()),
        "agreement": (both + neither) / n if n else float("nan"),
    }


def build_or_load(rebuild: bool) -> tuple[ReachabilityMap, dict[str, Any]]:
    w, q_home = world_of("desk")
    key = reachability.cache_key(w, q_home)
    path = assets_dir() / "reachability" / f"{key}.npz"
    if rebuild:
        path.unlink(missing_ok=True)
    cached = path.is_file()
    t, c = time.perf_counter(), time.process_time()
    with tqdm(total=3, desc="map", unit="family", disable=cached) as bar:

        def progress(done: int, total: int) -> None:
            bar.update(done - bar.n)

        m = reachability.load_or_build(w, q_home, progress=progress)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    g = DEFAULT_GRID
    info = {
        "built_now": not cached,
        "build_seconds": m.build_seconds,
        "this_run_wall_s": wall,
        "this_run_cpu_s": cpu,
        "cells": g.cells(),
        "shape": {"top": list(g.shape("top")), "side": list(g.shape("side"))},
        "reachable_fraction": {
            "top": m.fraction("top"),
            "side_either_roll": m.fraction("side"),
            "side_upright": float(m.side.mean()),
            "side_rolled": float(m.side_flipped.mean()),
        },
        "key": m.key,
        "cache": str(path),
        "grid": json.loads(g.to_json()),
    }
    return m, info


def lookup_speed(m: ReachabilityMap, name: str, args: argparse.Namespace) -> dict[str, Any]:
    sc = load_scene(name)
    cons = LayoutConstraints.of(sc)
    t = time.perf_counter()
    distinct = cons.sample(args.distinct, np.random.default_rng(args.seed))
    sample_s = time.perf_counter() - t
    poses = goal_poses(sc, cons, np.tile(distinct, (args.lookups // args.distinct, 1, 1)))
    names = list(sc.goal_names)
    screen_s, _ = median_seconds(lambda: m.screen(sc, names, poses), args.repeats)
    pos, rot, sym = sc.grasp_batch(names, poses)
    kinds = {k: [j for j, n in enumerate(names) if sc.grasps[n].kind == k] for k in GRASP_KINDS}

    def only_lookup() -> None:
        for k, cols in kinds.items():
            if cols:
                m.lookup(k, pos[:, cols], rot[:, cols], sym[cols])

    lookup_s, _ = median_seconds(only_lookup, args.repeats)
    ok = m.screen(sc, names, poses)
    return {
        "layouts": len(poses),
        "m": len(names),
        "distinct_layouts": args.distinct,
        "sampling_distinct_s": sample_s,
        "screen_median_s": screen_s,
        "lookup_only_median_s": lookup_s,
        "per_layout_us": screen_s / len(poses) * 1e6,
        "per_grasp_ns": lookup_s / poses.shape[0] / poses.shape[1] * 1e9,
        "grasps_screened_reachable": float(ok.mean()),
        "layouts_all_reachable": float(ok.all(axis=1).mean()),
    }


def agreement(m: ReachabilityMap, args: argparse.Namespace) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in AGREEMENT_SCENES:
        w, q_home = world_of(name)
        sc = w.scene
        cons = LayoutConstraints.of(sc)
        rng = np.random.default_rng(args.seed + 1)
        layouts = cons.sample(args.layouts, rng)
        names = list(sc.goal_names)
        screen = m.screen(sc, names, goal_poses(sc, cons, layouts))
        full = np.zeros_like(screen)
        reach = np.zeros_like(screen)
        away = {n: ObjectPose(5.0, 0.0, 0.0) for n in sc.objects}
        t = time.perf_counter()
        for i in tqdm(range(len(layouts)), desc=name, unit="layout"):
            layout = cons.to_layout(layouts[i])
            goals = sc.goal_set(layout)
            checks = check_grasps(w, goals, q_home, sc.poses(layout))
            full[i] = [checks[n].feasible for n in names]
            w.set_layout(away)  # reach: IK and the table only
            checks = check_grasps(w, goals, q_home)
            reach[i] = [checks[n].feasible for n in names]
        seconds = time.perf_counter() - t
        per_object = {}
        for j, n in enumerate(names):
            per_object[n] = {
                "kind": sc.grasps[n].kind,
                "symmetry": sc.grasps[n].symmetry,
                "screen_vs_reach": tally(screen[:, j], reach[:, j]),
                "screen_vs_full": tally(screen[:, j], full[:, j]),
            }
        out[name] = {
            "layouts": len(layouts),
            "grasps": int(screen.size),
            "screen_vs_full": tally(screen, full),
            "screen_vs_reach": tally(screen, reach),
            "reach_vs_full": tally(reach, full),
            "layouts_all_feasible": {
                "screen": float(screen.all(axis=1).mean()),
                "full": float(full.all(axis=1).mean()),
                "reach": float(reach.all(axis=1).mean()),
            },
            "full_check_seconds_per_layout": seconds / len(layouts) / 2,
            "per_object": per_object,
        }
    return out


def markdown(out: dict[str, Any]) -> str:
    b = out["build"]
    f = b["reachable_fraction"]
    lines = [
        "| build | cells | wall | CPU (this run) | reachable: top | side (either roll) |",
        "|---|---|---|---|---|---|",
        f"| {'fresh' if b['built_now'] else 'cached'} | {b['cells']:,} | "
        f"{b['build_seconds']:.0f} s | {b['this_run_cpu_s']:.0f} s | {f['top']:.1%} | "
        f"{f['side_either_roll']:.1%} |",
        "",
        "| lookups | layouts × M | screen (median) | per layout | lookup only, per grasp |"
        " layouts all reachable |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in out["lookups"].items():
        lines.append(
            f"| {name} | {r['layouts']:,} × {r['m']} | {r['screen_median_s'] * 1e3:.0f} ms | "
            f"{r['per_layout_us']:.2f} µs | {r['per_grasp_ns']:.0f} ns | "
            f"{r['layouts_all_reachable']:.1%} |"
        )
    lines += [
        "",
        "| agreement | grasps | vs | both feasible | neither | screen only | check only |"
        " agreement |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in out["agreement"].items():
        for label, key in (("full check", "screen_vs_full"), ("reach + table", "screen_vs_reach")):
            t = r[key]
            lines.append(
                f"| {name} | {t['grasps']} | {label} | {t['both_feasible']} | {t['neither']} | "
                f"{t['first_only']} | {t['second_only']} | {t['agreement']:.1%} |"
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rebuild", action="store_true", help="time a fresh build of the map")
    ap.add_argument("--layouts", type=int, default=300, help="layouts per agreement scene")
    ap.add_argument("--lookups", type=int, default=100_000)
    ap.add_argument("--distinct", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("docs/results/reachability.json"))
    args = ap.parse_args()
    out: dict[str, Any] = {
        "machine": {
            "python": platform.python_version(),
            "processor": platform.machine(),
            "cpus": os.cpu_count(),
            "load_average_at_start": os.getloadavg(),
        },
        "numpy": np.__version__,
    }
    m, out["build"] = build_or_load(args.rebuild)
    out["lookups"] = {name: lookup_speed(m, name, args) for name in LOOKUP_SCENES}
    out["agreement"] = agreement(m, args)
    out["machine"]["load_average_at_end"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(markdown(out))
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
