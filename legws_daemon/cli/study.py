"""``legws study``: a within-subject user study — check a protocol, plan its schedule."""

from __future__ import annotations

import json
from pathlib import Path

import click

from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo


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
    from legws_daemon.formats.files import output_folder, write_atomic
    from legws_daemon.study.protocol import load_protocol
    from legws_daemon.study.schedule import make_schedule
    from legws_daemon.study.store import existing_plan

    p = load_protocol(protocol)
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
    state = (
        "balanced" if not schedule.problems else f"NOT balanced: {len(schedule.problems)} problems"
    )
    echo(
        f"legws: {participants} participants, {schedule.design} design of "
        f"{len(schedule.conditions)} conditions ({len(schedule.rows)} orders), {state} -> {out}",
        err=True,
    )
