"""``legws plan``: stage-specific layouts of a task graph, one per decision point."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from legws_daemon.cli.design_options import load_operators, objective_options, operator_options
from legws_daemon.cli.robot import robot_option
from legws_daemon.design import METHODS
from legws_daemon.formats.printable import echo
from legws_daemon.task.plan import DEFAULT_ITERATIONS, Plan, PlannedDecision


def _j(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _for_whom(settings: dict[str, Any]) -> str:
    who = settings.get("design_for")
    return f", designed for {who}" if isinstance(who, str) else ""


def plan_rows(plan: Plan) -> list[list[str]]:
    """One table row per decision: label, candidates, optimised, J, K, R, feasible, image."""
    rows = []
    for d in plan.decisions:
        if not d.inference:
            j = "no inference needed"
        elif not d.optimised:
            j = f"{_j(d.certificate)} (not optimised)"
        else:
            j = f"{_j(d.certificate_start)} -> {_j(d.certificate)}"
        rows.append(
            [
                d.label,
                ", ".join(d.candidates),
                ", ".join(d.optimised) or "-",
                j,
                "-"
                if d.commit_objective is None
                else f"{d.commit_objective:.3f} ({d.commit_certified}/{len(d.candidates)})",
                "-" if d.commit_rate_estimate is None else f"{d.commit_rate_estimate:.0%}",
                "yes" if d.feasible else "NO",
                d.image or "-",
            ]
        )
    return rows


def render_table(plan: Plan) -> str:
    """The plan as text: a header line, the table, and the notes of infeasible decisions."""
    header = ["decision", "candidates", "optimised", "J start -> planned",
              "K (commit-certified)", "R", "feasible", "image"]  # fmt: skip
    rows = plan_rows(plan)
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(r: list[str]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()

    s = plan.settings
    where = f" in {plan.directory}" if plan.directory is not None else ""
    source = "from the cache" if plan.cached else f"{plan.seconds:.1f} s"
    lines = [
        f"plan of '{plan.taskgraph}' (scene {plan.scene}; {s['method']} for "
        f"{s.get('objective', 'slack')}{_for_whom(s)}, {s['iterations']} iterations, "
        f"seed {s['seed']}; "
        f"{source}){where}",
        "",
        line(header),
        line(["-" * w for w in widths]),
        *map(line, rows),
    ]
    bad: list[PlannedDecision] = [d for d in plan.decisions if not d.feasible]
    if bad:
        lines.append("")
        lines += [f"{d.label}: {d.note}" for d in bad]
    return "\n".join(lines)


@click.command("plan")
@click.argument("taskgraph")
@click.option(
    "--out", "out_dir", type=click.Path(path_type=Path, file_okay=False), default=None,
    help="Also copy plan.json and the pictures here (with --no-cache: default "
    "out/plan/TASKGRAPH).",
)  # fmt: skip
@click.option("--method", type=click.Choice(METHODS), default="cma-me", show_default=True)
@objective_options("Per decision: ")
@operator_options("Per decision: ")
@click.option(
    "--iterations", type=click.IntRange(1, 1_000_000), default=DEFAULT_ITERATIONS,
    show_default=True, help="Search iterations per optimised decision.",
)  # fmt: skip
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--no-cache", is_flag=True, help="Ignore and do not write the plan cache.")
@click.option("--json", "as_json", is_flag=True, help="Print plan.json (and where it is).")
@robot_option("sawyer", what="the arm whose reach and grasps the layouts are for")
@click.option("--quiet", is_flag=True, help="No progress bars.")
def plan_cmd(
    taskgraph: str,
    out_dir: Path | None,
    method: str,
    objective_kind: str,
    commit_form: str,
    operator_file: Path | None,
    operator_files: str | None,
    iterations: int,
    seed: int,
    no_cache: bool,
    as_json: bool,
    robot: str,
    quiet: bool,
) -> None:
    """Plan a layout for every decision point of TASKGRAPH (a name in taskgraphs/ or a path).

    A decision point is what a run offers at once: the start stage, then each stage's
    successors (several = a choice, labelled a|b). For each, the candidates that are movable
    objects (not fixed by the graph) are placed to maximise the certificate J of the
    decision's targets from the EE home (--objective commit: to minimise the commit
    objective K, the latest certified commit as a fraction of the way); every other object
    keeps its pose from the decision before. Single-candidate decisions need no inference.
    --operator FILE designs every decision for one person (an operator file), --operators
    A,B for the worst of a group; plan.json's settings record them (the certificates it
    records stay section 2's user's). Writes plan.json and a top-view PNG per decision;
    results are cached by the graph
    file, the scene file and the settings. A cached plan is used only while every stage
    layout meets the scene's constraints (as a --layout file must) and its recorded
    certificates are the ones its layouts give; else a warning, and it is planned again.
    """
    from legws_daemon.design.stage_plan import plan_taskgraph
    from legws_daemon.formats.files import output_folder
    from legws_daemon.task.plan_file import plan_to_data
    from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

    people = load_operators(operator_file, operator_files)  # a bad file: one line, first
    graph, scene = load_taskgraph(resolve_taskgraph(taskgraph))
    if out_dir is None and no_cache:
        out_dir = Path("out") / "plan" / graph.name
    if out_dir is not None:
        output_folder(out_dir)  # a file or device in the way: one line before any planning
    plan = plan_taskgraph(
        graph, scene, method=method, iterations=iterations, seed=seed, objective=objective_kind,
        commit_form=commit_form, operators=people, arm=robot,
        progress=not quiet, use_cache=not no_cache, out_dir=out_dir,
    )  # fmt: skip
    if as_json:
        data: dict[str, Any] = plan_to_data(plan)
        data["directory"] = str(plan.directory) if plan.directory is not None else None
        data["cached"] = plan.cached
        click.echo(json.dumps(data))
        return
    echo(render_table(plan))
