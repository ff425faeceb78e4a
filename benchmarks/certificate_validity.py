"""Is the certificate honest? Random feasible layouts, both cost forms, Monte Carlo on each.

For M in {2, 3, 5, 8} (scenes breakfast_easy, desk, meal_assembly, cluttered, with their
fixed clutter) draw N random feasible layouts as in method.md §5, compute J for the
``dragan`` and ``ratio`` cost forms, and on every layout certified by either form run the
Monte Carlo check (trials per goal, the same trajectories for both forms), once with the
certificate's unclipped user model and once with the robot's speed clip ``|v| <= v_max``.
A certified layout *violates* 1 - alpha when some goal's accuracy at the horizon is below
1 - alpha; *significantly* when even the Clopper-Pearson 95 % upper bound is below it.

The commit part (method.md §9) does the same for the commit certificate, per goal: on the
same layouts, every goal whose commit is certified gets N simulated users; a
commit-certified goal *violates* its promise when fewer than 1 - alpha of them make their
first commit on it at or before the certified step, *significantly* when even the
Clopper-Pearson upper bound is below 1 - alpha. The unclipped users are checked against
section 9's certificate; the speed-clipped users (the robot's) against the same certificate
computed for the clipped user's motion (``core.commit.clipped_user``: slower, in the robot's
own time). Both forms of the commit slack are checked: section 9's ``min`` and the exact
``sum`` (``core.commit``). Written to ``commit_validity.{json,md}`` beside the slack results.

Usage:
    python benchmarks/certificate_validity.py [--layouts 500] [--trials 2000] [--seed 0]
        [--workers 2] [--part slack|commit|both] [--out docs/results/certificate_validity.json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.commit import COMMIT_FORMS, clipped_user, commit_batch, unclipped_user
from legws_daemon.core.geometry import matrix_to_quat
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.montecarlo import commit_rates, monte_carlo, simulate_commits
from legws_daemon.core.params import CostForm, Params
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.scene import Scene
from legws_daemon.workers import worker_context

SCENES = {2: "breakfast_easy", 3: "desk", 5: "meal_assembly", 8: "cluttered"}
FORMS: tuple[CostForm, ...] = ("dragan", "ratio")


def _layouts(
    scene_name: str, layouts: int, seed: int, m: int
) -> tuple[Scene, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The scene, ``layouts`` random feasible layouts of it (the same for both parts) and
    their grasps."""
    sc = load_scene(scene_name)
    cons = LayoutConstraints.of(sc, sc.goal_names)
    poses = cons.sample(layouts, np.random.default_rng([seed, m]))
    return sc, poses, sc.grasp_batch(sc.goal_names, poses)


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


def _goals(scene_name: str, poses: np.ndarray) -> GoalSet:
    sc = load_scene(scene_name)
    pos, rot, sym = sc.grasp_batch(sc.goal_names, poses[None])
    return GoalSet(sc.goal_names, pos[0], matrix_to_quat(rot[0]), sym, sc.home)


MODELS = ("unclipped", "clipped")


Steps = dict[str, dict[str, dict[str, list[int]]]]  # model -> cost form -> commit form


def _check_commit(job: tuple[str, np.ndarray, Steps, int, int]) -> dict[str, Any]:
    """Monte Carlo of one layout's first commits: both cost forms, unclipped and clipped.

    ``steps[model][cost][commit_form][i]`` is goal ``i``'s certified commit step (0: not
    certified)."""
    scene_name, poses, steps, trials, seed = job
    goals = _goals(scene_name, poses)
    out: dict[str, Any] = {}
    for model in MODELS:
        clip = model == "clipped"
        rng = np.random.default_rng([seed, int(clip)])
        wanted = sorted(
            {i for f in FORMS for cf in COMMIT_FORMS for i, s in enumerate(steps[model][f][cf])
             if s > 0}
        )  # fmt: skip
        rolls = simulate_commits(
            goals, Params(), trials, rng, clip_speed=clip, costs=FORMS, true_goals=wanted
        )
        per_form: dict[str, Any] = {}
        for form in FORMS:
            per_form[form] = {}
            for cf in COMMIT_FORMS:
                by = [s if s > 0 else None for s in steps[model][form][cf]]
                rates = commit_rates(rolls[form], by, goals.names)
                per_form[form][cf] = [
                    {
                        "rate": r.rate_by_step,
                        "upper95": r.upper95,
                        "wrong": r.wrong,
                        "before_arrival": r.before_arrival,
                    }
                    for r in rates.values()
                ]
        out[model] = per_form
    return out


