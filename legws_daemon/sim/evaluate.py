"""``legws eval``: the protocol over many layouts, on a process pool, with a report.

Each layout's episodes are seeded from ``(seed, layout index)``, so the numbers do not
depend on how layouts are spread over the workers: same seed, same result.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from legws_daemon.core.params import Params
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.layout_file import layout_to_data
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.sim.protocol import Evaluator, PickResult, metrics
from legws_daemon.workers import worker_context

_worker: Evaluator | None = None


def _init_worker(scene_source: str, params: Params) -> None:
    global _worker
    _worker = Evaluator(load_scene(scene_source), params)


def _evaluate(job: tuple[int, Layout, int]) -> tuple[int, dict[str, Any], list[PickResult]]:
    index, layout, seed = job
    assert _worker is not None
    ev = _worker.evaluate(layout, [seed, index])
    infeasible = {n: c.reason for n, c in ev.feasibility.items() if not c.feasible}
    return index, {"infeasible": infeasible}, ev.picks


def random_layouts(scene: Scene, n: int, seed: int) -> list[Layout]:
    """``n`` random layouts of the scene's candidate goals satisfying the constraints."""
    cons = LayoutConstraints.of(scene, scene.goal_names)
    poses = cons.sample(n, np.random.default_rng([seed, 0x1A70]))
    return [cons.to_layout(row) for row in poses]


def run_eval(
    scene: Scene,
    layouts: Sequence[Layout],
    seed: int,
    *,
    params: Params | None = None,
    workers: int = 2,
    progress: Callable[[int], object] | None = None,
) -> dict[str, Any]:
    """Evaluate ``layouts``; returns the report (JSON-ready)."""
    params = params or Params()
    started = time.perf_counter()
    jobs = [(i, dict(layout), seed) for i, layout in enumerate(layouts)]
    results: dict[int, tuple[dict[str, Any], list[PickResult]]] = {}
    if workers <= 1:
        _init_worker(scene.source, params)
        for job in jobs:
            i, extra, picks = _evaluate(job)
            results[i] = (extra, picks)
            if progress:
                progress(1)
    else:
        with ProcessPoolExecutor(
            max_workers=workers,
            initializer=_init_worker,
            initargs=(scene.source, params),
            mp_context=worker_context(),
        ) as pool:
            for i, extra, picks in pool.map(_evaluate, jobs):
                results[i] = (extra, picks)
                if progress:
                    progress(1)
    seconds = time.perf_counter() - started
    per_layout = []
    all_picks: list[PickResult] = []
    for i, layout in enumerate(layouts):
        extra, picks = results[i]
        all_picks += picks
        per_layout.append({"index": i, "layout": layout_to_data(layout), **extra, **metrics(picks)})
    accs = [row["accuracy"] for row in per_layout]
    episodes = sum(p.feasible for p in all_picks)
    simulated = sum(p.duration for p in all_picks)
    aggregate = {
        **metrics(all_picks),
        "accuracy_layout_mean": float(np.mean(accs)),
        "accuracy_layout_sd": float(np.std(accs, ddof=1)) if len(accs) > 1 else 0.0,
        "layouts_all_feasible": sum(not row["infeasible"] for row in per_layout),
    }
    return {
        "scene": scene.name,
        "tier": scene.spec.tier,
        "m": len(scene.goal_names),
        "layouts": len(layouts),
        "seed": seed,
        "params": params.as_dict(),
        "aggregate": aggregate,
        "timing": {
            "seconds": seconds,
            "workers": workers,
            "episodes": episodes,
            "episodes_per_second": episodes / seconds if seconds > 0 else None,
            "simulated_seconds": simulated,
        },
        "per_layout": per_layout,
    }


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.1f} %"


def _sec(x: float | None) -> str:
    return "—" if x is None else f"{x:.1f}"


def markdown(report: dict[str, Any]) -> str:
    """The report as Markdown: the aggregate row, the failures, then one row per layout."""
    a = report["aggregate"]
    t_infer = (
        f"{_sec(a['t_infer_mean'])} ± {_sec(a['t_infer_sd'])}"
        if a["t_infer_mean"] is not None
        else "—"
    )
    lines = [
        f"## {report['scene']} ({report['tier'] or 'demo'}, M = {report['m']}): "
        f"{report['layouts']} layouts, seed {report['seed']}",
        "",
        "| accuracy | accuracy, feasible picks | T_infer (s) | commit | wrong commit | no commit "
        "| confirmed | completed | completed, acted on | infeasible picks | picks | picks/s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        f"| {_pct(a['accuracy'])} | {_pct(a['accuracy_feasible'])} | {t_infer} "
        f"| {_pct(a['commit_rate'])} | {_pct(a['wrong_commit_rate'])} "
        f"| {_pct(a['no_commit_rate'])} | {_pct(a['confirmed_rate'])} "
        f"| {_pct(a['completion_rate'])} | {_pct(a['completion_committed'])} "
        f"| {a['infeasible_picks']} | {a['episodes']} "
        f"| {report['timing']['episodes_per_second']:.0f} |",
        "",
        "Failures: " + (", ".join(f"{k} {v}" for k, v in a["failures"].items()) or "none") + ".",
        "",
        "| layout | accuracy | T_infer (s) | commit | wrong | no commit | completed "
        "| infeasible grasps | other failures |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["per_layout"]:
        bad = ", ".join(f"{n} ({r})" for n, r in row["infeasible"].items()) or "—"
        other = {k: v for k, v in row["failures"].items() if k != "infeasible_grasp"}
        others = ", ".join(f"{k} {v}" for k, v in other.items()) or "—"
        lines.append(
            f"| {row['index']} | {_pct(row['accuracy'])} | {_sec(row['t_infer_mean'])} "
            f"| {_pct(row['commit_rate'])} | {_pct(row['wrong_commit_rate'])} "
            f"| {_pct(row['no_commit_rate'])} | {_pct(row['completion_rate'])} | {bad} "
            f"| {others} |"
        )
    return "\n".join(lines) + "\n"


__all__ = ["markdown", "random_layouts", "run_eval"]
