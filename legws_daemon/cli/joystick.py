"""``legws joystick``: publish joystick messages to the daemon (keyboard, CAN device, replay).

Every subcommand takes the options of :func:`publisher_options` (profile, zenoh
configuration, rate, recording, duration), connects to the daemon's endpoints (the
profile's listen endpoints become connect endpoints) unless ``--zenoh-config`` is given,
and publishes on ``legws/<robot>/joystick``. SIGINT or SIGTERM ends a run cleanly: one last
zero-deflection message, the session closed, exit 0. Progress goes to standard error.

To add a subcommand with the same options::

    @joystick_group.command("sim-user")
    @publisher_options()
    @click.option("--goal", required=True)
    def sim_user_cmd(options: PublisherOptions, goal: str) -> None:
        profile = options.load_profile()
        with stop_on_signals() as stop, options.publisher(profile, "sim-user") as pub:
            pub.run(sample_fn, options.rate_for(profile), options.duration, stop)
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from legws_daemon.formats.profile import ProfileSpec, load_profile_named

if TYPE_CHECKING:
    from legws_daemon.joystick.publisher import Publisher

R = TypeVar("R")

#: A profile name in hw_profiles/ (or a .toml path).
DEFAULT_PROFILE = Path("sim")
#: How long a command waits for the daemon's subscriber before it starts anyway, s.
MATCH_WAIT = 2.0


@dataclass(frozen=True)
class PublisherOptions:
    """The options every ``legws joystick`` subcommand shares (see :func:`publisher_options`)."""

    profile: Path = DEFAULT_PROFILE
    zenoh_config: Path | None = None
    rate: float | None = None
    record: Path | None = None
    duration: float | None = None

    def load_profile(self) -> ProfileSpec:
        """The hardware profile; errors name the file and the field."""
        return load_profile_named(self.profile)

    def rate_for(self, profile: ProfileSpec) -> float:
        """``--rate``, or the profile's control rate."""
        return self.rate if self.rate is not None else profile.control.rate_hz

    def publisher(self, profile: ProfileSpec, kind: str) -> Publisher:
        """A (not yet opened) publisher labelled ``kind:<pid>`` that connects to the daemon."""
        from legws_daemon.joystick.publisher import Publisher, process_source

        return Publisher.for_profile(
            profile,
            source=process_source(kind),
            zenoh_config=self.zenoh_config,
            record=self.record,
        )


_OPTION_NAMES = ("profile", "zenoh_config", "rate", "record", "duration")


def publisher_options(*, rate: bool = True) -> Callable[[Callable[..., R]], Callable[..., R]]:
    """Add the shared options to a command; the command receives ``options: PublisherOptions``.

    Args:
        rate: whether the command has ``--rate`` (replay keeps the recorded timing instead).
    """

    def decorate(f: Callable[..., R]) -> Callable[..., R]:
        @functools.wraps(f)
        def wrapper(**kwargs: Any) -> R:
            common = {name: kwargs.pop(name, None) for name in _OPTION_NAMES}
            common["profile"] = common["profile"] or DEFAULT_PROFILE
            return f(options=PublisherOptions(**common), **kwargs)

        options = [
            click.option(
                "--profile",
                type=click.Path(path_type=Path, dir_okay=False),
                default=DEFAULT_PROFILE,
                show_default=True,
                help="Hardware profile: a name in hw_profiles/ or a .toml path.",
            ),
            click.option(
                "--zenoh-config",
                type=click.Path(path_type=Path, dir_okay=False),
                help="JSON5 zenoh configuration, used as is (instead of connecting to the "
                "endpoints the profile's daemon listens on).",
            ),
            click.option(
                "--record",
                type=click.Path(path_type=Path, dir_okay=False),
                help="Append every published message to this JSONL file (replay reads it).",
            ),
            click.option(
                "--duration",
                type=click.FloatRange(min=0.0, min_open=True),
                help="Stop after this many seconds (default: until Ctrl-C or SIGTERM).",
            ),
        ]
        if rate:
            options.insert(
                2,
                click.option(
                    "--rate",
                    type=click.FloatRange(min=0.0, max=1000.0, min_open=True),
                    help="Publishing rate, Hz (default: the profile's control rate).",
                ),
            )
        for option in reversed(options):
            wrapper = option(wrapper)
        return wrapper

    return decorate


def _started(pub: Publisher, what: str) -> None:
    """Wait briefly for the daemon's subscriber; say what runs, and warn if nobody listens."""
    if not pub.wait_matched(MATCH_WAIT):
        click.echo(
            f"legws: warning: nobody subscribes to {pub.key} yet (is the daemon running, and "
            "does its access control let this identity steer?); publishing anyway",
            err=True,
        )
    click.echo(f"legws: {what} on {pub.key}; Ctrl-C or SIGTERM stops", err=True)


