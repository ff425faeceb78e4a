"""Are the certificates honest for a given operator? (method.md §10)

Parts (each resumable: a finished piece is read back, not run again; results in
``--out``, a folder):

* ``grid``: every operator of §10's grid — rho in {0, 0.5, 0.8, 0.95}, bias in {0, ±10°,
  ±20°}, speed in {0.6, 1}, each steering, sigma = 0.03 m/s — on ``--layouts`` random
  feasible layouts per M in {2, 3, 5, 8} (the scenes of method.md §7, drawn as in §5, the
  same layouts for every operator). Certificates for the operator with the robot's clip
  (the daemon's certificates of a person): a goal is *certified* when its slack (§4) is
  positive against every alternative, *commit-certified* when §9's exact-sum commit
  certificate holds for it. Every certified goal gets ``--trials`` simulated users of that
  operator (clipped, AR(1) noise, bias, quantised steering: ``SimulatedUser``): the argmax at
  its horizon, and the first commit by its certified step (in ticks) and before it came
  further along the way than the nominal at that step (in progress; every user is followed
  to its own arrival, so a slower one is not cut off at the model's). A goal *violates* when
  its rate is below 1 - alpha, *significantly* when even the Clopper–Pearson upper bound is.
* ``mismatch``: §10's table of why the model is needed — certificates of section 2's user
  (§4 and §9 as written, the model without the clip) on ``--mismatch-layouts`` layouts per M,
  checked against users who steer otherwise (unclipped, as the certificates' own check):
  AR(1) noise of the same variance at rho 0.5/0.8/0.95, axis-only and axis-or-diagonal
  steering, a 20° bias either side, idle on 20 % of ticks, Student-t noise (3 dof), a 250 ms
  reaction delay. The share of certified goals whose promise fails.
* ``e2e``: an operator fitted from 20 simulated calibration reaches of a known grid operator
  (``sim.reaches``, several seeds) certifies layouts with its ``certify_with``; those goals
  are checked against the true operator.
* ``report``: ``--report``/operator_validity.json and .md from the pieces (kept in
  ``--out``, a cache: one small JSON per operator and M).

Usage:
    python benchmarks/operator_validity.py [--part grid|mismatch|e2e|report|all]
        [--layouts 500] [--trials 400] [--low-rho-trials N] [--mismatch-layouts 200]
        [--workers 2] [--seed 0]
        [--out .cache/bench/operator_validity] [--report docs/results]
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.commit import commit_batch
from legws_daemon.core.geometry import matrix_to_quat
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.montecarlo import (
    clopper_pearson,
    commit_rates,
    monte_carlo,
    simulate_commits,
)
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.operator_fit import fit_operator
from legws_daemon.core.params import Params
from legws_daemon.core.user_model import SimulatedUser
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.sim.reaches import simulate_reaches
from legws_daemon.workers import worker_context

SCENES = {2: "breakfast_easy", 3: "desk", 5: "meal_assembly", 8: "cluttered"}
RHOS = (0.0, 0.5, 0.8, 0.95)
BIASES = (0.0, 10.0, -10.0, 20.0, -20.0)
SPEEDS = (0.6, 1.0)
STEERINGS = ("free", "axes", "axes+diagonals")
SIGMA = 0.03
ALPHA = Params().alpha
#: The users of the mismatch table: name -> how they depart from section 2's.
MISMATCH: dict[str, dict[str, Any]] = {
    "rho 0.5": {"operator": OperatorModel(rho=0.5)},
    "rho 0.8": {"operator": OperatorModel(rho=0.8)},
    "rho 0.95": {"operator": OperatorModel(rho=0.95)},
    "axes": {"operator": OperatorModel(steering="axes")},
    "axes+diagonals": {"operator": OperatorModel(steering="axes+diagonals")},
    "bias +20°": {"operator": OperatorModel(bias_deg=20.0)},
    "bias -20°": {"operator": OperatorModel(bias_deg=-20.0)},
    "idle 20 %": {"idle": 0.2},
    "Student t, 3 dof": {"tails": 3.0},
    "delay 250 ms": {"delay": 5},
}
#: The true operators of the end-to-end part, and the fit's seeds.
E2E_TRUTHS = (
    OperatorModel(1.0, SIGMA, 0.0, 0.0, "free"),
    OperatorModel(0.6, SIGMA, 0.8, 10.0, "free"),
    OperatorModel(1.0, SIGMA, 0.5, -20.0, "axes"),
    OperatorModel(0.6, SIGMA, 0.0, 0.0, "axes+diagonals"),
)
E2E_SEEDS = (0, 1, 2)


def grid() -> list[OperatorModel]:
    """The grid's operators, the most correlated first (where a linearisation is most
    strained, and the fewest goals certify: quick to check)."""
    return [
        OperatorModel(s, SIGMA, r, b, h)
        for r, b, s, h in itertools.product(RHOS[::-1], BIASES, SPEEDS, STEERINGS)
    ]


def key(op: OperatorModel) -> str:
    return f"s{op.speed:g}_r{op.rho:g}_b{op.bias_deg:+g}_{op.steering}"


def layouts(m: int, n: int, seed: int) -> np.ndarray:
    sc = load_scene(SCENES[m])
    return LayoutConstraints.of(sc, sc.goal_names).sample(n, np.random.default_rng([seed, m]))


def _goal_set(scene_name: str, poses: np.ndarray) -> GoalSet:
    sc = load_scene(scene_name)
    pos, rot, sym = sc.grasp_batch(sc.goal_names, poses[None])
    return GoalSet(sc.goal_names, pos[0], matrix_to_quat(rot[0]), sym, sc.home)


def certify_layouts(
    m: int, poses: np.ndarray, operator: OperatorModel | None, clip: bool
) -> dict[str, np.ndarray]:
    """Per layout and goal: certified by J (every slack of the goal > 0), its horizon,
    commit-certified (exact sum) and the certified step."""
    sc = load_scene(SCENES[m])
    pos, rot, sym = sc.grasp_batch(sc.goal_names, poses)
    params = Params()
    user = operator.motion(params, clip) if operator is not None else None
    args = (sc.home.position, sc.home.rotation, pos, rot, sym, params)
    j = certify_batch(*args, operator, user)
    k = commit_batch(*args, user, "sum", operator)
    return {
        "slack_ok": np.asarray(j.slack.min(axis=2) > 0.0),
        "horizon": j.steps,
        "commit_ok": k.certified,
        "step": k.step,
        "J": j.objective,
        "K": k.objective,
    }


def check_layout(
    scene_name: str, poses: np.ndarray, cert: dict[str, Any], user: SimulatedUser, trials: int,
    seed: int,
) -> list[dict[str, Any]]:  # fmt: skip
    """Simulate ``user`` on one layout's certified goals: per goal the users whose argmax
    at the horizon is right (slack-certified goals), whose first commit is on it by the
    certified step and before the nominal's progress there (commit-certified goals), and
    whose first commit is wrong."""
    goals = _goal_set(scene_name, poses)
    params = Params()
    slack_ok = np.asarray(cert["slack_ok"], dtype=bool)
    commit_ok = np.asarray(cert["commit_ok"], dtype=bool)
    rows: dict[int, dict[str, Any]] = {
        int(i): {"goal": int(i), "slack_ok": bool(slack_ok[i]), "commit_ok": bool(commit_ok[i]),
                 "argmax": 0, "by_step": 0, "by_progress": 0, "wrong": 0, "trials": trials}
        for i in np.flatnonzero(slack_ok | commit_ok)
    }  # fmt: skip
    if slack_ok.any():
        wanted = np.flatnonzero(slack_ok).tolist()
        acc = monte_carlo(goals, params, trials, seed, user=user, true_goals=wanted, compiled=True)[
            "dragan"
        ]
        for i in wanted:
            rows[i]["argmax"] = acc[goals.names[i]].correct
    if commit_ok.any():
        wanted = np.flatnonzero(commit_ok).tolist()
        rolls = simulate_commits(
            goals, params, trials, np.random.default_rng([seed, 1]), user=user, true_goals=wanted,
            until_arrival=True, compiled=True,
        )["dragan"]  # fmt: skip
        by = [int(s) if ok else None for s, ok in zip(cert["step"], commit_ok, strict=True)]
        rates = commit_rates(rolls, by, goals.names)
        for i in wanted:
            r = rates[goals.names[i]]
            rows[i] |= {"by_step": round(r.rate_by_step * trials),
                        "by_progress": round(r.rate_by_progress * trials),
                        "wrong": round(r.wrong * trials)}  # fmt: skip
    return list(rows.values())


def summarise(checks: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Violations of the three promises over the goals checked."""
    ok = 1 - ALPHA
    out: dict[str, Any] = {}
    for promise, flag in (("argmax", "slack_ok"), ("by_step", "commit_ok"),
                          ("by_progress", "commit_ok")):  # fmt: skip
        rows = [c for c in checks if c[flag]]
        rates = [c[promise] / c["trials"] for c in rows]
        uppers = [clopper_pearson(c[promise], c["trials"])[1] for c in rows]
        out[promise] = {
            "goals": len(rows),
            "violating": int(sum(r < ok for r in rates)),
            "significantly": int(sum(u < ok for u in uppers)),
            "worst": float(min(rates)) if rates else None,
            "median": float(np.median(rates)) if rates else None,
        }
    commits = [c for c in checks if c["commit_ok"]]
    out["worst_wrong"] = float(max((c["wrong"] / c["trials"] for c in commits), default=0.0))
    return out


