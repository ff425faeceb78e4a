"""Does designing for the person pay? (issue 28, point 7; method.md §9's metrics, §10)

For one scene per M (Easy breakfast_easy, Med-A desk, Hard-A meal_assembly, Hard-B
cluttered) and three operators of §10's grid — correlated (rho 0.8), a keyboard (axis-only
steering), slow and biased (speed 0.6, 20°) — the layout is designed twice with
``legws optimize``'s code (CMA-ME, 1000 iterations, the slack objective, 5 seeds): for
section 2's user (the paper's design), and for the operator (``--operator``: J of its model
with the robot's clip). Each seed's best verified layout is then

* certified for the operator (numpy, the robot's clip): J, and how many goals are certified
  by J and commit-certified by K (exact sum);
* evaluated on the stand-in with ``legws eval``'s code, the simulated user steering as that
  operator (``--operator``), 10 picks per goal: the person's metrics of method.md §9 —
  commits on the true goal (overall and the worst goal), wrong commits, T_infer (mean over
  commits and Kaplan–Meier median) — with intervals over the 5 seeds (a percentile bootstrap,
  or Clopper–Pearson where every pick or none succeeded).

Resumable: the optimisation runs are cached (the optimiser's cache and ``--work``), each
evaluation is a JSON under ``--work``.

Usage:
    python benchmarks/operator_design.py [--seeds 0,1,2,3,4] [--scenes ...] [--workers 2]
        [--episodes-per-goal 10] [--out docs/results/operator_design.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import certify_commit
from legws_daemon.core.operator import OperatorModel
from legws_daemon.design.optimize import optimize
from legws_daemon.formats.goalset import load_goalset
from legws_daemon.formats.operator_file import NUMBERS, OperatorFile
from legws_daemon.scene.catalog import load_scene
from legws_daemon.sim.evaluate import load_elites, outward_percent, run_eval
from legws_daemon.sim.statistics import rate_interval

SCENES = ("breakfast_easy", "desk", "meal_assembly", "cluttered")
OPERATORS = {
    "correlated": OperatorModel(1.0, 0.03, 0.8, 0.0, "free"),
    "keyboard": OperatorModel(1.0, 0.03, 0.0, 0.0, "axes"),
    "slow_biased": OperatorModel(0.6, 0.03, 0.0, 20.0, "free"),
}


def person(name: str, op: OperatorModel) -> OperatorFile:
    """An operator file whose model is known exactly (fitted = certify_with = ``op``)."""
    return OperatorFile(name, op, op, {k: (getattr(op, k),) * 2 for k in NUMBERS}, 20, 1)


def certificates(goals_file: Path, op: OperatorModel) -> dict[str, Any]:
    goals, params = load_goalset(goals_file)
    user = op.motion(params, clip=True)
    j = certify(goals, params, op, user)
    k = certify_commit(goals, params, user, "sum", op)
    per_goal = {p.true: True for p in j.pairs}
    for p in j.pairs:
        per_goal[p.true] &= p.slack > 0
    return {
        "J": j.objective,
        "slack_certified": int(sum(per_goal.values())),
        "commit_certified": k.certified,
        "K": k.objective if np.isfinite(k.objective) else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--operators", default=",".join(OPERATORS))
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--episodes-per-goal", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--work", type=Path, default=Path(".cache/bench/operator_design"))
    ap.add_argument("--out", type=Path, default=Path("docs/results/operator_design.json"))
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    rows: list[dict[str, Any]] = []
    for scene_name in args.scenes.split(","):
        scene = load_scene(scene_name)
        paper_runs = []
        for s in seeds:
            out = args.work / "runs" / scene_name / "paper" / f"seed{s}"
            optimize(scene, out, iterations=args.iterations, seed=s, render=False)
            paper_runs.append(out)
        for op_name in args.operators.split(","):
            op = OPERATORS[op_name]
            file = person(op_name, op)
            runs = {"for section 2's user": paper_runs, "for the operator": []}
            for s in seeds:
                out = args.work / "runs" / scene_name / op_name / f"seed{s}"
                optimize(scene, out, iterations=args.iterations, seed=s, operators=[file],
                         render=False)  # fmt: skip
                runs["for the operator"].append(out)
            for design, folders in runs.items():
                path = args.work / "eval" / scene_name / op_name / f"{design.split()[-1]}.json"
                if path.is_file():
                    report = json.loads(path.read_text())
                else:
                    picked = [x for r in folders for x in load_elites(r, scene, 1)]
                    report = run_eval(
                        scene, [lay for lay, _ in picked], 0, workers=args.workers,
                        episodes_per_goal=args.episodes_per_goal,
                        elites=[e for _, e in picked], operator=op,
                    )  # fmt: skip
                    report.pop("per_layout", None)
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.write_text(json.dumps(report, indent=1, allow_nan=False) + "\n")
                certs = [certificates(r / "goals.json", op) for r in folders]
                rows.append({"scene": scene_name, "m": len(scene.goal_names), "operator": op_name,
                             "model": op.as_dict(), "design": design, "certificates": certs,
                             "aggregate": report["aggregate"]})  # fmt: skip
                print(scene_name, op_name, design, _row(rows[-1]), flush=True)
    args.out.write_text(json.dumps({"seeds": seeds, "iterations": args.iterations,
                                    "episodes_per_goal": args.episodes_per_goal, "rows": rows},
                                   indent=1, allow_nan=False) + "\n")  # fmt: skip
    text = markdown(rows)
    args.out.with_suffix(".md").write_text(text)
    print(text)


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.0f}"


def _rate(a: dict[str, Any], key: str, k_key: str, n_key: str) -> str:
    counts = a.get("counts", {})
    k, n = counts.get(k_key), counts.get(n_key)
    iv = a.get("intervals", {}).get("runs", {}).get(key)
    if k is None or n is None:
        return _pct(a.get(key))
    r = rate_interval(int(k), int(n), iv)
    if r.kind == "at_least":
        return f"{_pct(r.rate)} [≥ {outward_percent(r.low or 0.0, 1, 'low')}]"
    if r.kind == "at_most":
        return f"{_pct(r.rate)} [≤ {outward_percent(r.high or 0.0, 1, 'high')}]"
    if r.kind == "bootstrap":
        return f"{_pct(r.rate)} [{_pct(r.low)}, {_pct(r.high)}]"
    return _pct(r.rate)


def _sec(a: dict[str, Any], key: str) -> str:
    v = a.get(key)
    iv = a.get("intervals", {}).get("runs", {}).get(key)
    if v is None:
        return "—"
    if not iv or iv[0] is None or iv[1] is None:
        return f"{v:.1f}"
    return f"{v:.1f} [{iv[0]:.1f}, {'∞' if iv[1] is None else f'{iv[1]:.1f}'}]"


def _row(r: dict[str, Any]) -> str:
    a = r["aggregate"]
    certs = r["certificates"]
    j = np.mean([c["J"] for c in certs])
    cert = np.mean([c["slack_certified"] for c in certs])
    commit = np.mean([c["commit_certified"] for c in certs])
    return (f"| {r['scene']} | {r['m']} | {r['operator']} | {r['design']} | {j:.2f} | "
            f"{cert:.1f} / {r['m']} | {commit:.1f} / {r['m']} | "
            f"{_rate(a, 'commit_true_rate', 'commit_true', 'picks')} | "
            f"{_pct(a.get('commit_rate_min_goal'))} | "
            f"{_rate(a, 'wrong_commit_rate', 'wrong_commit', 'picks')} | "
            f"{_sec(a, 't_infer_mean')} | {_sec(a, 't_infer_km_median')} |")  # fmt: skip


def markdown(rows: list[dict[str, Any]]) -> str:
    head = ("| tier | M | operator | layout designed | J for the operator (mean of 5 seeds) | "
            "goals certified by J | commit-certified (K, exact sum) | commit on the true goal % "
            "[95 %] | worst goal % | wrong % | T_infer mean s | T_infer KM median s |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|\n")  # fmt: skip
    return head + "\n".join(_row(r) for r in rows) + "\n"


if __name__ == "__main__":
    main()
