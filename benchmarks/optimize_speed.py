"""Seconds of ``legws optimize``'s search per scene and objective (issue 28, point 8: target
≤ 15 s per scene for every objective and for an operator with bias and quantised steering).

What is timed: ``design.search.search`` of a ``LayoutProblem`` with the reachability screen
(what ``legws optimize`` runs, 1000 iterations of 3 × 30 layouts by default) — not the
verification of elites, the rendering or the writing of the run folder, which take the same
time for every objective. Each row is the median of ``--repeats`` searches with different
seeds, after one warm-up search in the same process (numba's compiled kernels then come from
its cache; ``cold`` is that first search in a fresh process, compile time included when the
cache is empty). The operator row designs for ``OperatorModel(0.8, 0.03, 0.5, 20°, axes)``.

Usage:
    python benchmarks/optimize_speed.py [--repeats 3] [--iterations 1000]
        [--scenes breakfast_easy,desk,...] [--objectives slack,commit,rate,time]
        [--out docs/results/optimize_speed.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.design.search import search
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.reachability import load_or_build
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene

SCENES = ("breakfast_easy", "desk", "breakfast", "kitchen_prep", "meal_assembly", "cluttered")
OBJECTIVES = ("slack", "commit", "rate", "time")
OPERATOR = OperatorModel(0.8, 0.03, 0.5, 20.0, "axes")
TARGET_S = 15.0
PAPER = "section 2's user"


def timed(problem: LayoutProblem, iterations: int, seed: int) -> float:
    started = time.perf_counter()
    search(problem, "cma-me", iterations, seed)
    return time.perf_counter() - started


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--objectives", default=",".join(OBJECTIVES))
    ap.add_argument("--out", type=Path, default=Path("docs/results/optimize_speed.json"))
    args = ap.parse_args()
    rows: list[dict[str, Any]] = []
    first = True
    for name in args.scenes.split(","):
        scene = load_scene(name)
        world = World(scene)
        q_home = home_configuration(world, scene.home.position, scene.home.rotation).q
        screen = load_or_build(world, q_home)
        for objective in args.objectives.split(","):
            for who, ops in ((PAPER, ()), ("operator", (OPERATOR,))):
                problem = LayoutProblem(scene, None, Params(), screen, objective=objective,
                                        operators=ops)  # fmt: skip
                cold = timed(problem, args.iterations, 100) if first else None
                first = False
                if cold is None:
                    timed(problem, min(args.iterations, 50), 100)  # warm-up
                times = [timed(problem, args.iterations, s) for s in range(args.repeats)]
                median = statistics.median(times)
                rows.append({
                    "scene": name, "objective": objective, "for": who, "seconds": median,
                    "runs": times, "cold": cold, "met": median <= TARGET_S,
                })  # fmt: skip
                print(
                    f"{name:15s} {objective:7s} {who:17s} {median:6.1f} s "
                    f"({', '.join(f'{t:.1f}' for t in times)})",
                    flush=True,
                )
    out = {
        "machine": {
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "load_average": os.getloadavg(),
        },
        "iterations": args.iterations,
        "repeats": args.repeats,
        "operator": OPERATOR.as_dict(),
        "target_seconds": TARGET_S,
        "rows": rows,
    }
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    lines = ["| scene | objective | section 2's user, s | operator, s |", "|---|---|---|---|"]
    for name in args.scenes.split(","):
        for objective in args.objectives.split(","):
            cells = [r for r in rows if r["scene"] == name and r["objective"] == objective]
            by = {r["for"]: r["seconds"] for r in cells}
            lines.append(f"| {name} | {objective} | {by[PAPER]:.1f} | {by['operator']:.1f} |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
