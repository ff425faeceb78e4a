"""``legws operator calibrate``: fit a person's operator model from reaches with their own
input device (method.md §10; docs/operator.md, *Calibrating a person*).

The command runs the daemon itself, in mode ``calibrate``: teleoperation as usual — the
dead-man, the operator lease, the safety envelope, the stop keys and hold-to-run all apply
— without an observer, a commit or assistance. It shows one target at a time (a point in
the Rerun view, a line here, status ``calibration`` and ``targets: {"calibration": ...}``
for every client); a reach is done when the EE is within 2 cm of its target, then the next
appears. After the last it writes the reaches as a teleoperation trace, fits the model,
writes the operator file and prints the fit. Any publisher steers: ``legws joystick
keyboard``, ``evdev``, ``can``, ``sim-user``.

Interrupted (SIGINT, SIGTERM): the robot stops as the daemon's does; the reaches done so
far (the one under way is dropped) are written to the trace, so that ``legws operator fit``
can fit them, alone or with another session's trace; no operator file is written (it would
describe fewer reaches than asked for). Exit 130.
"""

from __future__ import annotations

import re
import threading
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

import click

from legws_daemon.cli.robot import real_arm_options
from legws_daemon.core.calibration import MAX_TARGETS
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo

if TYPE_CHECKING:
    from legws_daemon.autonomy.calibration import Reach
    from legws_daemon.autonomy.events import Event
    from legws_daemon.telemetry.rerun_log import RerunLog

#: Exit code of a calibration interrupted before its last target (the CLI's for SIGINT).
EXIT_INTERRUPTED = 130
#: The default operator name when ``--name`` is not given and OUT's stem is not a name.
DEFAULT_NAME = "operator"


def _default_name(out: Path) -> str:
    """OUT's stem (``alice`` for ``alice.json``) when it is a valid name."""
    from legws_daemon.formats.operator_file import NAME_PATTERN

    stem = out.name.removesuffix(".json")
    return stem if re.fullmatch(NAME_PATTERN, stem) else DEFAULT_NAME


class _Terminal:
    """What the person reads at the terminal: a line when a target appears, when it is
    reached (with the seconds it took), and when the robot stops or fails."""

    def __init__(self) -> None:
        self.lock = threading.Lock()

    def __call__(self, event: Event) -> None:
        from legws_daemon.autonomy.events import (
            CalibrationReach,
            CalibrationReached,
            Fault,
            Reset,
            Stop,
        )

        match event:
            case CalibrationReach():
                x, y, z = event.target
                line = (
                    f"legws: target {event.reach} of {event.of} at ({x:.3f}, {y:.3f}, {z:.3f}) "
                    f"m, {event.distance:.2f} m away: steer the arm there"
                )
            case CalibrationReached():
                line = f"legws: target {event.reach} of {event.of} reached in {event.seconds:.1f} s"
            case Stop():
                line = (
                    f"legws: stopped by {event.by}: the reach under way is dropped; after a "
                    "reset the arm goes home and its target appears again"
                )
            case Fault():
                line = f"legws: fault ({event.error}): the reach under way is dropped"
            case Reset():
                line = "legws: reset done: the calibration goes on"
            case _:
                return
        with self.lock:
            echo(line, err=True)


