"""``legws optimize``: search, verify the best elite with the full check, write the results.

Outputs in the run folder (interfaces.md): ``summary.json`` (``objective``, ``coverage``,
``elites``, ``evaluations``, ``seconds`` and more), ``best_layout.json``, ``goals.json``
(certifying it reproduces ``objective`` exactly: ``objective`` *is* that certificate; and
``commit_objective``/``commit_certified`` are its commit certificate, method.md §9;
``commit_rate_estimate`` its estimated commit rate R, ``commit_time_estimate`` its
estimated commit time T in seconds; ``operators`` the same certificates for each person
designed for, ``design_for`` who that was),
``elites.json`` (the elites checked in full, best first, with ``verified``: what ``legws
eval --top-k`` evaluates), ``archive.csv``, ``archive.png`` (heatmap of the searched score
over the grid) and ``best_layout.png``. The search maximises J (``objective="slack"``),
minus the commit objective K (``objective="commit"``), R (``objective="rate"``) or
minus T (``objective="time"``). Results are cached by a hash of the scene file and the
settings.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from legws_daemon import __version__
from legws_daemon.arms import DEFAULT_ARM
from legws_daemon.arms import arm as arm_spec
from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import (
    certify_commit,
    commit_rate_estimate,
    commit_time_estimate,
)
from legws_daemon.core.params import Params
from legws_daemon.design.operators import design_for, operator_report, operator_settings
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.errors import InfeasibleError, LegwsError
from legws_daemon.formats.files import output_folder, read_limited, write_atomic
from legws_daemon.formats.goalset import goalset_to_data, load_goalset
from legws_daemon.formats.operator_file import OperatorFile
from legws_daemon.formats.validation import read_json
from legws_daemon.robot.assets import arm_key
from legws_daemon.robot.gripper import FINGER_GAP, TCP_OFFSET
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.planner import FEASIBILITY, MotionPlanner, stand_in_planner
from legws_daemon.robot.reachability import load_or_build
from legws_daemon.robot.world import World
from legws_daemon.scene.layout_file import dump_json, layout_to_data
from legws_daemon.scene.scene import Scene

if TYPE_CHECKING:  # the search itself (pyribs, numba) is imported only when it runs
    from legws_daemon.design.search import SearchResult

#: Elites tried, best first, before giving up on finding one that passes the full check.
MAX_VERIFIED = 60
#: Verified elites kept in ``elites.json`` (the top-k of ``legws eval``).
KEEP_VERIFIED = 5
#: Densest packing of equal discs in the plane (hexagonal).
_PACKING = math.pi / (2 * math.sqrt(3))
FILES = (
    "summary.json", "best_layout.json", "goals.json", "elites.json", "archive.csv", "archive.png"
)  # fmt: skip


def check_capacity(problem: LayoutProblem) -> None:
    """Fail at once when the bounds cannot hold the movable objects with the clearance."""
    c = problem.constraints
    k = len(problem.names) + len(c.fixed_xy)
    # discs of diameter `clearance` centred in the bounds grown by half a clearance
    area = (c.x_range[1] - c.x_range[0] + c.min_clearance) * (
        c.y_range[1] - c.y_range[0] + c.min_clearance
    )
    needed = k * math.pi * (c.min_clearance / 2) ** 2 / _PACKING
    if needed > area:
        raise InfeasibleError(
            f"{k} objects need {needed:.3f} m² at {c.min_clearance} m clearance; the bounds "
            f"x {c.x_range}, y {c.y_range} offer {area:.3f} m²: no layout exists"
        )


def settings_key(scene: Scene, settings: dict[str, Any]) -> str:
    """Hash of what a run depends on: the scene file, the robot model, the settings and the
    code's version. Cheap, so that a cached run needs no simulator."""
    h = hashlib.sha256()
    h.update(read_limited(Path(scene.source), "scene"))
    # every file of the arm's model, verified, and its whole description
    h.update(arm_key(arm_spec(settings.get("arm", DEFAULT_ARM))).encode())
    extra = {"version": __version__, "tcp": TCP_OFFSET, "gap": FINGER_GAP,
             "feasibility": FEASIBILITY}  # fmt: skip
    h.update(json.dumps({**settings, **extra}, sort_keys=True).encode())
    return h.hexdigest()[:20]


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "legws" / "optimize"


