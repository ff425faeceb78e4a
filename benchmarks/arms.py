"""Every registered arm on the stand-in: the task-graph demos and Table 1's optimised rows.

1. ``tea``, ``lego`` and ``feeding`` planned for the arm (``legws plan --robot ARM``) and run
   in-process (the controller and method.md §2's simulated user, no wall clock) over a few
   seeds: decisions completed, correct, wrong commits, the plan's certificates.
2. The six tiers of Table 1: ``legws optimize --robot ARM`` (CMA-ME, 1000 iterations, one
   seed) and ``legws eval --robot ARM`` of its best verified layout (N picks per goal, every
   pick from home): commit on the true goal, T_infer, completion of the picks acted on
   (Clopper–Pearson bound where every one completed), failures by kind.
3. The nearest reach: one pick of the LEGO brick at 18, 22, 26 and 30 cm from the arm's axis
   (four placements each) with the arm's ``min_reach`` lifted: what each arm's rule is from.

Usage:
    python benchmarks/arms.py [--arms sawyer,panda,ur5e,kinova3] [--seeds 3]
        [--episodes-per-goal 10] [--out docs/results/arms.json]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
GRAPHS = ("tea", "lego", "feeding")
TIERS = {
    "breakfast_easy": "Easy",
    "desk": "Med-A",
    "breakfast": "Med-B",
    "kitchen_prep": "Med-C",
    "meal_assembly": "Hard-A",
    "cluttered": "Hard-B",
}


def demos(arm: str, seeds: int) -> dict[str, Any]:
    from legws_daemon.demo.inprocess import run_inprocess
    from legws_daemon.demo.run import summarise
    from legws_daemon.design.stage_plan import plan_taskgraph
    from legws_daemon.formats.profile import load_profile_named, with_arm
    from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

    profile = with_arm(load_profile_named("sim"), arm)
    out: dict[str, Any] = {}
    for name in GRAPHS:
        graph, scene = load_taskgraph(resolve_taskgraph(name))
        t0 = time.perf_counter()
        plan = plan_taskgraph(graph, scene, arm=arm, progress=False, render=False)
        plan_s = time.perf_counter() - t0
        runs = decisions = correct = wrong = 0
        finished = 0
        for seed in range(seeds):
            c, events, user = run_inprocess(profile, graph, scene, seed, plan=plan)
            runs += 1
            finished += c.mode == "idle"
            for d in summarise(events, user.chosen):
                decisions += 1
                correct += d.correct
                wrong += not d.correct
        out[name] = {
            "plan_seconds": plan_s,
            "certificates": {d.label: d.certificate for d in plan.decisions},
            "runs": runs,
            "finished": finished,
            "decisions": decisions,
            "correct": correct,
            "not_correct": wrong,
        }
        print(arm, name, json.dumps(out[name]), flush=True)
    return out


def tiers(arm: str, episodes: int, workdir: Path) -> dict[str, Any]:
    from legws_daemon.core.params import Params
    from legws_daemon.design.optimize import optimize
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.scene.layout_file import load_layout
    from legws_daemon.sim.evaluate import run_eval

    out: dict[str, Any] = {}
    for name, tier in TIERS.items():
        scene = load_scene(name)
        run = workdir / arm / name
        t0 = time.perf_counter()
        summary = optimize(scene, run, iterations=1000, seed=0, arm=arm, render=False)
        layout = load_layout(run / "best_layout.json", scene)
        report = run_eval(
            scene, [layout], 0, params=Params(), workers=2, episodes_per_goal=episodes, arm=arm
        )
        agg = report["aggregate"]
        counts = agg["counts"]
        out[name] = {
            "tier": tier,
            "M": len(scene.goal_names),
            "J": summary["objective"],
            "picks": counts["picks"],
            "commit_true": counts["commit_true"],
            "wrong_commit": counts["wrong_commit"],
            "acted_on": counts["acted_on"],
            "completed": counts["completed"],
            "t_infer_mean": agg["t_infer_mean"],
            "t_infer_km_median": agg["t_infer_km_median"],
            "failures": agg["failures"],
            "infeasible_picks": agg["infeasible_picks"],
            "seconds": time.perf_counter() - t0,
        }
        print(arm, name, json.dumps(out[name]), flush=True)
    return out


#: The LEGO brick's distances from the arm's axis (m) and (y, yaw) placements of the probe.
NEAR_DISTANCES = (0.18, 0.22, 0.26, 0.30)
NEAR_PLACES = ((-0.03, 1.37), (0.0, 0.0), (0.1, 0.8), (-0.15, -0.7))


def near(arm_name: str) -> list[dict[str, Any]]:
    """One pick of the LEGO brick at each distance from the arm's axis and placement, with
    the arm's ``min_reach`` lifted (what the rule is measured from)."""
    import dataclasses

    import legws_daemon.arms as arms
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.scene.scene import ObjectPose
    from legws_daemon.sim.protocol import Evaluator

    arms.arm_names()  # the registry loaded, then this arm without its nearest reach
    spec = arms.arm(arm_name)
    arms._REGISTRY[arm_name] = dataclasses.replace(spec, min_reach=0.0)
    try:
        scene = load_scene("lego")
        ev = Evaluator(scene, arm=arm_name)
        layout = scene.default_layout()
        out = []
        for d in NEAR_DISTANCES:
            for y, yaw in NEAR_PLACES:
                trial = {**layout, "red_brick": ObjectPose(spec.mount.x + d, y, yaw)}
                check = ev.check(trial)["red_brick"]
                row: dict[str, Any] = {"distance": d, "y": y, "yaw": yaw}
                if not check.feasible:
                    row["outcome"] = "infeasible"
                else:
                    report = ev.evaluate(trial, [0, 1], 1)
                    pick = next(p for p in report.picks if p.true_goal == "red_brick")
                    row["outcome"] = "completed" if pick.completed else pick.failure
                out.append(row)
        counts: dict[float, dict[str, int]] = {}
        for row in out:
            c = counts.setdefault(row["distance"], {})
            c[row["outcome"]] = c.get(row["outcome"], 0) + 1
        print(arm_name, "near", json.dumps(counts), flush=True)
        return out
    finally:
        arms._REGISTRY[arm_name] = spec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", default="sawyer,panda,ur5e,kinova3")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--episodes-per-goal", type=int, default=10)
    ap.add_argument("--parts", default="demos,tiers,near")
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "results" / "arms.json")
    a = ap.parse_args()
    os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(prefix="legws-bench-cache-")
    work = Path(tempfile.mkdtemp(prefix="legws-arms-"))
    results: dict[str, Any] = json.loads(a.out.read_text()) if a.out.is_file() else {}
    results.setdefault("arms", {})
    results["seeds"] = a.seeds
    results["episodes_per_goal"] = a.episodes_per_goal
    parts = a.parts.split(",")
    for arm in a.arms.split(","):
        entry = results["arms"].setdefault(arm, {})
        if "demos" in parts:
            entry["demos"] = demos(arm, a.seeds)
        if "tiers" in parts:
            entry["tiers"] = tiers(arm, a.episodes_per_goal, work)
        if "near" in parts:
            entry["near"] = near(arm)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(results, indent=1) + "\n")  # after every arm: resumable
    print(markdown(results))