@click.command("calibrate")
@click.option(
    "--profile",
    default="sim",
    show_default=True,
    help="Hardware profile: a name in hw_profiles/ or a .toml path.",
)
@click.option(
    "--targets",
    "count",
    type=click.IntRange(2, MAX_TARGETS),
    default=20,
    show_default=True,
    help="Reaches: one target each, shown one at a time.",
)
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="The operator file to write (JSON, interfaces.md).",
)
@click.option(
    "--name",
    help="Whom the model describes (letters, digits, _ . -; shown in status and warnings); "
    "default: OUT's name without .json.",
)
@click.option(
    "--trace",
    "trace_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="The teleoperation trace of the reaches (default: NAME.trace.jsonl next to OUT).",
)
@click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Seed of the targets and of the fit's bootstrap.",
)
@click.option(
    "--scene",
    default="desk",
    show_default=True,
    help="The scene on the table (its bounds, the tallest object's height, the EE home).",
)
@click.option(
    "--resamples",
    type=click.IntRange(100, 100_000),
    default=1000,
    show_default=True,
    help="Bootstrap resamples of reaches for the 95 %% intervals.",
)
@click.option(
    "--rerun",
    "rerun_target",
    multiple=True,
    metavar="save:PATH|spawn|connect[:URL]|web[:[HOST:]PORT]",
    help="Stream to Rerun, as `legws daemon --rerun` (repeatable): the target is drawn at "
    "world/calibration/target.",
)
@click.option(
    "--zenoh-config",
    type=click.Path(path_type=Path, dir_okay=False),
    help="zenoh JSON5 configuration for a real network (default: the profile's loopback).",
)
@real_arm_options()
def calibrate_cmd(
    profile: str,
    count: int,
    out: Path,
    name: str | None,
    trace_file: Path | None,
    seed: int,
    scene: str,
    resamples: int,
    rerun_target: tuple[str, ...],
    zenoh_config: Path | None,
    allow_motion: bool,
    insecure_transport: bool,
) -> int:
    """Calibrate the person at the joystick: the daemon in calibration mode shows one
    target at a time (Rerun, this terminal, status), records each reach, then fits their
    operator model and writes OUT. Steer with any publisher (legws joystick keyboard,
    evdev, can, sim-user). SIGINT: the robot stops, the reaches done are written to the
    trace, no operator file; exit 130."""
    from legws_daemon.autonomy.calibration import targets_for
    from legws_daemon.cli.daemon import (
        install_stop_handlers,
        require_motion_allowed,
        require_secure_transport,
    )
    from legws_daemon.daemon.service import CalibrationSpec, DaemonConfig, DaemonService
    from legws_daemon.formats.files import output_path
    from legws_daemon.formats.operator_file import check_name
    from legws_daemon.formats.profile import load_profile_named
    from legws_daemon.safety.envelope import Box
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.transport.security import authentication_problem
    from legws_daemon.transport.session import config_from_file, config_from_spec

    name = check_name(name, "--name") if name is not None else _default_name(out)
    output_path(out)
    trace = trace_file if trace_file is not None else out.parent / f"{name}.trace.jsonl"
    output_path(trace)
    spec = load_profile_named(profile)
    require_motion_allowed(spec, allow_motion)
    sc = load_scene(scene)
    # the targets from home, checked before anything moves (the run draws them from where
    # the EE really is: the same when it starts at home)
    targets_for(sc, Box.of(spec.workspace), sc.home.position, count, seed)
    params = Params(v_max=spec.control.v_max, dt=1.0 / spec.control.rate_hz)
    zcfg = config_from_file(zenoh_config) if zenoh_config else config_from_spec(spec.transport)
    problem = authentication_problem(zcfg)
    where = str(zenoh_config) if zenoh_config else "the profile's [transport]"
    insecure = require_secure_transport(spec, problem, insecure_transport, where)
    # the log goes to the terminal from here on: every input is checked (an in-process run
    # that stops at bad input leaves the caller's logging as it was)
    from legws_daemon.telemetry.terminal_log import log_to_terminal

    log_to_terminal("legws calibrate")
    stop = threading.Event()
    install_stop_handlers(stop)
    with ExitStack() as stack:
        telemetry: RerunLog | None = None
        if rerun_target:
            from legws_daemon.telemetry.rerun_log import RerunLog

            rerun_log = RerunLog(rerun_target, robot=spec.robot, tick_period=params.dt)
            stack.callback(rerun_log.close)
            if rerun_log.web is not None:
                page = rerun_log.web.target.page_url
                echo(f"legws: watch in a browser: {page}", err=True)
            telemetry = rerun_log
        config = DaemonConfig(
            spec, sc, sc.default_layout(), params, zcfg, telemetry=telemetry,
            transport_problem=problem, insecure_transport=insecure,
            calibration=CalibrationSpec(count, seed), on_event=_Terminal(),
        )  # fmt: skip
        echo(
            f"legws: calibrating operator {name}: {count} targets on legws/{spec.robot}/; "
            "steer the arm to each (status `calibration`, Rerun world/calibration/target)",
            err=True,
        )
        service = DaemonService(config)
        service.run(stop)
    run = service.controller.calibration if service.controller is not None else None
    done = list(run.done) if run is not None else []
    finished = run is not None and run.finished
    if not finished:
        return _interrupted(done, count, trace, out)
    _write_trace(trace, done)
    extra: dict[str, object] = {"profile": spec.name, "scene": sc.name, "targets": count,
                                "seed": seed}  # fmt: skip
    return _fit(done, params, name, out, trace, resamples, seed, extra)


def _write_trace(trace: Path, reaches: list[Reach]) -> int:
    from legws_daemon.formats.trace import Segment, write_trace

    segments = [Segment(i, r.ee, r.u, r.target, f"reach {r.index}") for i, r in enumerate(reaches)]
    ticks = write_trace(trace, segments)
    echo(f"legws: {len(segments)} reaches, {ticks} ticks -> {trace}", err=True)
    return ticks


def _interrupted(done: list[Reach], count: int, trace: Path, out: Path) -> int:
    """SIGINT mid-way: the reaches done go to the trace; no operator file."""
    if not done:
        echo("legws: calibration interrupted before a reach was done: nothing written",
                   err=True)  # fmt: skip
        return EXIT_INTERRUPTED
    _write_trace(trace, done)
    echo(
        f"legws: calibration interrupted after {len(done)} of {count} reaches: no operator file "
        f"written; fit the reaches done with `legws operator fit {trace} --out {out}` (a fit "
        "needs at least 2)",
        err=True,
    )
    return EXIT_INTERRUPTED


def _fit(
    done: list[Reach],
    params: Params,
    name: str,
    out: Path,
    trace: Path,
    resamples: int,
    seed: int,
    extra: dict[str, object],
) -> int:
    from legws_daemon.cli.operator import describe
    from legws_daemon.core.operator_fit import fit_operator
    from legws_daemon.formats.operator_file import OperatorFile

    segments = [(r.ee, r.u, r.target) for r in done]
    try:
        fit = fit_operator(segments, params, resamples=resamples, seed=seed)
    except InputError as err:
        raise InputError(str(err).removeprefix("segments: "), source=str(trace)) from None
    extra = {**extra, "trace": str(trace), "seconds": [round(r.seconds, 2) for r in done]}
    record = OperatorFile.from_fit(fit, name, extra)
    record.write(out)
    echo(describe(record))
    echo(f"legws: wrote {out}", err=True)
    return 0