def verify(
    problem: LayoutProblem, result: SearchResult, planner: MotionPlanner, keep: int = 1
) -> list[dict[str, Any]]:
    """Check elites best first until ``keep`` satisfy every constraint and have all grasps
    pass the motion planner's full check (IK, collisions, a straight approach, a clear way
    from home: what ``legws eval`` counts as feasible), or :data:`MAX_VERIFIED` were tried.

    Returns every elite checked, best first: ``rank`` (among the elites), ``layout``,
    ``objective`` (the searched score minus penalties), ``verified`` and, when not,
    ``reason``. At least one is verified.

    Raises:
        InfeasibleError: when none of the elites tried passes.
    """
    scene = problem.scene
    checked: list[dict[str, Any]] = []
    passed = 0
    for rank, elite in enumerate(result.elites[:MAX_VERIFIED]):
        layout = problem.layout(elite.solution)
        poses = scene.poses(layout)
        entry: dict[str, Any] = {
            "rank": rank,
            "layout": layout_to_data(layout),
            "objective": elite.objective,
        }
        problems = problem.constraints.problems(poses)
        if problems:
            entry |= {"verified": False, "reason": problems[0]}
        else:
            planner.set_layout(poses)
            goals = scene.goal_set(layout, goals=problem.names)
            rotations = goals.rotations
            reason = None
            for i, n in enumerate(goals.names):
                c = planner.check(n, goals.positions[i], rotations[i], int(goals.symmetry[i]))
                if not c.feasible:
                    reason = f"{n}: {c.reason}"
                    break
            entry |= {"verified": reason is None} | ({"reason": reason} if reason else {})
        checked.append(entry)
        passed += entry["verified"]
        if passed >= keep:
            return checked
    if passed:
        return checked
    raise InfeasibleError(
        f"none of the best {min(MAX_VERIFIED, len(result.elites))} elites passed the full "
        "IK, collision and approach check; run more iterations or relax the scene"
    )


def heatmap_png(result: SearchResult) -> bytes:
    """The archive as a 20 × 20 heatmap of the searched score, J, -K or R (feasible elites;
    grey: empty or infeasible)."""
    from PIL import Image

    from legws_daemon.design.search import GRID

    grid = np.full(GRID[0] * GRID[1], np.nan)
    for row in result.table:
        if row["feasible_screen"]:
            grid[row["cell"]] = row["score"]
    grid = grid.reshape(GRID)
    finite = grid[np.isfinite(grid)]
    lo, hi = (float(finite.min()), float(finite.max())) if len(finite) else (0.0, 1.0)
    t = np.clip((grid - lo) / max(hi - lo, 1e-9), 0, 1)
    # a blue-to-yellow ramp; rows: first measure (up), columns: second measure (right)
    rgb = np.stack([40 + 215 * t, 60 + 160 * t, 140 - 110 * t], axis=-1)
    rgb[~np.isfinite(grid)] = 200
    img = Image.fromarray(np.flipud(rgb.astype(np.uint8))).resize(
        (400, 400), Image.Resampling.NEAREST
    )
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue()


