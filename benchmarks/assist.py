"""The value of the help before the commit: ``commit``, ``blend`` and ``hindsight`` on the six
tiers, random and optimised layouts, in simulated time (``legws eval --assist``'s code).

Per tier and policy the same layouts and seeds (paired): ``--layouts`` random feasible
layouts (seed ``--seed``), or the ``--top-k`` best verified elites of every CMA-ME seed of
the slack-optimised runs (``--source optimised``; ``--runs``, the tables' run folders), with
enough picks per goal that every condition has at least ``--picks`` picks (480: a completion
where every pick acted on completed then has a Clopper–Pearson lower bound of 99 % once 368
were acted on; random layouts leave some grasps infeasible, the hand some ungrasped).

Measured per pick (legws_daemon.sim.protocol): time to grasp (motion onset to the gripper
closing on the object wanted), time to task (to the object lifted clear), the operator's
effort (the integral of ``|u| dt``), the share of the approach the robot drove (EE distance
at its asking over all of it, onset to grasp), wrong grasps (a wrong commit counts: the
protocol stops the pick there), overrides, completion of the picks acted on.

Intervals: the time to grasp's mean and its ratio to ``commit``'s get the 95 % percentile
bootstrap over layouts (paired: one draw of layouts for both policies); a rate where every
pick (or none) counted succeeded gets the Clopper–Pearson bound, else the bootstrap.

The simulated user is section 2's (``O_paper``), or with ``--operator`` one of method.md
§10's operators (those of benchmarks/operator_design.py: ``correlated`` rho 0.8,
``slow_biased`` speed 0.6 and a 20° bias, ``keyboard`` axis-aligned steering).

Writes ``OUT/SOURCE[-OPERATOR]/SCENE-POLICY.json`` (the eval report; an existing one is read
back, not run again) and ``OUT/SOURCE[-OPERATOR].md`` (the table) and prints it.

Usage:
    python benchmarks/assist.py [--source random|optimised] [--tiers a,b]
        [--policies commit,blend,hindsight,none] [--layouts 30] [--picks 480] [--top-k 3]
        [--seed 0] [--workers 2] [--operator correlated|slow_biased|keyboard]
        [--runs docs/results/tables/runs] [--out docs/results/assist]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, cast

import numpy as np
from tqdm import tqdm

from legws_daemon.core.arbitration import POLICIES, AssistPolicy
from legws_daemon.core.operator import OperatorModel
from legws_daemon.scene.catalog import load_scene
from legws_daemon.sim.evaluate import (
    Elite,
    load_elites,
    outward_percent,
    random_layouts,
    run_eval,
)
from legws_daemon.sim.statistics import rate_interval

#: The paper's six tiers, in order (each scene file names its tier).
SCENES = ("breakfast_easy", "desk", "breakfast", "kitchen_prep", "meal_assembly", "cluttered")
RESAMPLES = 2000
#: method.md §10's operators (as benchmarks/operator_design.py)
OPERATORS = {
    "correlated": OperatorModel(1.0, 0.03, 0.8, 0.0, "free"),
    "keyboard": OperatorModel(1.0, 0.03, 0.0, 0.0, "axes"),
    "slow_biased": OperatorModel(0.6, 0.03, 0.0, 20.0, "free"),
}


def _layouts(
    source: str, name: str, args: argparse.Namespace
) -> tuple[list[Any], list[Elite] | None]:
    scene = load_scene(name)
    if source == "random":
        return random_layouts(scene, args.layouts, args.seed), None
    runs = sorted((args.runs / "slack" / name / "cma-me").glob("seed*"))
    if not runs:
        raise SystemExit(f"no slack-optimised runs under {args.runs}/slack/{name}/cma-me")
    loaded = [pair for run in runs for pair in load_elites(run, scene, args.top_k)]
    return [layout for layout, _ in loaded], [elite for _, elite in loaded]


def _folder(args: argparse.Namespace) -> str:
    return args.source if args.operator is None else f"{args.source}-{args.operator}"


def run(source: str, name: str, policy: str, args: argparse.Namespace) -> dict[str, Any]:
    path = args.out / _folder(args) / f"{name}-{policy}.json"
    if path.exists():
        return dict(json.loads(path.read_text()))
    scene = load_scene(name)
    layouts, elites = _layouts(source, name, args)
    per_goal = max(1, math.ceil(args.picks / (len(layouts) * len(scene.goal_names))))
    with tqdm(total=len(layouts), desc=f"{source} {name} {policy}", unit="layout") as bar:
        report = run_eval(
            scene, layouts, args.seed, workers=args.workers, progress=bar.update,
            episodes_per_goal=per_goal, elites=elites, assist=cast(AssistPolicy, policy),
            operator=None if args.operator is None else OPERATORS[args.operator],
        )  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=1, allow_nan=False) + "\n")
    return report


def _grasp_sums(report: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Per layout: the sum of the times to grasp the object wanted, and their count."""
    sums, counts = [], []
    for row in report["per_layout"]:
        k = row["counts"]["grasped_true"]
        t = row["time_to_grasp_s"]
        sums.append(0.0 if t is None else t * k)
        counts.append(k)
    return np.array(sums), np.array(counts, dtype=float)


