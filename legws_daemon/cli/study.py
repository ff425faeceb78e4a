"""``legws study``: a within-subject user study — check a protocol, plan its schedule, run it
with simulated participants, analyse its data."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import click

from legws_daemon.cli.robot import robot_option
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo

if TYPE_CHECKING:
    from legws_daemon.study.protocol import Protocol
    from legws_daemon.study.schedule import Schedule


@click.group("study")
def study_group() -> None:
    """User studies: protocols, counterbalanced schedules (docs/study.md)."""


@study_group.command("check")
@click.argument("protocol")
def check_cmd(protocol: str) -> None:
    """Validate PROTOCOL (a name in studies/ or a .toml path) and its tasks; print its
    conditions and how many participants balance its design."""
    from legws_daemon.study.counterbalance import design_rows
    from legws_daemon.study.protocol import load_protocol

    p = load_protocol(protocol)
    design = p.spec.design
    rows = design_rows(design.counterbalance, len(p.condition_names))
    echo(f"{p.name}: {p.spec.title}")
    for c in p.spec.conditions:
        task = p.tasks[c.task]
        echo(f"  {c.name}: {task.kind} {task.source}, layout {c.layout}, assist {c.assist}")
    echo(
        f"  {design.counterbalance} design: {len(rows)} orders; "
        f"participants in multiples of {len(rows)}"
    )


@study_group.command("plan")
@click.argument("protocol")
@click.option(
    "--participants",
    type=click.IntRange(1, 999),
    required=True,
    help="How many participants (pseudonyms P01..PNN).",
)
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The study folder: schedule.json, schedule.csv, plan.json.",
)
@click.option(
    "--incomplete",
    is_flag=True,
    help="Write a schedule that is not balanced (a number of participants that is not a "
    "multiple of the design's orders); plan.json lists where it is not.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Replace a different plan already in the folder (its participants' orders change).",
)
def plan_cmd(protocol: str, participants: int, out: Path, incomplete: bool, force: bool) -> None:
    """Plan a study of PROTOCOL: every participant's order of conditions (counterbalanced
    and checked: every condition in every position equally often, and for a Williams design
    every ordered pair of neighbours) and every step of their session."""
    from legws_daemon.study.protocol import load_protocol

    schedule = write_plan(load_protocol(protocol), participants, out, incomplete, force)
    state = (
        "balanced" if not schedule.problems else f"NOT balanced: {len(schedule.problems)} problems"
    )
    echo(
        f"legws: {participants} participants, {schedule.design} design of "
        f"{len(schedule.conditions)} conditions ({len(schedule.rows)} orders), {state} -> {out}",
        err=True,
    )


def write_plan(
    p: Protocol, participants: int, out: Path, incomplete: bool, force: bool
) -> Schedule:
    """Make the schedule of ``participants`` and write it into ``out`` (refused when it is
    not balanced without ``incomplete``, or when ``out`` holds another plan without
    ``force``)."""
    from legws_daemon.formats.files import output_folder, write_atomic
    from legws_daemon.study.schedule import make_schedule
    from legws_daemon.study.store import existing_plan

    schedule = make_schedule(p, participants)
    if schedule.problems and not incomplete:
        rows = len(schedule.rows)
        low = (participants // rows) * rows
        near = ", ".join(str(n) for n in (low, low + rows) if n > 0)
        raise InputError(
            f"{participants} participants do not balance a {schedule.design} design of "
            f"{len(schedule.conditions)} conditions ({schedule.problems[0]}); use a multiple "
            f"of {rows} ({near}) or --incomplete",
            field="--participants",
        )
    plan = schedule.plan_json()
    old = existing_plan(out)
    if old is not None and old != plan and not force:
        raise InputError(
            "holds a different plan (its participants' orders would change); "
            "use another folder or --force",
            source=str(out / "plan.json"),
        )
    output_folder(out)
    write_atomic(out / "plan.json", (json.dumps(plan, indent=1) + "\n").encode())
    write_atomic(
        out / "schedule.json", (json.dumps(schedule.schedule_json(), indent=1) + "\n").encode()
    )
    write_atomic(out / "schedule.csv", schedule.csv_text().encode())
    return schedule


@study_group.command("run")
@click.argument("protocol")
@click.option(
    "--simulate",
    "population",
    required=True,
    help="A population of simulated participants (a name in studies/populations/ or a "
    ".toml path): the whole study runs on the stand-in in simulated time.",
)
@click.option("--participants", type=click.IntRange(1, 999), required=True)
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The study folder: the plan, a folder per participant, the trial table.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the draws.")
@click.option("--incomplete", is_flag=True, help="As for `study plan`.")
@click.option("--force", is_flag=True, help="As for `study plan`.")
@robot_option("sawyer", what="the arm of the stand-in")
def run_cmd(
    protocol: str,
    population: str,
    participants: int,
    out: Path,
    seed: int,
    incomplete: bool,
    force: bool,
    robot: str,
) -> None:
    """Run a whole study of PROTOCOL with simulated participants drawn from a population
    (method.md §10 operator models; planted effects per condition): calibration, practice,
    trials and questionnaires of every session, on the daemon's controller and the MuJoCo
    stand-in in simulated time. Writes the plan, per participant their operator file,
    calibration trace, trial table (CSV, Parquet) and answers, and the study's trial table
    and data dictionary."""
    from legws_daemon.study.population import load_population
    from legws_daemon.study.protocol import load_protocol
    from legws_daemon.study.simulate import simulate_study

    p = load_protocol(protocol)
    people = load_population(population, p.condition_names)
    schedule = write_plan(p, participants, out, incomplete, force)

    def progress(pseudonym: str) -> None:
        echo(f"legws: {pseudonym} done", err=True)

    rows = simulate_study(p, schedule, people, out, seed=seed, arm=robot, progress=progress)
    trials = [r for r in rows if r["kind"] == "trial"]
    done = sum(bool(r["completed"]) for r in trials)
    echo(
        f"legws: {participants} simulated participants, {len(trials)} trials "
        f"({done} completed) -> {out}/trials.parquet",
        err=True,
    )


@study_group.command("analyze")
@click.argument("folder", type=click.Path(path_type=Path, file_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The report folder: report.md, report.html, results.json, figures/.",
)
@click.option("--reference", default=None, help="The reference condition (default: the first).")
@click.option(
    "--power-sims",
    type=click.IntRange(0, 100_000),
    default=200,
    show_default=True,
    help="Simulated datasets per study size in the power analysis (0: none).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the power analysis.")
def analyze_cmd(folder: Path, out: Path, reference: str | None, power_sims: int, seed: int) -> None:
    """Analyse the study in FOLDER (its trials.parquet, or its participants'): mixed models of
    time to task and commit time, a binomial GEE of success, the questionnaires, and the
    power to detect the effects measured."""
    from legws_daemon.study.report import analyze

    results = analyze(folder, out, reference=reference, power_sims=power_sims, seed=seed)
    model = results["models"].get("time_to_task_s")
    if model is not None:
        for c, e in model["conditions"].items():
            echo(
                f"time to task, {c} vs {model['reference']}: {e['estimate']:+.2f} s "
                f"[{e['low']:+.2f}, {e['high']:+.2f}], p = {e['p']:.3g}"
            )
    echo(f"legws: report -> {out}/report.md, {out}/report.html", err=True)
