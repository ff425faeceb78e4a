"""The paper's Tables 1 and 2 on the unified loop, as the person sees them (method.md §8, §9).

Parts (each resumable: a finished piece is read back, not run again):

* ``random``: per tier, ``--layouts`` random feasible layouts for each of ``--random-seeds``
  (30 × 3 by default), evaluated by ``legws eval``'s code (``run_eval``) with
  ``--episodes-per-goal`` picks per goal; 95 % bootstrap intervals over the layouts;
* ``optimise``: ``legws optimize``'s code for every tier × objective (``slack``, ``commit``,
  ``rate``, ``time``)
  × method × seed (5 seeds by default), 1000 iterations; runs land in
  ``OUT/runs/OBJECTIVE/SCENE/METHOD/seedS`` (and in the optimisation cache);
* ``eval``: per tier × objective, the ``--top-k`` best verified elites of every CMA-ME seed,
  evaluated together; intervals over layouts and over the optimisation seeds;
* ``report``: ``tables.json``, ``tables.md`` (Table 1 and Table 2 with the paper's numbers
  beside ours), ``person.png`` (commit rate and Kaplan–Meier ``T_infer`` per tier and
  condition, with intervals) and ``layouts.png`` (every tier's shipped layout next to its
  slack- and commit-optimised layout, seed 0).

Usage:
    python benchmarks/tables.py [--part all|random|optimise|eval|report] [--tiers a,b]
        [--objectives slack,commit,rate,time] [--methods cma-me,map-elites,cma-mae]
        [--seeds 0,1,2,3,4] [--random-seeds 0,1,2] [--layouts 30] [--episodes-per-goal 10]
        [--top-k 3] [--iterations 1000] [--workers 2] [--out docs/results/tables]
        [--no-figures]

Every rate in the report has a 95 % interval: the bootstrap over layouts or seeds, or, where
every pick counted succeeded or none did, the Clopper–Pearson bound on its k of n picks
(``legws_daemon.sim.evaluate.rate_intervals``); the report reads the evaluations on disk and
reruns nothing.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.commit import commit_batch, commit_rate_estimate, commit_time_estimate
from legws_daemon.core.params import Params
from legws_daemon.design.optimize import optimize
from legws_daemon.formats.goalset import load_goalset
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.sim.evaluate import (
    RATE_NOTATION,
    Elite,
    format_rate,
    group_intervals,
    load_elites,
    random_layouts,
    rate_intervals,
    run_eval,
    user_model,
)

#: The paper's numbers: tier, J of ME, T_infer random (mean, sd), T_infer ME, accuracy
#: random, accuracy ME, Table 2 seconds, elites, coverage.
PAPER = {
    "breakfast_easy": ("Easy", 8.03, 6.1, 2.4, 5.4, 0.92, 1.00, 597, 374, 0.935),
    "desk": ("Med-A", 4.68, 6.9, 3.4, 9.4, 0.91, 1.00, 920, 399, 0.998),
    "breakfast": ("Med-B", 5.14, 9.9, 2.8, 9.5, 1.00, 1.00, 653, 400, 1.0),
    "kitchen_prep": ("Med-C", 6.07, 7.7, 3.9, 5.1, 0.93, 1.00, 727, 397, 0.993),
    "meal_assembly": ("Hard-A", 1.74, 12.5, 3.0, 10.6, 0.88, 1.00, 461, 400, 1.0),
    "cluttered": ("Hard-B", -0.99, 10.9, 3.6, 9.6, 0.25, 0.54, 340, 400, 1.0),
}
OBJECTIVES = ("slack", "commit", "rate", "time")
METHODS = ("cma-me", "map-elites", "cma-mae")
#: The summary fields Table 2 reports per run.
RUN_KEYS = ("objective", "commit_objective", "commit_certified", "commit_objective_sum",
            "commit_certified_sum", "commit_rate_estimate", "commit_time_estimate", "coverage",
            "feasible_coverage", "elites", "qd_score", "seconds", "verified_rank")  # fmt: skip


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def _write(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n")
    tmp.replace(path)


def part_random(args: argparse.Namespace) -> None:
    for name in args.tiers:
        path = args.out / "random" / f"{name}.json"
        if path.is_file():
            continue
        sc = load_scene(name)
        layouts = [lay for s in args.random_seeds for lay in random_layouts(sc, args.layouts, s)]
        with tqdm(total=len(layouts), desc=f"random {name}", unit="layout") as bar:
            report = run_eval(
                sc, layouts, args.random_seeds[0], workers=args.workers,
                episodes_per_goal=args.episodes_per_goal, progress=bar.update,
            )  # fmt: skip
        report["random_seeds"] = args.random_seeds
        # the best of 10,000 random feasible layouts, for the certificates' scale
        cons = LayoutConstraints.of(sc, sc.goal_names)
        poses = cons.sample(10_000, np.random.default_rng([0, 77]))
        pos, rot, sym = sc.grasp_batch(sc.goal_names, poses)
        home = sc.home
        j = certify_batch(home.position, home.rotation, pos, rot, sym, Params()).objective
        k = commit_batch(home.position, home.rotation, pos, rot, sym, Params()).objective
        report["random_10000"] = {
            "best_J": float(j.max()),
            "best_K": float(k.min()),
            "share_K_le_1": float(np.mean(k <= 1.0)),
        }
        _write(path, report)


def run_dir(args: argparse.Namespace, objective: str, name: str, method: str, seed: int) -> Path:
    root: Path = args.out
    return root / "runs" / objective / name / method / f"seed{seed}"


def part_optimise(args: argparse.Namespace) -> None:
    jobs = [(o, n, m, s) for o in args.objectives for n in args.tiers for m in args.methods
            for s in args.seeds]  # fmt: skip
    for objective, name, method, seed in tqdm(jobs, desc="optimise", unit="run"):
        out = run_dir(args, objective, name, method, seed)
        if (out / "summary.json").is_file():
            continue
        t = time.perf_counter()
        summary = optimize(load_scene(name), out, method=method, iterations=args.iterations,
                           seed=seed, objective=objective, render=False)  # fmt: skip
        summary["wall_seconds"] = time.perf_counter() - t
        _write(out / "summary.json", summary)


def part_eval(args: argparse.Namespace) -> None:
    for objective in args.objectives:
        for name in args.tiers:
            path = args.out / "optimised" / objective / f"{name}.json"
            if path.is_file():
                continue
            sc = load_scene(name)
            runs = [run_dir(args, objective, name, "cma-me", s) for s in args.seeds]
            if not all((r / "summary.json").is_file() for r in runs):
                print(f"eval {objective} {name}: optimisation runs missing, skipped")
                continue
            picked = [x for r in runs for x in load_elites(r, sc, args.top_k)]
            layouts = [lay for lay, _ in picked]
            elites: list[Elite] = [e for _, e in picked]
            with tqdm(total=len(layouts), desc=f"{objective} {name}", unit="layout") as bar:
                report = run_eval(sc, layouts, 0, workers=args.workers, elites=elites,
                                  episodes_per_goal=args.episodes_per_goal,
                                  progress=bar.update)  # fmt: skip
            _write(path, report)


# --- report ---------------------------------------------------------------------------------


def _load(path: Path) -> dict[str, Any] | None:
    return json.loads(path.read_text()) if path.is_file() else None


def collect(args: argparse.Namespace) -> dict[str, Any]:
    rows: dict[str, Any] = {}
    for name in args.tiers:
        row: dict[str, Any] = {"random": _load(args.out / "random" / f"{name}.json")}
        for objective in OBJECTIVES:
            row[objective] = {"eval": _load(args.out / "optimised" / objective / f"{name}.json")}
            if objective == "rate" and row[objective]["eval"] is None:
                # benchmarks/commit_ceiling.py's loop evaluation of its best rate layouts
                ceiling = (_load(args.out.parent / "commit_ceiling.json") or {}).get(name, {})
                loop = ceiling.get("loop")
                row[objective]["eval"] = (
                    {"aggregate": loop["aggregate"], "per_layout": loop["per_layout"]}
                    if loop
                    else None
                )
                if loop:
                    row[objective]["ceiling"] = _ceiling_summary(ceiling)
            for method in METHODS:
                runs = []
                for s in args.seeds:
                    summary = _load(run_dir(args, objective, name, method, s) / "summary.json")
                    if summary is not None:
                        runs.append({"seed": s} | {k: summary.get(k) for k in RUN_KEYS})
                        if runs[-1]["commit_rate_estimate"] is None:  # runs made before R, T
                            goals, params = load_goalset(
                                run_dir(args, objective, name, method, s) / "goals.json"
                            )
                            runs[-1]["commit_rate_estimate"] = commit_rate_estimate(goals, params)
                            runs[-1]["commit_time_estimate"] = commit_time_estimate(goals, params)
                row[objective][method] = runs
        rows[name] = row
    return rows


def _ceiling_summary(ceiling: dict[str, Any]) -> dict[str, Any]:
    """What the tables use of benchmarks/commit_ceiling.py's result (the layouts left out)."""
    best = ceiling.get("best_monte_carlo") or {}
    return {
        "best_chance_per_seed": [r.get("best_chance") for r in ceiling.get("runs", [])],
        "chance_vs_monte_carlo_correlation": ceiling.get("chance_vs_monte_carlo_correlation"),
        "best_monte_carlo": {k: v for k, v in best.items() if k != "layout"},
        "random": ceiling.get("random"),
    }


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.0f}"