def run_job(
    job: tuple[str, int, int, int, dict[str, Any] | None, bool, dict[str, Any], int, int],
) -> dict[str, Any]:
    """One piece (in a worker): the certificates of ``n`` layouts of M for the certifying
    operator (``None``: section 2's user, the model as written), and the checks of their
    certified goals against the simulated user."""
    part, m, n, layout_seed, certifying, clip, simulated, trials, seed = job
    started = time.perf_counter()
    poses = layouts(m, n, layout_seed)
    op = OperatorModel(**certifying) if certifying is not None else None
    cert = certify_layouts(m, poses, op, clip)
    spec = dict(simulated)
    user = SimulatedUser(OperatorModel(**spec.pop("operator")), **spec)
    checks: list[dict[str, Any]] = []
    todo = np.flatnonzero((cert["slack_ok"] | cert["commit_ok"]).any(axis=1))
    for i in todo.tolist():
        one = {k: cert[k][i].tolist() for k in ("slack_ok", "commit_ok", "horizon", "step")}
        rows = check_layout(SCENES[m], poses[i], one, user, trials, seed * 100_003 + int(i))
        checks += [r | {"layout": int(i)} for r in rows]
    return {
        "part": part, "m": m, "layouts": n, "trials": trials, "clip": clip,
        "certified_for": certifying, "simulated": simulated, **_counts(cert),
        "summary": summarise(checks), "worst": _worst(checks),
        "seconds": time.perf_counter() - started,
    }  # fmt: skip