def _ratio_interval(
    base: dict[str, Any], other: dict[str, Any], seed: int
) -> tuple[float, float, float]:
    """Mean time to grasp of ``other`` over ``base``'s, with the paired bootstrap over
    layouts (the same draw for both)."""
    s0, c0 = _grasp_sums(base)
    s1, c1 = _grasp_sums(other)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(s0), (RESAMPLES, len(s0)))
    r = (s1[idx].sum(1) / c1[idx].sum(1)) / (s0[idx].sum(1) / c0[idx].sum(1))
    point = (s1.sum() / c1.sum()) / (s0.sum() / c0.sum())
    return float(point), float(np.percentile(r, 2.5)), float(np.percentile(r, 97.5))


def _mean_interval(report: dict[str, Any], seed: int) -> tuple[float, float]:
    s, c = _grasp_sums(report)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(s), (RESAMPLES, len(s)))
    m = s[idx].sum(1) / c[idx].sum(1)
    return float(np.percentile(m, 2.5)), float(np.percentile(m, 97.5))


def _rate(k: int, n: int) -> str:
    """``k`` of ``n`` in per cent, with its Clopper–Pearson bound where k = n or k = 0,
    rounded outward as every report's (a lower bound of 98.99 % reads 98.9, never 99.0:
    the targets are judged on it)."""
    ri = rate_interval(k, n)
    if n == 0:
        return "—"
    pct = f"{100 * k / n:.1f} %"
    if ri.kind == "at_least":
        return f"{pct} (≥ {outward_percent(ri.low or 0.0, 1, 'low')} %)"
    if ri.kind == "at_most":
        return f"{pct} (≤ {outward_percent(ri.high or 0.0, 1, 'high')} %)"
    return pct


def table(reports: dict[tuple[str, str], dict[str, Any]], seed: int) -> str:
    lines = [
        "| tier | M | assist | time to grasp, s | vs commit | time to task, s | effort, s "
        "| robot's share | wrong grasps | overrides | completion, acted on | failures "
        "| picks |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in SCENES:
        base = reports.get((name, "commit"))
        for policy in ("commit", "blend", "hindsight", "none"):
            r = reports.get((name, policy))
            if r is None:
                continue
            a = r["aggregate"]
            c = a["counts"]
            lo, hi = _mean_interval(r, seed)
            if base is not None and policy != "commit":
                p, plo, phi = _ratio_interval(base, r, seed)
                versus = f"{100 * (p - 1):+.0f} % [{100 * (plo - 1):+.0f}, {100 * (phi - 1):+.0f}]"
            else:
                versus = "—"
            failures = {k: v for k, v in a["failures"].items() if k != "infeasible_grasp"}
            named = ", ".join(f"{k} {v}" for k, v in failures.items()) or "none"
            share = a["robot_share"]
            lines.append(
                f"| {r['tier']} | {r['m']} | {policy} "
                f"| {a['time_to_grasp_s']:.1f} [{lo:.1f}, {hi:.1f}] "
                f"| {versus} | {a['time_to_task_s']:.1f} | {a['effort']:.1f} "
                f"| {'—' if share is None else f'{100 * share:.0f} %'} "
                f"| {c['wrong_grasps']} of {c['picks']}: {_rate(c['wrong_grasps'], c['picks'])} "
                f"| {c['overrides']} | {c['completed']} of {c['acted_on']}: "
                f"{_rate(c['completed'], c['acted_on'])} | {named} | {c['picks']} |"
            )  # fmt: skip
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", choices=("random", "optimised"), default="random")
    ap.add_argument("--tiers", default=",".join(SCENES))
    ap.add_argument("--policies", default="commit,blend,hindsight,none")
    ap.add_argument("--layouts", type=int, default=30)
    ap.add_argument("--picks", type=int, default=480)
    ap.add_argument("--top-k", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--operator", choices=sorted(OPERATORS), default=None)
    ap.add_argument("--runs", type=Path, default=Path("docs/results/tables/runs"))
    ap.add_argument("--out", type=Path, default=Path("docs/results/assist"))
    args = ap.parse_args()
    reports: dict[tuple[str, str], dict[str, Any]] = {}
    unknown = set(args.policies.split(",")) - set(POLICIES)
    if unknown:
        ap.error(f"--policies: unknown {', '.join(sorted(unknown))}; known: {', '.join(POLICIES)}")
    for name in args.tiers.split(","):
        for policy in args.policies.split(","):
            reports[(name, policy)] = run(args.source, name, policy, args)
    # the table covers every report on disk (an interrupted run resumes tier by tier)
    for path in sorted((args.out / _folder(args)).glob("*.json")):
        name, policy = path.stem.rsplit("-", 1)
        reports.setdefault((name, policy), json.loads(path.read_text()))
    text = table(reports, args.seed)
    (args.out / f"{_folder(args)}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
