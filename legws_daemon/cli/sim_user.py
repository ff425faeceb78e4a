"""``legws joystick sim-user``: the simulated user of method.md §2, closing the loop; or a
simulated operator of method.md §10 (``--speed``, ``--rho``, ``--bias``, ``--steering``, or
``--operator FILE``: the fitted model of an operator file)."""

from __future__ import annotations

import time
from pathlib import Path

import click
import numpy as np

from legws_daemon.cli.joystick import PublisherOptions, publisher_options, watching
from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.core.operator import (
    BIAS_RANGE_DEG,
    RHO_RANGE,
    SPEED_RANGE,
    STEERINGS,
    OperatorModel,
)
from legws_daemon.core.params import Params
from legws_daemon.formats.printable import echo


def simulated_operator(
    sigma: float,
    speed: float | None,
    rho: float | None,
    bias: float | None,
    steering: str | None,
    operator_file: Path | None,
) -> OperatorModel | None:
    """The operator model the simulated user steers like: ``--operator FILE``'s fitted
    model, or the one the options give (the others at section 2's values); ``None`` when no
    option asks for one (section 2's user, as before)."""
    given = [n for n, v in (("--speed", speed), ("--rho", rho), ("--bias", bias),
                            ("--steering", steering)) if v is not None]  # fmt: skip
    if operator_file is not None:
        if given:
            raise click.UsageError(f"give --operator or {', '.join(given)}, not both")
        from legws_daemon.formats.operator_file import load_operator

        return load_operator(operator_file).fitted
    if not given:
        return None
    return OperatorModel(
        1.0 if speed is None else speed,
        sigma,
        0.0 if rho is None else rho,
        0.0 if bias is None else bias,
        "free" if steering is None else steering,  # type: ignore[arg-type]
    )


@click.command("sim-user")
@publisher_options()
@click.option(
    "--goal",
    "goals",
    multiple=True,
    help="A goal the user wants (repeatable, in order: one per decision of a task graph). "
    "None: choose at random at each decision.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Noise seed.")
@click.option(
    "--sigma",
    type=FiniteFloat(min=0.0, max=1.0),
    default=Params().sigma,
    show_default=True,
    help="Joystick velocity noise, m/s per axis.",
)
@click.option(
    "--cancel-after",
    type=FiniteFloat(min=0.0),
    help="Press cancel this many seconds into the robot's assistance (once).",
)
@click.option(
    "--speed",
    type=FiniteFloat(min=SPEED_RANGE[0], max=SPEED_RANGE[1]),
    help="Simulated operator (method.md §10): mean deflection toward the aim (default 1).",
)
@click.option(
    "--rho",
    type=FiniteFloat(min=RHO_RANGE[0], max=RHO_RANGE[1]),
    help="Simulated operator: lag-1 autocorrelation of the noise per control period (default 0).",
)
@click.option(
    "--bias",
    type=FiniteFloat(min=BIAS_RANGE_DEG[0], max=BIAS_RANGE_DEG[1]),
    help="Simulated operator: the aim turned about the base z axis, degrees, anticlockwise "
    "from above (default 0).",
)
@click.option(
    "--steering",
    type=click.Choice(STEERINGS),
    help="Simulated operator: free, axes (one of ±x ±y ±z, a keyboard) or axes+diagonals "
    "(default free).",
)
@click.option(
    "--operator",
    "operator_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Steer like the fitted model of this operator file (legws operator calibrate/fit).",
)
@click.option(
    "--onset",
    type=FiniteFloat(min=0.0, max=600.0),
    default=0.0,
    show_default=True,
    help="Hesitate this many seconds after the daemon's first status before the first push "
    "(the stick held still, enable held), as a person who has just been told the goal.",
)
@click.option(
    "--until-done/--forever",
    default=True,
    show_default=True,
    help="Stop when the daemon reports the stage done (mode idle).",
)
def sim_user_cmd(
    options: PublisherOptions,
    goals: tuple[str, ...],
    seed: int,
    sigma: float,
    cancel_after: float | None,
    speed: float | None,
    rho: float | None,
    bias: float | None,
    steering: str | None,
    operator_file: Path | None,
    onset: float,
    until_done: bool,
) -> None:
    """Steer like the paper's noisy user, from the daemon's published status.

    At each decision it goes for the first --goal on offer (or a random one), pushing
    toward its position with Gaussian velocity noise; after the daemon commits it lets go
    (zero deflection, dead-man held) and watches the robot act; at the goal without a
    commit it presses confirm. In a calibration (legws operator calibrate) it steers to
    each target shown. It ends when the daemon's task is done (--until-done). With --speed,
    --rho, --bias or --steering (or --operator FILE) it steers like that operator model
    (method.md §10), its noise correlated over the time that really passes between samples.
    """
    from legws_daemon.formats.messages import Buttons
    from legws_daemon.joystick.publisher import Sample, stop_on_signals
    from legws_daemon.joystick.sim_user import SimUser, UserView

    profile = options.load_profile()
    operator = simulated_operator(sigma, speed, rho, bias, steering, operator_file)
    rng = np.random.default_rng(seed)
    dt = 1.0 / profile.control.rate_hz
    user = SimUser(goals, sigma, profile.control.v_max, rng, cancel_after, operator=operator, dt=dt)
    with (
        stop_on_signals() as stop,
        options.publisher(profile, "sim-user") as pub,
        watching(pub, profile, options) as watch,
    ):
        first = watch.newest
        view = UserView.from_status(first) if first is not None else None
        if view is not None:
            user.choose(view)  # a goal that is no target of this decision: one line, exit 2

        heard: list[float] = []  # when the first fresh status came (the onset's start)

        def sample() -> Sample | None:
            if until_done and watch.done.is_set():
                stop.set()
                return None
            now = time.monotonic()
            status = watch.latest(now)
            if status is not None and not heard:
                heard.append(now)
            if heard and now - heard[0] < onset:
                return (0.0, 0.0, 0.0), Buttons(enable=True)  # told the goal, not pushing yet
            return user.sample(status, now, watch.received)

        wanted = ", ".join(goals) or "a random goal at each decision"
        who = "" if operator is None else f" steering like {operator.describe()}"
        after = f", pushing {onset:g} s after the daemon's first status" if onset else ""
        echo(f"legws: simulated user{who} going for {wanted} on {pub.key}{after}", err=True)
        pub.run(sample, options.rate_for(profile), options.duration, stop)
    echo(f"legws: daemon modes seen: {' -> '.join(watch.modes_seen)}", err=True)
    for decision, goal in user.chosen:
        echo(f"legws: at {decision} the user went for {goal}", err=True)