def _simulated(user: SimulatedUser) -> dict[str, Any]:
    return {"operator": user.operator.as_dict(), "clip": user.clip, "idle": user.idle,
            "tails": user.tails, "delay": user.delay}  # fmt: skip


def _run(pool: ProcessPoolExecutor, jobs: dict[Path, tuple[Any, ...]], desc: str) -> None:
    """Run the pieces not on disk yet, writing each as it finishes."""
    todo = {path: job for path, job in jobs.items() if not path.is_file()}
    futures = {pool.submit(run_job, job): path for path, job in todo.items()}
    from concurrent.futures import as_completed

    for future in tqdm(as_completed(futures), total=len(futures), desc=desc, unit="piece"):
        _write(futures[future], future.result())


def _worst(checks: Sequence[dict[str, Any]], n: int = 5) -> list[dict[str, Any]]:
    """The ``n`` checks with the lowest rate of any promise they were certified for."""

    def low(c: dict[str, Any]) -> float:
        rates = [c["argmax"]] if c["slack_ok"] else []
        rates += [c["by_step"], c["by_progress"]] if c["commit_ok"] else []
        return float(min(rates) / c["trials"])

    return sorted(checks, key=low)[:n]


def _write(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1, allow_nan=False) + "\n")
    tmp.replace(path)


