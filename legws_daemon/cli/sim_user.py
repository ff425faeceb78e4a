"""``legws joystick sim-user``: the simulated user of method.md §2, closing the loop."""

from __future__ import annotations

import time
from pathlib import Path

import click
import numpy as np

from legws_daemon.cli.joystick import PublisherOptions, publisher_options
from legws_daemon.core.params import Params
from legws_daemon.formats.layout_file import load_layout
from legws_daemon.scene.catalog import load_scene


@click.command("sim-user")
@publisher_options()
@click.option("--goal", required=True, help="The object the simulated user wants.")
@click.option("--scene", default="desk", show_default=True, help="Scene the daemon runs.")
@click.option(
    "--layout",
    "layout_file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Layout JSON the daemon runs (default: the scene's).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Noise seed.")
@click.option(
    "--sigma",
    type=click.FloatRange(min=0.0, max=1.0),
    default=Params().sigma,
    show_default=True,
    help="Joystick velocity noise, m/s per axis.",
)
@click.option(
    "--cancel-after",
    type=click.FloatRange(min=0.0),
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
    goal: str,
    scene: str,
    layout_file: Path | None,
    seed: int,
    sigma: float,
    cancel_after: float | None,
    until_done: bool,
) -> None:
    """Steer toward GOAL like the paper's noisy user, from the daemon's published EE pose.

    Pushes toward the goal's grasp position with Gaussian velocity noise; after the
    daemon commits it lets go (zero deflection, dead-man held) and watches the robot
    finish; at the object without a commit it presses confirm.
    """
    from legws_daemon.joystick.publisher import Sample, stop_on_signals
    from legws_daemon.joystick.sim_user import SimUser, StatusWatch
    from legws_daemon.transport.session import keys

    profile = options.load_profile()
    sc = load_scene(scene)
    layout = load_layout(layout_file, sc) if layout_file else sc.default_layout()
    goals = sc.goal_set(layout)
    target = goals.positions[goals.index(goal)]
    user = SimUser(target, sigma, profile.control.v_max, np.random.default_rng(seed), cancel_after)
    watch = StatusWatch(keys(profile.robot)["status"])
    with stop_on_signals() as stop, options.publisher(profile, "sim-user") as pub:
        sub = pub.session.declare_subscriber(watch.key, lambda s: watch.offer(s.payload.to_bytes()))

        def sample() -> Sample | None:
            if until_done and watch.done.is_set():
                stop.set()
                return None
            now = time.monotonic()
            return user.sample(watch.latest(now), now)

        click.echo(f"legws: simulated user steering to '{goal}' on {pub.key}", err=True)
        try:
            pub.run(sample, options.rate_for(profile), options.duration, stop)
        finally:
            sub.undeclare()  # type: ignore[no-untyped-call]
        click.echo(f"legws: daemon modes seen: {' -> '.join(watch.modes_seen)}", err=True)
