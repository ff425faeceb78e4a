"""``legws study``: a within-subject user study — check a protocol, plan its schedule, run it
with simulated participants, analyse its data."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import click

from legws_daemon.cli.robot import real_arm_options, robot_option
from legws_daemon.cli.study_export import export_cmd
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.printable import echo

if TYPE_CHECKING:
    from legws_daemon.study.protocol import Protocol
    from legws_daemon.study.schedule import Schedule


#: Seconds the participant's page stays up after the session's last step at most: until the
#: page has read that it is over (it polls twice a second), or this long when nobody looks.
DONE_LINGER_S = 10.0


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
    "--participant",
    default=None,
    help="Run this participant's session with a person (a pseudonym of the plan in --out, "
    "e.g. P07): the page, the robot of --profile, the recordings.",
)
@click.option(
    "--simulate",
    "population",
    default=None,
    help="A population of simulated participants (a name in studies/populations/ or a "
    ".toml path): alone, the whole study runs on the stand-in in simulated time; with "
    "--participant, that participant is drawn from it (a rehearsal, in real time).",
)
@click.option(
    "--participants",
    type=click.IntRange(1, 999),
    default=None,
    help="With --simulate: how many participants (the plan is made, as `study plan`).",
)
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The study folder: the plan, a folder per participant, the trial table.",
)
@click.option(
    "--profile",
    default="sim",
    show_default=True,
    help="With --participant: the "
    "hardware profile of the robot (a name in hw_profiles/ or a .toml path).",
)
@click.option(
    "--zenoh-config",
    "zenoh_config",
    default=None,
    type=click.Path(path_type=Path, dir_okay=False),
    help="With --participant: a zenoh configuration for a real network.",
)
@click.option(
    "--page-port",
    type=click.IntRange(0, 65535),
    default=8090,
    show_default=True,
    help="With --participant: the participant's page, http://127.0.0.1:PORT/ (0: any free port).",
)
@click.option(
    "--viewer-port",
    type=click.IntRange(0, 65534),
    default=9090,
    show_default=True,
    help="With --participant: the Rerun web viewer beside the "
    "page (its stream on PORT+1); 0: no viewer.",
)
@click.option(
    "--trial-limit",
    type=click.FloatRange(10.0, 3600.0),
    default=180.0,
    show_default=True,
    help="With --participant: seconds a trial may run.",
)
@click.option(
    "--calibration-targets",
    type=click.IntRange(2, 200),
    default=20,
    show_default=True,
    help="With --participant: reaches of the calibration.",
)
@real_arm_options()
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the draws.")
@click.option("--incomplete", is_flag=True, help="As for `study plan`.")
@click.option("--force", is_flag=True, help="As for `study plan`.")
@robot_option(None, what="the arm (the stand-in's with --simulate: the Sawyer by default)")
def run_cmd(
    protocol: str,
    participant: str | None,
    population: str | None,
    participants: int | None,
    out: Path,
    profile: str,
    zenoh_config: Path | None,
    page_port: int,
    viewer_port: int,
    trial_limit: float,
    calibration_targets: int,
    allow_motion: bool,
    insecure_transport: bool,
    seed: int,
    incomplete: bool,
    force: bool,
    robot: str | None,
) -> None:
    """Run PROTOCOL: one participant's session with a person (--participant), a whole
    study of simulated participants (--simulate), or both: a rehearsal, a participant drawn
    from the population at the page and the stick of a person's session.

    \b
    With a person: their steps of the plan in --out (`legws study plan`), on the robot of
    --profile: the calibration (method.md §10), the practice, the trials — each in a daemon
    of its own, recorded — and the questionnaires, on the page at
    http://127.0.0.1:PAGE-PORT/ beside the Rerun web viewer. The participant steers with
    their own publisher (`legws joystick keyboard`, `evdev`, `can`). Pause on the page
    stops a trial (the robot stops; it runs again on Resume); run the same command again
    after a crash or Ctrl-C to go on at the step not finished.

    \b
    Simulated (method.md §10 operator models; planted effects per condition): calibration,
    practice, trials and questionnaires of every session, on the daemon's controller and
    the MuJoCo stand-in in simulated time.
    """
    from legws_daemon.study.protocol import load_protocol

    if participant is None and population is None:
        raise InputError(
            "give --participant (a person's session) or --simulate (a whole simulated "
            "study), or both (a rehearsal)",
            field="--participant",
        )
    p = load_protocol(protocol)
    if participant is None and population is not None:
        if participants is None:
            raise InputError("--simulate needs --participants N", field="--participants")
        _simulate(p, population, participants, out, seed, incomplete, force, robot or "sawyer")
        return
    assert participant is not None
    from legws_daemon.study.pseudonym import check_pseudonym

    check_pseudonym(participant)
    if participants is not None:
        raise InputError("--participants is for --simulate; a person's session runs from "
                         "the plan in --out", field="--participants")  # fmt: skip
    _person(p, participant, out, profile, zenoh_config, page_port, viewer_port, trial_limit,
            calibration_targets, allow_motion, insecure_transport, seed, robot,
            population)  # fmt: skip


def _simulate(
    p: Protocol, population: str, participants: int, out: Path, seed: int, incomplete: bool,
    force: bool, robot: str,
) -> None:  # fmt: skip
    from legws_daemon.study.population import load_population
    from legws_daemon.study.simulate import simulate_study

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


def _person(
    p: Protocol, participant: str, out: Path, profile: str, zenoh_config: Path | None,
    page_port: int, viewer_port: int, trial_limit: float, calibration_targets: int,
    allow_motion: bool, insecure_transport: bool, seed: int, robot: str | None,
    rehearsal: str | None = None,
) -> None:  # fmt: skip
    import signal
    from contextlib import ExitStack

    from legws_daemon.formats.profile import load_profile_named
    from legws_daemon.study.control import Control
    from legws_daemon.study.layouts import Layouts
    from legws_daemon.study.rig import RigSpec
    from legws_daemon.study.session import Session
    from legws_daemon.study.store import planned_schedule
    from legws_daemon.study.web import StudyPage

    schedule = planned_schedule(p, out)
    spec = load_profile_named(profile)
    control = Control(p.spec.questionnaires)
    with ExitStack() as stack:
        from legws_daemon.telemetry.web_viewer import WebTarget, WebViewer

        target = WebTarget("127.0.0.1", viewer_port, viewer_port + 1) if viewer_port else None
        viewer_page = target.page_url if target is not None else None
        grpc = target.grpc_url if target is not None else None
        rig = RigSpec(profile, zenoh_config, spec.robot, robot, allow_motion,
                      insecure_transport, grpc)  # fmt: skip
        people = None
        if rehearsal is not None:
            from legws_daemon.study.population import load_population

            people = load_population(rehearsal, p.condition_names)
        # the session's checks (the participant in the plan, its session.json) come before
        # the viewer starts: a refused session starts nothing
        session = Session(
            p, schedule, participant, out / participant, rig, control,
            Layouts(out / "layouts", arm=robot or spec.arm), trial_limit=trial_limit,
            calibration_targets=calibration_targets, seed=seed, viewer_url=viewer_page,
            rehearsal=people.spec.name if people is not None else None,
        )  # fmt: skip
        stand_in = None
        if people is not None:  # a simulated participant at the page and the stick
            from legws_daemon.study.rehearse import SimulatedPerson
            from legws_daemon.study.simulate import draw_participant

            who, rng = draw_participant(people, list(schedule.steps), participant, seed)
            logs = out / participant / "logs"
            stand_in = SimulatedPerson(who, people, p, control, rig, logs, rng)
        if target is not None:
            stack.enter_context(WebViewer.start(target, field="--viewer-port"))
        page = stack.enter_context(StudyPage(control, page_port, viewer_page))
        if stand_in is not None:
            stand_in.start()
            stack.callback(stand_in.close)
        first = session.next_step
        where = (
            "from the start"
            if not session.state.done
            else f"at step {first.index if first else '-'}"
        )
        echo(f"legws: {participant}'s session {where}: open {page.url}", err=True)

        def terminate(signum: int, frame: object) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, terminate)
        try:
            rows = session.run()
            control.wait_seen(DONE_LINGER_S)  # the page shows the end before it goes
        except KeyboardInterrupt:
            if stand_in is not None and stand_in.error is not None:
                raise InputError(f"the simulated participant: {stand_in.error}",
                                 field="--simulate") from None  # fmt: skip
            step = session.next_step
            at = step.index if step else "-"
            echo(f"legws: {participant}'s session stopped before step {at}; "
                 "run the same command to go on", err=True)  # fmt: skip
            raise SystemExit(130) from None
        except LegwsError as err:  # the page says why the session stopped, then the line
            control.show(phase="failed", message=f"The session stopped: {err}")
            control.wait_seen(DONE_LINGER_S)
            raise
    trials = [r for r in rows if r["kind"] == "trial"]
    echo(f"legws: {participant} done: {len(trials)} trials "
         f"({sum(bool(r['completed']) for r in trials)} completed) -> {out / participant}",
         err=True)  # fmt: skip


study_group.add_command(export_cmd)


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