def _counts(cert: dict[str, np.ndarray]) -> dict[str, Any]:
    return {
        "goals": int(cert["slack_ok"].size),
        "slack_certified": int(cert["slack_ok"].sum()),
        "commit_certified": int(cert["commit_ok"].sum()),
        "layouts_J_positive": int((cert["J"] > 0).sum()),
        "layouts_K_le_1": int((cert["K"] <= 1).sum()),
    }


def part_grid(args: argparse.Namespace, pool: ProcessPoolExecutor) -> None:
    jobs = {
        args.out / "grid" / f"M{m}" / f"{key(op)}.json": (
            "grid",
            m,
            args.layouts,
            args.seed,
            op.as_dict(),
            True,
            _simulated(SimulatedUser(op, clip=True)),
            args.trials if op.rho >= 0.8 or args.low_rho_trials is None else args.low_rho_trials,
            args.seed,
        )
        for op in grid()
        for m in SCENES
    }
    _run(pool, jobs, "grid")


def part_mismatch(args: argparse.Namespace, pool: ProcessPoolExecutor) -> None:
    jobs = {}
    for name, spec in MISMATCH.items():
        operator = spec.get("operator", OperatorModel())
        rest = {k: v for k, v in spec.items() if k != "operator"}
        user = SimulatedUser(operator, clip=False, **rest)
        for m in SCENES:
            path = args.out / "mismatch" / f"M{m}" / f"{name.replace(' ', '_')}.json"
            jobs[path] = ("mismatch", m, args.mismatch_layouts, args.seed + 1, None, False,
                          _simulated(user), args.trials, args.seed)  # fmt: skip
    _run(pool, jobs, "mismatch")


def part_e2e(args: argparse.Namespace, pool: ProcessPoolExecutor) -> None:
    params = Params()
    jobs = {}
    fits: dict[str, dict[str, Any]] = {}
    for truth, seed in itertools.product(E2E_TRUTHS, E2E_SEEDS):
        name = f"{key(truth)}_seed{seed}"
        fit_path = args.out / "e2e" / name / "fit.json"
        if fit_path.is_file():
            fits[name] = json.loads(fit_path.read_text())
        else:
            rng = np.random.default_rng([seed, 77])
            reaches = simulate_reaches(SimulatedUser(truth, clip=True), 20, rng)
            fit = fit_operator(reaches, params, seed=seed)
            intervals = fit.intervals
            fits[name] = {
                "truth": truth.as_dict(), "seed": seed, "fitted": fit.model.as_dict(),
                "certify_with": fit.certify_with.as_dict(),
                "intervals": {k: list(v) for k, v in intervals.items()},
                "covered": {k: lo <= getattr(truth, k) <= hi for k, (lo, hi) in intervals.items()},
            }  # fmt: skip
            _write(fit_path, fits[name])
        for m in SCENES:
            jobs[args.out / "e2e" / name / f"M{m}.json"] = (
                "e2e", m, args.mismatch_layouts, args.seed + 2, fits[name]["certify_with"], True,
                _simulated(SimulatedUser(truth, clip=True)), args.trials, args.seed + seed,
            )  # fmt: skip
    _run(pool, jobs, "e2e")


# --- report -----------------------------------------------------------------------------------


def _pieces(folder: Path) -> list[dict[str, Any]]:
    return (
        [json.loads(p.read_text()) for p in sorted(folder.rglob("*.json"))]
        if folder.is_dir()
        else []
    )


