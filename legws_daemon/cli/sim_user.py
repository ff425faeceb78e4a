"""``legws joystick sim-user``: the simulated user of method.md §2, closing the loop."""

from __future__ import annotations

import time

import click
import numpy as np

from legws_daemon.cli.joystick import PublisherOptions, publisher_options
from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.core.params import Params


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
    until_done: bool,
) -> None:
    """Steer like the paper's noisy user, from the daemon's published status.

    At each decision it goes for the first --goal on offer (or a random one), pushing
    toward its position with Gaussian velocity noise; after the daemon commits it lets go
    (zero deflection, dead-man held) and watches the robot act; at the goal without a
    commit it presses confirm. It ends when the daemon's task is done (--until-done).
    """
    from legws_daemon.joystick.publisher import Sample, stop_on_signals
    from legws_daemon.joystick.sim_user import SimUser, StatusWatch
    from legws_daemon.transport.session import keys

    profile = options.load_profile()
    user = SimUser(goals, sigma, profile.control.v_max, np.random.default_rng(seed), cancel_after)
    watch = StatusWatch(keys(profile.robot)["status"])
    with stop_on_signals() as stop, options.publisher(profile, "sim-user") as pub:
        sub = pub.session.declare_subscriber(watch.key, lambda s: watch.offer(s.payload.to_bytes()))

        def sample() -> Sample | None:
            if until_done and watch.done.is_set():
                stop.set()
                return None
            now = time.monotonic()
            return user.sample(watch.latest(now), now)

        wanted = ", ".join(goals) or "a random goal at each decision"
        click.echo(f"legws: simulated user going for {wanted} on {pub.key}", err=True)
        try:
            pub.run(sample, options.rate_for(profile), options.duration, stop)
        finally:
            sub.undeclare()  # type: ignore[no-untyped-call]
        click.echo(f"legws: daemon modes seen: {' -> '.join(watch.modes_seen)}", err=True)
        for decision, goal in user.chosen:
            click.echo(f"legws: at {decision} the user went for {goal}", err=True)