@click.group("joystick")
def joystick_group() -> None:
    """Publish joystick messages to the daemon: keyboard, CAN device or a recording."""


@joystick_group.command("keyboard")
@publisher_options()
@click.option(
    "--step",
    type=click.FloatRange(min=0.0, max=1.0, min_open=True),
    default=1.0,
    show_default=True,
    help="Deflection a key sets on its axis.",
)
@click.option(
    "--hold",
    type=click.FloatRange(min=0.0, max=10.0, min_open=True),
    default=0.3,
    show_default=True,
    help="Seconds a key's deflection lasts unless the key repeats.",
)
def keyboard_cmd(options: PublisherOptions, step: float, hold: float) -> None:
    """Steer from this terminal: w/s +x/-x, a/d +y/-y, r/f +z/-z, space zero, c cancel, q quit.

    A terminal reports no key releases: a key's deflection decays to zero unless the key
    repeats within --hold seconds (holding a key down repeats it).
    """
    from legws_daemon.joystick.keyboard import (
        KeyboardState,
        RawTerminal,
        run_keyboard,
        stdin_terminal_fd,
    )
    from legws_daemon.joystick.publisher import stop_on_signals

    profile = options.load_profile()
    state = KeyboardState(step=step, hold=hold)
    fd = stdin_terminal_fd()
    rate = options.rate_for(profile)
    with stop_on_signals() as stop, options.publisher(profile, "keyboard") as pub:
        _started(pub, f"keyboard at {rate:g} Hz")
        with RawTerminal(fd) as terminal:
            run_keyboard(
                pub, terminal, state, rate=rate, duration=options.duration, stop_event=stop
            )


@joystick_group.command("can")
@publisher_options()
@click.option(
    "--interface",
    type=click.Choice(["socketcan", "virtual"]),
    default="socketcan",
    show_default=True,
    help="python-can interface (virtual: frames from this process only).",
)
@click.option("--channel", required=True, help="Bus channel, e.g. can0.")
@click.option(
    "--bitrate",
    type=click.IntRange(min=1, max=10_000_000),
    help="Bit rate, bit/s (socketcan takes it from 'ip link' instead).",
)
def can_cmd(options: PublisherOptions, interface: str, channel: str, bitrate: int | None) -> None:
    """Publish a CAN joystick (frame layout: the profile's [can] table).

    The newest valid frame is published every tick; when none arrived for longer than the
    profile's deadman timeout nothing is published, so the daemon stops the robot.
    """
    from legws_daemon.joystick.can_input import CanReader, open_bus, run_can
    from legws_daemon.joystick.publisher import stop_on_signals

    profile = options.load_profile()
    rate = options.rate_for(profile)
    bus = open_bus(
        "virtual" if interface == "virtual" else "socketcan", channel, bitrate, profile.can
    )
    try:
        reader = CanReader(bus, profile.can, profile.control.deadman_timeout)
        with stop_on_signals() as stop, options.publisher(profile, f"can-{channel}") as pub:
            _started(
                pub, f"CAN {interface} {channel} id 0x{profile.can.arbitration_id:X} at {rate:g} Hz"
            )
            published = run_can(pub, reader, rate=rate, duration=options.duration, stop_event=stop)
    finally:
        bus.shutdown()
    summary = f"{reader.frames} frames, {reader.rejected} rejected, {published} messages published"
    if reader.last_error:
        summary += f"; last rejection: {reader.last_error}"
    click.echo(f"legws: CAN joystick stopped: {summary}", err=True)


@joystick_group.command("replay")
@publisher_options(rate=False)
@click.argument("file", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--speed",
    type=click.FloatRange(min=0.0, max=1000.0, min_open=True),
    default=1.0,
    show_default=True,
    help="Replay this many times faster than recorded.",
)
@click.option("--loop", is_flag=True, help="Start over at the end of the file.")
def replay_cmd(options: PublisherOptions, file: Path, speed: float, loop: bool) -> None:
    """Republish the joystick messages of FILE (a --record JSONL file) with their timing.

    Messages get fresh seq numbers and stamps; the intervals between them are the recorded
    ones (by stamp) divided by --speed.
    """
    from legws_daemon.joystick.publisher import stop_on_signals
    from legws_daemon.joystick.replay import load_recording, nominal_interval, replay

    profile = options.load_profile()
    messages = load_recording(file)
    gap = nominal_interval(messages, 1.0 / profile.control.rate_hz)
    with stop_on_signals() as stop, options.publisher(profile, "replay") as pub:
        _started(pub, f"replay of {len(messages)} messages from {file} at speed {speed:g}")
        published = replay(
            pub,
            messages,
            gap=gap,
            speed=speed,
            loop=loop,
            duration=options.duration,
            stop_event=stop,
        )
    click.echo(f"legws: replay stopped: {published} messages published", err=True)
