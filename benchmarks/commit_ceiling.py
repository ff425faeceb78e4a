"""How many commits can a layout of a tier give at all? The commit *rate* searched directly.

The commit objective ``K`` (method.md §9) bounds the worst goal; the person sees the rate
over all goals. This benchmark searches layouts for the rate itself: the same CMA-ME search
as ``legws optimize --objective rate`` (the scene's constraints and reachability screen,
1000 iterations): the score is ``R``, the mean over goals of
:func:`~legws_daemon.core.commit.commit_chance_batch` (the estimated chance of a commit on the
true goal before arrival, for the robot's speed-clipped user). Then, per scene:

* the ``--verify`` best feasible elites of every seed are measured by Monte Carlo
  (:func:`~legws_daemon.core.montecarlo.simulate_commits`, clipped user, ``--trials`` per
  goal), with a Clopper–Pearson interval on the best one;
* the ``--top-k`` best of those by Monte Carlo are run on the unified loop (``legws eval``'s
  code, ``--episodes-per-goal`` picks per goal), the rate a person gets;
* the same Monte Carlo on ``--random`` random feasible layouts, for scale.

Usage:
    python benchmarks/commit_ceiling.py [--scenes cluttered] [--seeds 0,1,2]
        [--iterations 1000] [--verify 20] [--trials 200] [--top-k 3]
        [--episodes-per-goal 10] [--random 300] [--out docs/results/commit_ceiling.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from legws_daemon.core.montecarlo import clopper_pearson, commit_rates, simulate_commits
from legws_daemon.core.params import Params
from legws_daemon.design.problem import (
    LayoutProblem,
)
from legws_daemon.design.search import search
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.reachability import load_or_build
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.layout_file import layout_from_data, layout_to_data
from legws_daemon.scene.scene import Scene
from legws_daemon.sim.evaluate import Elite, run_eval

#: What the benchmark keeps of each layout's loop evaluation.
LOOP_KEYS = ("commit_true_rate", "commit_rate_min_goal", "wrong_commit_rate", "t_infer_km_median")


def mc_rate(sc: Scene, layout: Any, params: Params, trials: int, seed: int) -> dict[str, Any]:
    """Monte Carlo commits before arrival on the true goal, clipped user."""
    gs = sc.goal_set(layout)
    roll = simulate_commits(gs, params, trials, np.random.default_rng([seed, 91]),
                            clip_speed=True)[params.cost]  # fmt: skip
    rates = commit_rates(roll, [None] * gs.m, gs.names)
    hits = sum(round(r.before_arrival * trials) for r in rates.values())
    lo, hi = clopper_pearson(hits, trials * gs.m)
    return {
        "rate": hits / (trials * gs.m),
        "lower95": lo,
        "upper95": hi,
        "min_goal": min(r.before_arrival for r in rates.values()),
        "wrong": float(np.mean([r.wrong for r in rates.values()])),
    }


def ceiling(name: str, args: argparse.Namespace) -> dict[str, Any]:
    sc = load_scene(name)
    params = Params()
    world = World(sc)
    q_home = home_configuration(world, sc.home.position, sc.home.rotation).q
    screen = load_or_build(world, q_home)
    candidates: list[tuple[float, int, Any]] = []
    runs = []
    for seed in args.seeds:
        problem = LayoutProblem(sc, params=params, objective="rate")
        problem.screen = screen
        with tqdm(total=args.iterations, desc=f"{name} seed {seed}", unit="it") as bar:

            def tick(_it: int, best: float, _coverage: float) -> None:
                bar.set_postfix(best=f"{best:.3f}", refresh=False)
                bar.update()

            result = search(problem, "cma-me", args.iterations, seed, progress=tick)
        rows = [(i, r) for i, r in enumerate(result.table) if r["feasible_screen"]]
        rows.sort(key=lambda ir: -ir[1]["commit_rate_estimate"])
        runs.append({
            "seed": seed,
            "seconds": result.seconds,
            "feasible_cells": len(rows),
            "best_chance": rows[0][1]["commit_rate_estimate"] if rows else None,
        })  # fmt: skip
        for i, r in rows[: args.verify]:
            layout = problem.layout(result.elites[i].solution)
            candidates.append((r["commit_rate_estimate"], seed, layout))
    verified: list[dict[str, Any]] = []
    for chance, seed, layout in tqdm(candidates, desc=f"{name} Monte Carlo", unit="layout"):
        mc = mc_rate(sc, layout, params, args.trials, len(verified))
        verified.append({"seed": seed, "chance": chance, **mc, "layout": layout_to_data(layout)})
    verified.sort(key=lambda v: -v["rate"])
    cons = LayoutConstraints.of(sc, sc.goal_names)
    rng = np.random.default_rng([0, 78])
    random_rates = [
        mc_rate(sc, cons.to_layout(p), params, 50, k)["rate"]
        for k, p in enumerate(tqdm(cons.sample(args.random, rng), desc=f"{name} random"))
    ]
    top = verified[: args.top_k]
    loop = None
    if top:
        layouts = [layout_from_data(v["layout"], sc, "commit_ceiling") for v in top]
        elites = [Elite(f"commit_ceiling seed {v['seed']}", k, k + 1, v["chance"])
                  for k, v in enumerate(top)]  # fmt: skip
        with tqdm(total=len(layouts), desc=f"{name} loop", unit="layout") as bar:
            report = run_eval(sc, layouts, 0, workers=args.workers, elites=elites,
                              episodes_per_goal=args.episodes_per_goal,
                              progress=bar.update)  # fmt: skip
        loop = {
            "aggregate": report["aggregate"],
            "per_layout": [{k: pl[k] for k in LOOP_KEYS} for pl in report["per_layout"]],
        }
    corr = np.corrcoef([v["chance"] for v in verified], [v["rate"] for v in verified])[0, 1]
    return {
        "goals": len(sc.goal_names),
        "runs": runs,
        "verified": verified,
        "best_monte_carlo": verified[0] if verified else None,
        "chance_vs_monte_carlo_correlation": float(corr),
        "random": {
            "layouts": args.random,
            "median": float(np.median(random_rates)),
            "best": float(np.max(random_rates)),
        },
        "loop": loop,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="cluttered")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--verify", type=int, default=20)
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--top-k", type=int, default=3)
    ap.add_argument("--episodes-per-goal", type=int, default=10)
    ap.add_argument("--random", type=int, default=300)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("docs/results/commit_ceiling.json"))
    args = ap.parse_args()
    args.seeds = [int(s) for s in args.seeds.split(",")]
    out: dict[str, Any] = json.loads(args.out.read_text()) if args.out.is_file() else {}
    for name in args.scenes.split(","):
        started = time.perf_counter()
        out[name] = ceiling(name, args)
        out[name]["seconds"] = time.perf_counter() - started
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=2) + "\n")
        best = out[name]["best_monte_carlo"]
        loop = out[name]["loop"]
        print(name, "best Monte Carlo rate", best and best["rate"],
              "loop", loop and loop["aggregate"]["commit_true_rate"])  # fmt: skip


if __name__ == "__main__":
    main()
