"""Is the certificate honest? Random feasible layouts, both cost forms, Monte Carlo on each.

For M in {2, 3, 5, 8} (scenes breakfast_easy, desk, meal_assembly, cluttered, with their
fixed clutter) draw N random feasible layouts as in method.md §5, compute J for the
``dragan`` and ``ratio`` cost forms, and on every layout certified by either form run the
Monte Carlo check (trials per goal, the same trajectories for both forms), once with the
certificate's unclipped user model and once with the robot's speed clip ``|v| <= v_max``.
A certified layout *violates* 1 - alpha when some goal's accuracy at the horizon is below
1 - alpha; *significantly* when even the Clopper-Pearson 95 % upper bound is below it.

Usage:
    python benchmarks/certificate_validity.py [--layouts 500] [--trials 2000] [--seed 0]
        [--workers 2] [--out docs/results/certificate_validity.json]
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.geometry import matrix_to_quat
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.montecarlo import monte_carlo
from legws_daemon.core.params import Params
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.workers import worker_context

SCENES = {2: "breakfast_easy", 3: "desk", 5: "meal_assembly", 8: "cluttered"}
FORMS = ("dragan", "ratio")


def _check(job: tuple[str, np.ndarray, int, int]) -> dict[str, Any]:
    """Monte Carlo of one layout, both forms, unclipped and clipped."""
    scene_name, poses, trials, seed = job
    sc = load_scene(scene_name)
    names = sc.goal_names
    pos, rot, sym = sc.grasp_batch(names, poses[None])
    goals = GoalSet(names, pos[0], matrix_to_quat(rot[0]), sym, sc.home)
    out: dict[str, Any] = {}
    for clip in (False, True):
        res = monte_carlo(goals, Params(), trials, seed, clip_speed=clip, costs=FORMS)
        out["clipped" if clip else "unclipped"] = {
            form: {
                "min_accuracy": min(a.accuracy for a in per_goal.values()),
                "min_upper95": min(a.upper95 for a in per_goal.values()),
            }
            for form, per_goal in res.items()
        }
    return out


def run(layouts: int, trials: int, seed: int, workers: int) -> dict[str, Any]:
    params = Params()
    results: dict[str, Any] = {
        "layouts_per_m": layouts,
        "trials_per_goal": trials,
        "seed": seed,
        "alpha": params.alpha,
        "per_m": {},
    }
    started = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers, mp_context=worker_context()) as pool:
        for m, scene_name in SCENES.items():
            sc = load_scene(scene_name)
            cons = LayoutConstraints.of(sc, sc.goal_names)
            rng = np.random.default_rng([seed, m])
            poses = cons.sample(layouts, rng)
            pos, rot, sym = sc.grasp_batch(sc.goal_names, poses)
            J = {
                form: certify_batch(
                    sc.home.position, sc.home.rotation, pos, rot, sym, params.with_cost(form)
                ).objective
                for form in FORMS
            }
            todo = np.flatnonzero((J["dragan"] > 0) | (J["ratio"] > 0))
            jobs = [(scene_name, poses[i], trials, seed + int(i)) for i in todo]
            checks = list(
                tqdm(
                    pool.map(_check, jobs, chunksize=4),
                    total=len(jobs),
                    desc=f"M={m} {scene_name}",
                    unit="layout",
                )
            )
            by_index = dict(zip(todo.tolist(), checks, strict=True))
            row: dict[str, Any] = {"scene": scene_name, "layouts": layouts}
            for form in FORMS:
                certified = np.flatnonzero(J[form] > 0)
                entry: dict[str, Any] = {
                    "certified": len(certified),
                    "J_median": float(np.median(J[form])),
                }
                for model in ("unclipped", "clipped"):
                    accs = [by_index[i][model][form]["min_accuracy"] for i in certified]
                    uppers = [by_index[i][model][form]["min_upper95"] for i in certified]
                    entry[model] = {
                        "violating": int(sum(a < 1 - params.alpha for a in accs)),
                        "significantly_violating": int(sum(u < 1 - params.alpha for u in uppers)),
                        "worst_min_accuracy": float(min(accs)) if accs else None,
                    }
                row[form] = entry
            results["per_m"][str(m)] = row
    results["seconds"] = time.perf_counter() - started
    return results


def markdown(results: dict[str, Any]) -> str:
    head = (
        "| M | scene | form | certified (J > 0) | violating 1-α | significantly | worst accuracy "
        "| violating, speed-clipped | significantly | worst accuracy |\n"
        "|---|---|---|---|---|---|---|---|---|---|\n"
    )
    rows = []
    for m, row in results["per_m"].items():
        for form in FORMS:
            e = row[form]
            u, c = e["unclipped"], e["clipped"]

            def worst(x: float | None) -> str:
                return "—" if x is None else f"{x:.3f}"

            cells = [m, row["scene"], form, f"{e['certified']} / {row['layouts']}"]
            for model in (u, c):
                cells += [
                    model["violating"],
                    model["significantly_violating"],
                    worst(model["worst_min_accuracy"]),
                ]
            rows.append("| " + " | ".join(str(x) for x in cells) + " |")
    return head + "\n".join(rows) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", type=int, default=500)
    ap.add_argument("--trials", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("docs/results/certificate_validity.json"))
    args = ap.parse_args()
    results = run(args.layouts, args.trials, args.seed, args.workers)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    table = markdown(results)
    args.out.with_suffix(".md").write_text(table)
    print(table)
    print(f"{results['seconds']:.0f} s; written {args.out} and {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