def _time(agg: dict[str, Any], key: str, ci: dict[str, Any] | None) -> str:
    """A time in seconds with its bootstrap interval (``∞``: a bound not reached)."""
    value = agg.get(key)
    if value is None:
        return "—"
    iv = (ci or {}).get(key)
    if iv is None:
        return f"{value:.1f}"

    def b(x: float | None) -> str:
        return "∞" if x is None else f"{x:.1f}"

    return f"{value:.1f} [{b(iv[0])}, {b(iv[1])}]"


#: Decimals of each rate column of Table 1 (completion is close to 100 %: one more).
RATE_DIGITS = {"commit_true_rate": 0, "commit_rate_min_goal": 0, "wrong_commit_rate": 0,
               "accuracy": 0, "completion_committed": 1}  # fmt: skip


def _rates(report: dict[str, Any], group: str) -> dict[str, str]:
    """The rates of a report with their intervals over ``group`` (:func:`format_rate`)."""
    a = report["aggregate"]
    rates = rate_intervals(a, group_intervals(report, group))
    return {k: format_rate(r, RATE_DIGITS[k], 1, "") for k, r in rates.items()}


def _failures(agg: dict[str, Any]) -> str:
    return ", ".join(f"{k} {v}" for k, v in (agg.get("failures") or {}).items()) or "none"