def markdown(results: dict[str, Any]) -> str:
    from legws_daemon.core.montecarlo import clopper_pearson
    from legws_daemon.sim.evaluate import outward_percent

    lines = [
        "| arm | tier | M | J | picks | commit on the true goal % | wrong commits | "
        "completed, of acted on % | failures | T_infer mean s | T_infer KM median s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for arm, entry in results["arms"].items():
        for row in entry.get("tiers", {}).values():
            n, k = row["acted_on"], row["completed"]
            done = f"{100 * k / n:.1f}" if n else "—"
            if n and k == n:
                done += f" [≥ {outward_percent(clopper_pearson(k, n, 0.95)[0], 1, 'low')}]"
            fails = ", ".join(f"{f} {c}" for f, c in row["failures"].items()) or "none"
            km = row["t_infer_km_median"]
            lines.append(
                f"| {arm} | {row['tier']} | {row['M']} | {row['J']:.2f} | {row['picks']} | "
                f"{100 * row['commit_true'] / row['picks']:.0f} | {row['wrong_commit']} | "
                f"{done} | {fails} | {row['t_infer_mean']:.1f} | "
                f"{'—' if km is None else f'{km:.1f}'} |"
            )
    lines += [
        "",
        "| arm | task graph | runs finished | decisions correct | not correct | J per decision |",
        "|---|---|---|---|---|---|",
    ]
    for arm, entry in results["arms"].items():
        for name, d in entry.get("demos", {}).items():
            js = ", ".join(f"{k} {v:.2f}" for k, v in d["certificates"].items() if v is not None)
            lines.append(
                f"| {arm} | {name} | {d['finished']}/{d['runs']} | "
                f"{d['correct']}/{d['decisions']} | {d['not_correct']} | {js} |"
            )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
