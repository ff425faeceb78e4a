"""How early can commits be in a tier at all? The commit objective without joystick noise.

With ``sigma -> 0`` the commit certificate (method.md §9, exact-sum form) reduces to the
geometry: a goal's commit comes before arrival only if, at its own grasp, every other goal
is far enough off the straight way, ``sum_g exp(-beta (C_g - C_g*)) <= (1-p)/p``. The same
search as ``legws optimize --objective commit`` (CMA-ME, the scene's constraints and
reachability screen) then finds the best a layout of the workspace can do for a noise-free
user: if even that ``K`` is above 1, no layout of the workspace lets every goal commit before
arrival, however the search is run. Reported per scene: the noise-free best ``K``, how many
goals it certifies, and the same for the real noise (``sigma = 0.03``) over the same search.

Usage:
    python benchmarks/commit_bound.py [--scenes cluttered,meal_assembly] [--iterations 1000]
        [--seed 0] [--out docs/results/commit_bound.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.core.commit import commit_batch
from legws_daemon.core.params import Params
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.design.search import search
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.reachability import load_or_build
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene

#: Joystick noise of the noise-free bound (the model needs sigma > 0), m/s.
NOISE_FREE = 1e-9


def best(name: str, sigma: float, iterations: int, seed: int) -> dict[str, Any]:
    sc = load_scene(name)
    params = Params(sigma=sigma)
    world = World(sc)
    q_home = home_configuration(world, sc.home.position, sc.home.rotation).q
    problem = LayoutProblem(sc, params=params, objective="commit", commit_form="sum")
    problem.screen = load_or_build(world, q_home)
    started = time.perf_counter()
    result = search(problem, "cma-me", iterations, seed)
    feasible = [row for row in result.table if row["feasible_screen"]]
    top = min(feasible, key=lambda r: r["commit_objective"])
    i = result.table.index(top)
    poses = problem.decode(result.elites[i].solution)
    g = problem.goals.poses(poses)
    batch = commit_batch(sc.home.position, sc.home.rotation, g.positions, g.rotations,
                         g.symmetry, params, form="sum")  # fmt: skip
    return {
        "sigma": sigma,
        "best_K": float(batch.objective[0]),
        "certified": int(batch.count[0]),
        "goals": len(problem.names),
        "fractions": [float(x) for x in np.sort(batch.fraction[0])],
        "archive_feasible_cells": len(feasible),
        "seconds": time.perf_counter() - started,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="cluttered,meal_assembly")
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("docs/results/commit_bound.json"))
    args = ap.parse_args()
    out: dict[str, Any] = {}
    for name in args.scenes.split(","):
        out[name] = {
            "noise_free": best(name, NOISE_FREE, args.iterations, args.seed),
            "noisy": best(name, Params().sigma, args.iterations, args.seed),
        }
        print(name, json.dumps(out[name]))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