def _person(report: dict[str, Any] | None, group: str) -> list[str]:
    if report is None:
        return ["—"] * 9
    a = report["aggregate"]
    ci = group_intervals(report, group)
    rates = _rates(report, group)
    km = a.get("t_infer_km_median")
    km_text = _time(a, "t_infer_km_median", ci) if km is not None else "> 30"
    return [
        str(a["episodes"]),
        rates["commit_true_rate"],
        rates["commit_rate_min_goal"],
        rates["wrong_commit_rate"],
        rates["completion_committed"],
        _failures(a),
        _time(a, "t_infer_mean", ci),
        km_text,
        rates["accuracy"],
    ]


#: Said once above the tables of rates: what they hold for, and how to read the intervals.
NOTES = (
    f"Every rate and time holds for {user_model(None)}. {RATE_NOTATION}"
    " *Completed*: the true goal's object lifted 2 cm clear of the table, of the picks the"
    " controller acted on (committed or confirmed). *Failures*: every named failure by kind"
    " (`infeasible_grasp`: no episode); a failure on the way home, after the lift, leaves the"
    " pick completed, so failures can outnumber the picks not completed."
)


def _hard_b_rate(rows: dict[str, Any]) -> list[str]:
    """Hard-B designed for the rate: the loop rows of every condition and the Monte Carlo of
    benchmarks/commit_ceiling.py, from the same data as Table 1."""
    name = "cluttered"
    row = rows.get(name)
    if row is None or row["rate"].get("ceiling") is None:
        return []
    ceiling = row["rate"]["ceiling"]
    loop = row["rate"]["eval"]
    n_runs = (loop["aggregate"]["intervals"].get("runs") or {}).get("groups")
    rate_label = (
        f"rate-optimised (CMA-ME, {len(ceiling['best_chance_per_seed'])} seeds; the "
        f"{len(loop.get('per_layout') or [])} best layouts, from {n_runs} of them; loop)"
    )

    def named(report: dict[str, Any] | None, what: str) -> str:
        n = len(report["per_layout"]) if report else 0
        return f"{what} ({n} layouts, loop)"

    conds = [
        (named(row["random"], "random"), row["random"], "layouts"),
        (named(row["slack"]["eval"], "slack-optimised, CMA-ME"), row["slack"]["eval"], "runs"),
        (named(row["commit"]["eval"], "commit-optimised, CMA-ME"), row["commit"]["eval"], "runs"),
        (rate_label, loop, "runs"),
    ]
    out = [
        "### Hard-B designed for the rate (`--objective rate`)",
        "",
        "The rows on the loop are those of Table 1 (the same notation; intervals over "
        "layouts or seeds as named). The Monte Carlo rows are `benchmarks/commit_ceiling.py`'s: "
        "the same simulated user (method.md §2, speed-clipped) without the stand-in, until "
        "arrival, with the Clopper–Pearson interval on all trials of the layout.",
        "",
        "| Hard-B (M = 8) | intervals over | picks | commit on the true goal % "
        "| worst goal % | wrong commit % | KM T_infer s |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, report, group in conds:
        if report is None:
            continue
        a = report["aggregate"]
        groups = (a.get("intervals", {}).get(group) or {}).get("groups")
        rates = _rates(report, group)
        km = _time(a, "t_infer_km_median", group_intervals(report, group))
        out.append(
            f"| {label} | {'layouts' if group == 'layouts' else 'seeds'} ({groups}) "
            f"| {a['episodes']} | {rates['commit_true_rate']} | {rates['commit_rate_min_goal']} "
            f"| {rates['wrong_commit_rate']} | {km} |"
        )
    best = ceiling["best_monte_carlo"]
    if best:
        out.append(
            "| rate-optimised, Monte Carlo of the best layout | — | — "
            f"| {_pct(best['rate'])} [{_pct(best['lower95'])}, {_pct(best['upper95'])}] "
            f"| {_pct(best['min_goal'])} | {_pct(best['wrong'])} | — |"
        )
    rnd = ceiling.get("random")
    if rnd:
        out.append(
            f"| best of {rnd['layouts']} random layouts, Monte Carlo (median) | — | — "
            f"| {_pct(rnd['best'])} ({_pct(rnd['median'])}) | — | — | — |"
        )
    a = loop["aggregate"]
    per_layout = loop.get("per_layout") or []
    per_goal = ", ".join(f"{g} {_pct(r)} %" for g, r in a["commit_rate_by_goal"].items())
    each = ", ".join(
        f"{_pct(r['commit_true_rate'])} % (worst goal {_pct(r['commit_rate_min_goal'])} %)"
        for r in per_layout
    )
    chances = ", ".join(f"{c:.3f}" for c in ceiling["best_chance_per_seed"] if c is not None)
    out += [
        "",
        f"Rate-optimised on the loop, per layout: {each or '—'}; per goal over the "
        f"{len(per_layout)} layouts: {per_goal}. Best R per seed {chances}; R against the "
        f"Monte Carlo rate over the measured elites: correlation "
        f"{ceiling['chance_vs_monte_carlo_correlation']:.2f}; the best layout by Monte Carlo: "
        f"R {best['chance']:.3f}, Monte Carlo {best['rate']:.3f}.",
    ]
    return out


def _mean_sd(values: list[float | None], digits: int = 2) -> str:
    v = [x for x in values if x is not None]
    if not v:
        return "—"
    if len(v) == 1:
        return f"{v[0]:.{digits}f}"
    return f"{np.mean(v):.{digits}f} ± {np.std(v, ddof=1):.{digits}f}"


def markdown(rows: dict[str, Any]) -> str:
    head = ("picks | commit on the true goal % | min over goals % | wrong commit % "
            "| completed, of acted on % | failures | T_infer mean s | T_infer KM median s "
            "| accuracy %")  # fmt: skip
    out = [
        "### Table 1, as the person sees it",
        "",
        "Random: intervals over layouts; optimised: over the optimisation seeds (each seed's "
        "verified elites pooled). Paper: T_infer and accuracy of its Table 1.",
        "",
        NOTES,
        "",
        f"| tier | M | condition | {head} | paper T_infer | paper accuracy % |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, row in rows.items():
        tier, _, t_r, sd_r, t_me, a_r, a_me, *_ = PAPER[name]
        m = len(load_scene(name).goal_names)
        cells = {
            "random": (_person(row["random"], "layouts"), f"{t_r} ± {sd_r}", _pct(a_r)),
            "slack-optimised": (_person(row["slack"]["eval"], "runs"), f"{t_me} (ME)", _pct(a_me)),
        }
        for objective in OBJECTIVES[1:]:
            if objective == "commit" or row[objective]["eval"] is not None:
                cells[f"{objective}-optimised"] = (
                    _person(row[objective]["eval"], "runs"),
                    "—",
                    "—",
                )
        for cond, (person, t_paper, a_paper) in cells.items():
            out.append(f"| {tier} | {m} | {cond} | " + " | ".join(person)
                       + f" | {t_paper} | {a_paper} |")  # fmt: skip
    hard_b = _hard_b_rate(rows)
    out += ["", *hard_b] if hard_b else []
    out += [
        "",
        "### Certificates of the optimised layouts (CMA-ME, mean ± sd over seeds)",
        "",
        "| tier | objective | J | K (§9) | certified (§9) | K (exact sum) | certified (exact "
        "sum) | largest K, exact sum | R | T s | verified rank per seed | paper J (ME) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, row in rows.items():
        tier, j_paper, *_ = PAPER[name]
        for objective in OBJECTIVES:
            runs = row[objective]["cma-me"]
            if not runs:
                continue
            out.append(
                f"| {tier} | {objective} | {_mean_sd([r['objective'] for r in runs])} "
                f"| {_mean_sd([r['commit_objective'] for r in runs])} "
                f"| {_mean_sd([r['commit_certified'] for r in runs], 1)} "
                f"| {_mean_sd([r['commit_objective_sum'] for r in runs])} "
                f"| {_mean_sd([r['commit_certified_sum'] for r in runs], 1)} "
                f"| {max(r['commit_objective_sum'] for r in runs):.4f} "
                f"| {_mean_sd([r['commit_rate_estimate'] for r in runs])} "
                f"| {_mean_sd([r['commit_time_estimate'] for r in runs])} "
                f"| {', '.join(str(r['verified_rank']) for r in runs)} | {j_paper} |"
            )
    out += [
        "",
        "### Table 2: the search (mean ± sd over seeds)",
        "",
        "| tier | objective | method | seeds | seconds | elites | coverage % | feasible "
        "coverage % | J | K (§9) | K (exact sum) | paper ME: s / elites / coverage % |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, row in rows.items():
        tier, *_, s_p, e_p, c_p = PAPER[name]
        for objective in OBJECTIVES:
            for method in METHODS:
                runs = row[objective][method]
                if not runs:
                    continue
                cov = [100 * r["coverage"] for r in runs]
                feas = [100 * r["feasible_coverage"] for r in runs]
                out.append(
                    f"| {tier} | {objective} | {method} | {len(runs)} "
                    f"| {_mean_sd([r['seconds'] for r in runs], 0)} "
                    f"| {_mean_sd([r['elites'] for r in runs], 0)} | {_mean_sd(cov, 1)} "
                    f"| {_mean_sd(feas, 1)} | {_mean_sd([r['objective'] for r in runs])} "
                    f"| {_mean_sd([r['commit_objective'] for r in runs])} "
                    f"| {_mean_sd([r['commit_objective_sum'] for r in runs])} "
                    f"| {s_p} / {e_p} / {100 * c_p:.1f} |"
                )
    return "\n".join(out) + "\n"


def plot(rows: dict[str, Any], path: Path) -> None:
    """Commit rate and Kaplan–Meier T_infer per tier and condition, with 95 % intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(rows)
    conds = [("random", "layouts", "random")] + [
        (o, "runs", f"{o}-optimised") for o in OBJECTIVES
        if any(rows[n][o]["eval"] is not None for n in names)
    ]  # fmt: skip
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    width = 0.8 / len(conds)
    x = np.arange(len(names))
    for c, (key, group, label) in enumerate(conds):
        for ax, metric, scale in ((axes[0], "commit_true_rate", 100.0),
                                  (axes[1], "t_infer_km_median", 1.0)):  # fmt: skip
            vals, lo, hi = [], [], []
            for n in names:
                rep = rows[n][key] if key == "random" else rows[n][key]["eval"]
                a = rep["aggregate"] if rep else {}
                v = a.get(metric)
                iv = (a.get("intervals", {}).get(group) or {}).get(metric) or [v, v]
                if rep is not None and metric == "commit_true_rate":
                    # the tables' interval: Clopper–Pearson at 0 % and 100 %, else bootstrap
                    r = rate_intervals(a, group_intervals(rep, group))[metric]
                    iv = [r.low, r.high] if r is not None and r.low is not None else [v, v]
                vals.append(np.nan if v is None else scale * v)
                lo.append(np.nan if v is None or iv[0] is None else scale * (v - iv[0]))
                hi.append(np.nan if v is None or iv[1] is None else scale * (iv[1] - v))
            offset = (c - (len(conds) - 1) / 2) * width
            ax.bar(x + offset, vals, width, yerr=[lo, hi], capsize=3, label=label)
    tiers = [f"{PAPER[n][0]}\n(M={len(load_scene(n).goal_names)})" for n in names]
    paper_t = [PAPER[n][4] for n in names]
    axes[1].scatter(x, paper_t, marker="_", s=300, color="black", zorder=3,
                    label="paper, ME optimised")  # fmt: skip
    axes[0].set_ylabel("commit on the true goal before arrival (%)")
    axes[0].set_ylim(0, 105)
    axes[1].set_ylabel("T_infer, Kaplan–Meier median (s)")
    for ax in axes:
        ax.set_xticks(x, tiers)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(loc="lower left", fontsize=8)
    axes[1].legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def layouts_figure(args: argparse.Namespace, path: Path) -> None:
    """Every tier: its shipped layout, the slack- and the commit-optimised one (seed 0)."""
    from PIL import Image, ImageDraw

    from legws_daemon.robot.render import render_layout
    from legws_daemon.scene.layout_file import load_layout

    w, h = 320, 240
    cols = (
        "shipped",
        *(
            o
            for o in OBJECTIVES
            if run_dir(args, o, args.tiers[0], "cma-me", args.seeds[0]).is_dir()
        ),
    )
    sheet = Image.new("RGB", (w * len(cols) + 90, h * len(args.tiers) + 24), "white")
    draw = ImageDraw.Draw(sheet)
    for c, label in enumerate(cols):
        draw.text((90 + c * w + 8, 6), label if c == 0 else f"{label}-optimised", fill="black")
    for r, name in enumerate(args.tiers):
        sc = load_scene(name)
        draw.text((6, 24 + r * h + h // 2), f"{PAPER[name][0]}\nM={len(sc.goal_names)}",
                  fill="black")  # fmt: skip
        for c, cond in enumerate(cols):
            layout = sc.default_layout()
            if cond != "shipped":
                best = run_dir(args, cond, name, "cma-me", args.seeds[0]) / "best_layout.json"
                if not best.is_file():
                    continue
                layout = load_layout(best, sc)
            img = Image.fromarray(render_layout(sc, layout, w, h, "top"))
            sheet.paste(img, (90 + c * w, 24 + r * h))
    sheet.save(path)


def part_report(args: argparse.Namespace) -> None:
    rows = collect(args)
    _write(args.out / "tables.json", rows)
    text = markdown(rows)
    (args.out / "tables.md").write_text(text)
    print(text)
    if not args.figures:
        return
    plot(rows, args.out / "person.png")
    try:
        layouts_figure(args, args.out / "layouts.png")
    except Exception as err:  # no OpenGL here: the tables still stand
        print(f"layouts.png not drawn: {err}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("all", "random", "optimise", "eval", "report"),
                    default="all")  # fmt: skip
    ap.add_argument("--tiers", default=",".join(PAPER))
    ap.add_argument("--objectives", default=",".join(OBJECTIVES))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--random-seeds", default="0,1,2")
    ap.add_argument("--layouts", type=int, default=30)
    ap.add_argument("--episodes-per-goal", type=int, default=10)
    ap.add_argument("--top-k", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("docs/results/tables"))
    ap.add_argument("--no-figures", dest="figures", action="store_false",
                    help="report: tables.json and tables.md only, person.png and layouts.png "
                         "left as they are")  # fmt: skip
    args = ap.parse_args()
    args.tiers = [t for t in args.tiers.split(",") if t]
    args.objectives = [o for o in args.objectives.split(",") if o]
    args.methods = [m for m in args.methods.split(",") if m]
    args.seeds = _ints(args.seeds)
    args.random_seeds = _ints(args.random_seeds)
    started = time.perf_counter()
    parts = {"random": part_random, "optimise": part_optimise, "eval": part_eval,
             "report": part_report}  # fmt: skip
    for name, fn in parts.items():
        if args.part in ("all", name):
            fn(args)
    print(f"{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