def run_commit(layouts: int, trials: int, seed: int, workers: int) -> dict[str, Any]:
    """The commit certificate's honesty (method.md §9) on the slack part's layouts."""
    params = Params()
    users = {"unclipped": unclipped_user(params), "clipped": clipped_user(params)}
    results: dict[str, Any] = {
        "layouts_per_m": layouts,
        "trials_per_goal": trials,
        "seed": seed,
        "alpha": params.alpha,
        "p_thresh": params.p_thresh,
        "clipped_user": {
            "speed": users["clipped"].speed,
            "along": users["clipped"].along,
            "across": users["clipped"].across,
        },
        "per_m": {},
    }
    started = time.perf_counter()
    with ProcessPoolExecutor(max_workers=workers, mp_context=worker_context()) as pool:
        for m, scene_name in SCENES.items():
            sc, poses, (pos, rot, sym) = _layouts(scene_name, layouts, seed, m)
            home = sc.home
            args = (home.position, home.rotation, pos, rot, sym)
            batch = {
                model: {
                    form: {
                        cf: commit_batch(*args, params.with_cost(form), user, cf)
                        for cf in COMMIT_FORMS
                    }
                    for form in FORMS
                }
                for model, user in users.items()
            }
            any_cert = np.zeros((layouts, m), dtype=bool)
            for model in MODELS:
                for form in FORMS:
                    for cf in COMMIT_FORMS:
                        any_cert |= batch[model][form][cf].certified
            todo = np.flatnonzero(any_cert.any(axis=1))
            jobs = []
            for i in todo.tolist():
                steps: Steps = {
                    model: {
                        f: {
                            cf: np.where(bt.certified[i], bt.step[i], 0).astype(int).tolist()
                            for cf, bt in batch[model][f].items()
                        }
                        for f in FORMS
                    }
                    for model in MODELS
                }
                jobs.append((scene_name, poses[i], steps, trials, seed + i))
            checks = list(
                tqdm(
                    pool.map(_check_commit, jobs, chunksize=2),
                    total=len(jobs),
                    desc=f"commit M={m} {scene_name}",
                    unit="layout",
                )
            )
            by_index = dict(zip(todo.tolist(), checks, strict=True))
            row: dict[str, Any] = {"scene": scene_name, "layouts": layouts, "goals": layouts * m}
            for form in FORMS:
                entry: dict[str, Any] = {}
                for model, cf in itertools.product(MODELS, COMMIT_FORMS):
                    b = batch[model][form][cf]
                    cert = [(int(i), int(g)) for i, g in zip(*np.nonzero(b.certified), strict=True)]
                    rs = [by_index[i][model][form][cf][g] for i, g in cert]
                    ok = 1 - params.alpha
                    entry[f"{model}/{cf}"] = {
                        "certified_goals": len(cert),
                        "layouts_all_certified": int(np.sum(b.objective <= 1.0)),
                        "K_median": float(np.median(b.objective)),
                        "violating": int(sum(r["rate"] < ok for r in rs)),
                        "significantly_violating": int(sum(r["upper95"] < ok for r in rs)),
                        "worst_rate": float(min(r["rate"] for r in rs)) if rs else None,
                        "median_rate": float(np.median([r["rate"] for r in rs])) if rs else None,
                        "worst_wrong": float(max(r["wrong"] for r in rs)) if rs else None,
                    }
                row[form] = entry
            results["per_m"][str(m)] = row
    results["seconds"] = time.perf_counter() - started
    return results


def markdown_commit(results: dict[str, Any]) -> str:
    head = (
        "| M | scene | cost form | user | commit slack | commit-certified goals | layouts K ≤ 1 "
        "| violating 1-α | significantly | worst rate | median rate | worst wrong |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )

    def num(x: float | None) -> str:
        return "—" if x is None else f"{x:.3f}"

    rows = []
    for m, row in results["per_m"].items():
        for form in FORMS:
            for model, cf in itertools.product(MODELS, COMMIT_FORMS):
                e = row[form][f"{model}/{cf}"]
                cells = [
                    m, row["scene"], form, model, cf, f"{e['certified_goals']} / {row['goals']}",
                    f"{e['layouts_all_certified']} / {row['layouts']}", e["violating"],
                    e["significantly_violating"], num(e["worst_rate"]), num(e["median_rate"]),
                    num(e["worst_wrong"]),
                ]  # fmt: skip
                rows.append("| " + " | ".join(str(x) for x in cells) + " |")
    return head + "\n".join(rows) + "\n"


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
            sc, poses, (pos, rot, sym) = _layouts(scene_name, layouts, seed, m)
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
                    accs = [by_index[i][model][form]["min_accuracy"] for i in certified.tolist()]
                    uppers = [by_index[i][model][form]["min_upper95"] for i in certified.tolist()]
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
    ap.add_argument("--part", choices=("slack", "commit", "both"), default="both")
    ap.add_argument("--out", type=Path, default=Path("docs/results/certificate_validity.json"))
    args = ap.parse_args()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    parts = []
    if args.part in ("slack", "both"):
        parts.append((args.out, run, markdown))
    if args.part in ("commit", "both"):
        parts.append((args.out.with_name("commit_validity.json"), run_commit, markdown_commit))
    for out, runner, table_of in parts:
        results = runner(args.layouts, args.trials, args.seed, args.workers)
        out.write_text(json.dumps(results, indent=2) + "\n")
        table = table_of(results)
        out.with_suffix(".md").write_text(table)
        print(table)
        print(f"{results['seconds']:.0f} s; written {out} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
