"""The random-condition rows of the paper's Table 1 for all six tiers, on the stand-in.

Runs ``legws eval --layouts random:30`` for every paper scene (same code path), writes each
report to ``docs/results/eval_random/SCENE.{json,md}`` and a comparison table with the
paper's random rows to ``docs/results/eval_random/table1_random.md``.

With ``--scenes a,b`` only those tiers run; the table reads the others' reports from the
output folder (so an interrupted run resumes tier by tier).

Usage:
    python benchmarks/eval_random.py [--layouts 30] [--seed 0] [--workers 2] [--cost ratio]
        [--scenes cluttered]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from tqdm import tqdm

from legws_daemon.core.params import COST_FORMS, Params
from legws_daemon.scene.catalog import load_scene
from legws_daemon.sim.evaluate import markdown, random_layouts, run_eval

#: The paper's Table 1, random condition: T_infer mean, sd (s) and argmax accuracy.
PAPER_RANDOM = {
    "breakfast_easy": ("Easy", 2, 6.1, 2.4, 0.92),
    "desk": ("Med-A", 3, 6.9, 3.4, 0.91),
    "breakfast": ("Med-B", 3, 9.9, 2.8, 1.00),
    "kitchen_prep": ("Med-C", 3, 7.7, 3.9, 0.93),
    "meal_assembly": ("Hard-A", 5, 12.5, 3.0, 0.88),
    "cluttered": ("Hard-B", 8, 10.9, 3.6, 0.25),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cost", choices=COST_FORMS, default="dragan")
    ap.add_argument("--scenes", default=",".join(PAPER_RANDOM), help="tiers to run")
    ap.add_argument(
        "--out", type=Path, default=None, help="default docs/results/eval_random[_ratio]"
    )
    args = ap.parse_args()
    if args.out is None:
        suffix = "" if args.cost == "dragan" else f"_{args.cost}"
        args.out = Path(f"docs/results/eval_random{suffix}")
    params = Params(cost=args.cost)
    args.out.mkdir(parents=True, exist_ok=True)
    selected = set(args.scenes.split(","))
    rows: list[dict[str, Any]] = []
    for name, (tier, m, t_mean, t_sd, acc) in PAPER_RANDOM.items():
        if name not in selected:
            report = json.loads((args.out / f"{name}.json").read_text())
        else:
            scene = load_scene(name)
            layouts = random_layouts(scene, args.layouts, args.seed)
            with tqdm(total=len(layouts), desc=name, unit="layout") as bar:
                report = run_eval(
                    scene, layouts, args.seed, params=params, workers=args.workers,
                    progress=bar.update,
                )  # fmt: skip
            (args.out / f"{name}.json").write_text(json.dumps(report, indent=2) + "\n")
            (args.out / f"{name}.md").write_text(markdown(report))
        a, t = report["aggregate"], report["timing"]
        rows.append(
            {
                "tier": tier, "scene": name, "m": m, "paper": (acc, t_mean, t_sd),
                "accuracy": a["accuracy"], "accuracy_feasible": a["accuracy_feasible"],
                "t_mean": a["t_infer_mean"], "t_sd": a["t_infer_sd"],
                "commit": a["commit_rate"], "wrong": a["wrong_commit_rate"],
                "none": a["no_commit_rate"], "infeasible": a["infeasible_picks"],
                "confirmed": a["confirmed_rate"], "completed": a["completion_rate"],
                "completed_acted": a["completion_committed"], "failures": a["failures"],
                "episodes": a["episodes"], "seconds": t["seconds"],
                "eps": t["episodes_per_second"],
            }
        )  # fmt: skip
    total = sum(r["seconds"] for r in rows)  # wall-clock of every tier's run

    def pct1(x: float | None) -> str:
        return "—" if x is None else f"{100 * x:.1f} %"

    def f(x: float | None, pct: bool = False) -> str:
        if x is None:
            return "—"
        return f"{100 * x:.0f} %" if pct else f"{x:.1f}"

    lines = [
        "| tier | scene | M | accuracy (ours) | accuracy (paper) | T_infer s (ours) "
        "| T_infer s (paper) | accuracy, feasible picks | commit | wrong commit | no commit "
        "| confirmed | completed | completed, acted on | infeasible picks | other failures "
        "| picks | seconds |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        pa, pm, ps = r["paper"]
        other = {k: v for k, v in r["failures"].items() if k != "infeasible_grasp"}
        others = ", ".join(f"{k} {v}" for k, v in other.items()) or "none"
        lines.append(
            f"| {r['tier']} | {r['scene']} | {r['m']} | {f(r['accuracy'], True)} "
            f"| {f(pa, True)} | {f(r['t_mean'])} ± {f(r['t_sd'])} | {pm} ± {ps} "
            f"| {f(r['accuracy_feasible'], True)} | {f(r['commit'], True)} "
            f"| {f(r['wrong'], True)} | {f(r['none'], True)} | {f(r['confirmed'], True)} "
            f"| {f(r['completed'], True)} | {pct1(r['completed_acted'])} "
            f"| {r['infeasible']} | {others} | {r['episodes']} | {r['seconds']:.0f} |"
        )
    eps = sum(r["episodes"] for r in rows) / total
    lines += [
        "",
        f"Cost form {args.cost}. All six tiers: {total:.0f} s wall-clock, {args.workers} "
        f"workers, {eps:.0f} picks/s.",
    ]
    table = "\n".join(lines) + "\n"
    (args.out / "table1_random.md").write_text(table)
    print(table)


if __name__ == "__main__":
    main()