def _merge(summaries: Sequence[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for promise in ("argmax", "by_step", "by_progress"):
        rows = [s[promise] for s in summaries]
        worst = [r["worst"] for r in rows if r["worst"] is not None]
        out[promise] = {
            "goals": sum(r["goals"] for r in rows),
            "violating": sum(r["violating"] for r in rows),
            "significantly": sum(r["significantly"] for r in rows),
            "worst": min(worst) if worst else None,
        }
    out["worst_wrong"] = max((s["worst_wrong"] for s in summaries), default=0.0)
    return out


def _cell(e: dict[str, Any]) -> str:
    worst = "—" if e["worst"] is None else f"{e['worst']:.3f}"
    return f"{e['goals']} / {e['violating']} / {e['significantly']} / {worst}"


def report(args: argparse.Namespace) -> None:
    out: dict[str, Any] = {"alpha": ALPHA}
    lines = ["# Operator certificates: honesty (method.md §10)", ""]
    grid_pieces = [p for p in _pieces(args.out / "grid") if "summary" in p]
    if grid_pieces:
        by_m: dict[int, list[dict[str, Any]]] = {}
        for p in grid_pieces:
            by_m.setdefault(p["m"], []).append(p)
        out["grid"] = {}
        lines += [
            "## The grid: certificates for the operator (robot's clip), checked against it", "",
            f"{grid_pieces[0]['layouts']} random feasible layouts per M, the same for every "
            "operator; "
            f"{' or '.join(str(t) for t in sorted({p['trials'] for p in grid_pieces}))} "
            "simulated users of the operator per certified goal (per rho below). Cells: "
            "certified goals / violating 1−α / significantly (Clopper–Pearson upper bound "
            "below) / worst rate.", "",
            "| M | operators | layouts | argmax at the horizon (§4) | first commit by the "
            "certified step, ticks (§9, exact sum) | … counted in progress | worst wrong |",
            "|---|---|---|---|---|---|---|",
        ]  # fmt: skip
        for m in sorted(by_m):
            merged = _merge([p["summary"] for p in by_m[m]])
            out["grid"][str(m)] = merged | {"operators": len(by_m[m])}
            lines.append(
                f"| {m} | {len(by_m[m])} of {len(grid())} | {by_m[m][0]['layouts']} "
                f"| {_cell(merged['argmax'])} "
                f"| {_cell(merged['by_step'])} | {_cell(merged['by_progress'])} "
                f"| {merged['worst_wrong']:.3f} |"
            )
        lines += ["", "Per rho (every bias, speed and steering; all M pooled):", "",
                  "| rho | operators | users per goal | argmax | by step | by progress "
                  "| worst wrong |", "|---|---|---|---|---|---|---|"]  # fmt: skip
        out["per_rho"] = {}
        per_rho = len(BIASES) * len(SPEEDS) * len(STEERINGS)
        for rho in sorted({p["certified_for"]["rho"] for p in grid_pieces}):
            ps = [p for p in grid_pieces if p["certified_for"]["rho"] == rho]
            merged = _merge([p["summary"] for p in ps])
            n_ops = len({key(OperatorModel(**p["certified_for"])) for p in ps})
            trials = sorted({p["trials"] for p in ps})
            out["per_rho"][str(rho)] = merged | {"operators": n_ops, "pieces": len(ps)}
            lines.append(
                f"| {rho:g} | {n_ops} of {per_rho} ({len(ps)} of {4 * per_rho} operator × M) "
                f"| {', '.join(map(str, trials))} | {_cell(merged['argmax'])} "
                f"| {_cell(merged['by_step'])} | {_cell(merged['by_progress'])} "
                f"| {merged['worst_wrong']:.3f} |"
            )
        lines += ["", "Per operator (all M pooled):", "",
                  "| operator | argmax | by step | by progress | certified by J, of goals "
                  "| commit-certified |", "|---|---|---|---|---|---|"]  # fmt: skip
        ops: dict[str, list[dict[str, Any]]] = {}
        for p in grid_pieces:
            ops.setdefault(key(OperatorModel(**p["certified_for"])), []).append(p)
        out["per_operator"] = {}
        for name, ps in ops.items():
            merged = _merge([p["summary"] for p in ps])
            goals = sum(p["goals"] for p in ps)
            cert = sum(p["slack_certified"] for p in ps)
            commit = sum(p["commit_certified"] for p in ps)
            out["per_operator"][name] = merged | {"goals": goals, "slack_certified": cert,
                                                   "commit_certified": commit}  # fmt: skip
            lines.append(
                f"| {name} | {_cell(merged['argmax'])} | {_cell(merged['by_step'])} "
                f"| {_cell(merged['by_progress'])} | {cert} / {goals} | {commit} |"
            )
    mismatch = [p for p in _pieces(args.out / "mismatch") if "summary" in p]
    if mismatch:
        out["mismatch"] = {}
        lines += ["", "## Section 2's certificates against users who steer otherwise", "",
                  f"{mismatch[0]['layouts']} random feasible layouts per M, "
                  f"{mismatch[0]['trials']} simulated users per certified goal, unclipped. "
                  "Share of certified goals whose promise fails (rate below 1−α), per M = 2, "
                  "3, 5, 8.", "",
                  "| user | argmax (J > 0 per goal) | commit in ticks | commit in progress "
                  "| worst wrong |", "|---|---|---|---|---|"]  # fmt: skip
        names: dict[str, list[dict[str, Any]]] = {}
        for p in mismatch:
            names.setdefault(_user_name(p["simulated"]), []).append(p)
        for name in MISMATCH:
            ps = sorted(names.get(name, []), key=lambda p: p["m"])
            if not ps:
                continue

            def shares(promise: str, ps: list[dict[str, Any]] = ps) -> str:
                cells = []
                for p in ps:
                    s = p["summary"][promise]
                    cells.append(
                        "—" if not s["goals"] else f"{100 * s['violating'] / s['goals']:.0f} %"
                    )
                return ", ".join(cells)

            out["mismatch"][name] = {str(p["m"]): p["summary"] for p in ps}
            wrong = max(p["summary"]["worst_wrong"] for p in ps)
            lines.append(
                f"| {name} | {shares('argmax')} | {shares('by_step')} "
                f"| {shares('by_progress')} | {wrong:.3f} |"
            )
    e2e = []
    for fit_path in sorted((args.out / "e2e").glob("*/fit.json")):
        fit = json.loads(fit_path.read_text())
        per_m = {p["m"]: p for p in _pieces(fit_path.parent) if "summary" in p}
        if len(per_m) == len(SCENES):
            e2e.append(fit | {"per_m": {str(m): p for m, p in sorted(per_m.items())}})
    if e2e:
        out["e2e"] = e2e
        first = next(iter(e2e[0]["per_m"].values()))
        lines += ["", "## Certified from a fit of 20 calibration reaches, checked against the "
                  "true operator", "",
                  f"{first['layouts']} random feasible layouts per M, {first['trials']} simulated "
                  "users of the true operator per goal certified for the fit's certify_with; "
                  "cells pooled over M = 2, 3, 5, 8 as in the grid.", "",
                  "| true operator | seed | certify_with | intervals cover the truth | argmax | "
                  "by step | by progress |", "|---|---|---|---|---|---|---|"]  # fmt: skip
        for p in e2e:
            merged = _merge([v["summary"] for v in p["per_m"].values()])
            truth = OperatorModel(**p["truth"])
            cw = OperatorModel(**p["certify_with"])
            missed = [k for k, v in p["covered"].items() if not v]
            lines.append(
                f"| {truth.describe()} | {p['seed']} | {cw.describe()} | "
                f"{'NO: ' + ', '.join(missed) if missed else 'yes'} "
                f"| {_cell(merged['argmax'])} | {_cell(merged['by_step'])} "
                f"| {_cell(merged['by_progress'])} |"
            )
    _write(args.report / "operator_validity.json", out)
    (args.report / "operator_validity.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _user_name(simulated: dict[str, Any]) -> str:
    for name, spec in MISMATCH.items():
        operator = spec.get("operator", OperatorModel())
        rest = {k: v for k, v in spec.items() if k != "operator"}
        if _simulated(SimulatedUser(operator, clip=False, **rest)) == simulated:
            return name
    return "?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", default="all", choices=["grid", "mismatch", "e2e", "report", "all"])
    ap.add_argument("--layouts", type=int, default=500)
    ap.add_argument("--mismatch-layouts", type=int, default=200)
    ap.add_argument("--trials", type=int, default=400)
    ap.add_argument(
        "--low-rho-trials", type=int, default=None,
        help="the grid's users per goal for rho < 0.8 (default: --trials)",
    )  # fmt: skip
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path(".cache/bench/operator_validity"))
    ap.add_argument("--report", type=Path, default=Path("docs/results"))
    args = ap.parse_args()
    parts = ["mismatch", "e2e", "grid"] if args.part == "all" else [args.part]
    if args.part != "report":
        with ProcessPoolExecutor(max_workers=args.workers, mp_context=worker_context()) as pool:
            for part in parts:
                {"grid": part_grid, "mismatch": part_mismatch, "e2e": part_e2e}[part](args, pool)
    report(args)


if __name__ == "__main__":
    main()