def optimize(
    scene: Scene,
    out_dir: Path,
    *,
    method: str = "cma-me",
    iterations: int = 1000,
    seed: int = 0,
    movable: Sequence[str] | None = None,
    objective: str = "slack",
    commit_form: str = "sum",
    operators: Sequence[OperatorFile] = (),
    arm: str = DEFAULT_ARM,
    use_cache: bool = True,
    render: bool = True,
    progress: Callable[[int, float, float], None] | None = None,
) -> dict[str, Any]:
    """Optimise a scene's layout and write the run folder; returns the summary.

    ``operators``: design for these people (their ``certify_with`` models, the worst of
    them; method.md §10); empty: for section 2's user. ``arm``: the arm whose reach and
    grasps screen and verify the layouts."""
    from legws_daemon.design.search import search

    problem = LayoutProblem(
        scene, movable, Params(), objective=objective, commit_form=commit_form,
        operators=[f.certify_with for f in operators],
    )  # fmt: skip
    check_capacity(problem)
    settings = {
        "scene": scene.name,
        "objective_kind": objective,
        "method": method,
        "iterations": iterations,
        "seed": seed,
        "movable": list(problem.names),
        "params": problem.params.as_dict(),
    }
    if objective == "commit":  # what the search minimised: K of this form
        settings["commit_form"] = commit_form
    if operators:  # for whom (absent: section 2's user, as runs before the option)
        settings["operators"] = operator_settings(operators)
    if arm != DEFAULT_ARM:  # absent: the Sawyer (the key of runs made before arms)
        settings["arm"] = arm
    key = settings_key(scene, settings)
    cached = cache_dir() / key
    output_folder(out_dir)
    if use_cache and all((cached / f).is_file() for f in FILES):
        for f in cached.iterdir():
            write_atomic(out_dir / f.name, read_limited(f, "cache file"))
        summary: dict[str, Any] = read_json(out_dir / "summary.json", "summary")
        summary["cached"] = True
        return summary
    world = World(scene, arm=arm)
    q_home = home_configuration(world, scene.home.position, scene.home.rotation).q
    problem.screen = load_or_build(world, q_home)
    result = search(problem, method, iterations, seed, progress)
    checked = verify(problem, result, stand_in_planner(world), KEEP_VERIFIED)
    best = next(e for e in checked if e["verified"])
    layout, rank = problem.layout(result.elites[best["rank"]].solution), best["rank"]
    goals = scene.goal_set(layout, goals=problem.names)
    write_atomic(out_dir / "best_layout.json", dump_json(layout_to_data(layout)).encode())
    write_atomic(out_dir / "goals.json", dump_json(goalset_to_data(goals, problem.params)).encode())
    # the reported objective is the certificate of the written goal set, so that
    # `legws certify goals.json` reproduces it to the last digit
    written, params = load_goalset(out_dir / "goals.json")
    slack = certify(written, params).objective
    commit = certify_commit(written, params)  # method.md §9 as `legws certify --commit`
    commit_sum = certify_commit(written, params, form="sum")
    rate = commit_rate_estimate(written, params)
    time_estimate = commit_time_estimate(written, params)
    write_atomic(out_dir / "elites.json", (json.dumps(checked, indent=2) + "\n").encode())
    summary = {
        "objective": slack,
        "commit_objective": commit.objective,
        "commit_certified": commit.certified,
        "commit_objective_sum": commit_sum.objective,
        "commit_certified_sum": commit_sum.certified,
        "commit_rate_estimate": rate,
        "commit_time_estimate": time_estimate,
        "goals": len(written.names),
        "coverage": result.coverage,
        "elites": len(result.elites),
        "evaluations": result.evaluations,
        "seconds": result.seconds,
        "feasible_coverage": result.feasible_coverage,
        "qd_score": result.qd_score,
        "verified_rank": rank,
        "verified_ranks": [e["rank"] for e in checked if e["verified"]],
        "measure_ranges": result.ranges,
        "key": key,
        "cached": False,
        **settings,
        # each person's certificates of the written goals (numpy, the robot's clip)
        "operators": [operator_report(written, params, f) for f in operators],
        "design_for": design_for([f.name for f in operators]),
    }
    buf = io.StringIO()
    if result.table:
        writer = csv.DictWriter(buf, fieldnames=list(result.table[0]))
        writer.writeheader()
        writer.writerows(result.table)
    write_atomic(out_dir / "archive.csv", buf.getvalue().encode())
    write_atomic(out_dir / "archive.png", heatmap_png(result))
    if render:
        try:
            from legws_daemon.robot.render import render_layout, save_png

            save_png(render_layout(scene, layout, 800, 600, "top"), out_dir / "best_layout.png")
        except LegwsError as err:  # no GL here: the numbers still stand
            summary["render_error"] = str(err)
    write_atomic(out_dir / "summary.json", (json.dumps(summary, indent=2) + "\n").encode())
    if use_cache:
        output_folder(cached)
        for f in out_dir.iterdir():
            if f.is_file() and (f.name in FILES or f.name == "best_layout.png"):
                write_atomic(cached / f.name, read_limited(f, "cache file"))
    return summary
