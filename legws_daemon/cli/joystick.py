"""``legws joystick``: publish joystick messages to the daemon (keyboard, CAN device, replay).

Every subcommand takes the options of :func:`publisher_options` (profile, zenoh
configuration, rate, recording, duration), connects to the daemon's endpoints (the
profile's listen endpoints become connect endpoints) unless ``--zenoh-config`` is given,
and publishes on ``legws/<robot>/joystick``. It reads the daemon's status on the same
session: no status within ``--wait-daemon`` seconds is one line saying where it looked
(exit 2), and while it runs one line on standard error says what the daemon does (mode, top
goal and p, commit, phase, operator, deadman; :mod:`legws_daemon.joystick.daemon_status`).
SIGINT or SIGTERM ends a run cleanly: one last zero-deflection message, the session closed,
exit 0. Progress goes to standard error.

To add a subcommand with the same options::

    @joystick_group.command("sim-user")
    @publisher_options()
    @click.option("--goal", required=True)
    def sim_user_cmd(options: PublisherOptions, goal: str) -> None:
        profile = options.load_profile()
        with stop_on_signals() as stop, options.publisher(profile, "sim-user") as pub:
            with watching(pub, profile, options):
                pub.run(sample_fn, options.rate_for(profile), options.duration, stop)
"""

from __future__ import annotations

import contextlib
import functools
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from legws_daemon.cli.lazy import LazyGroup
from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.formats.printable import echo
from legws_daemon.formats.profile import ProfileSpec, load_profile_named
from legws_daemon.joystick.daemon_status import STATUS_WAIT

if TYPE_CHECKING:
    from legws_daemon.joystick.daemon_status import StatusWatch
    from legws_daemon.joystick.publisher import Publisher

R = TypeVar("R")

#: A profile name in hw_profiles/ (or a .toml path).
DEFAULT_PROFILE = Path("sim")
#: How long a command waits for the daemon's first status by default, s.
WAIT_DAEMON = STATUS_WAIT


@dataclass(frozen=True)
class PublisherOptions:
    """The options every ``legws joystick`` subcommand shares (see :func:`publisher_options`)."""

    profile: Path = DEFAULT_PROFILE
    zenoh_config: Path | None = None
    rate: float | None = None
    record: Path | None = None
    duration: float | None = None
    take_control: bool = False
    wait_daemon: float = WAIT_DAEMON

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
            take_control=self.take_control,
        )

    def dialled(self, profile: ProfileSpec) -> list[str]:
        """Where the session looks for the daemon, for messages."""
        if self.zenoh_config is not None:
            return [f"the endpoints of {self.zenoh_config}"]
        from legws_daemon.joystick.publisher import dial_spec

        return list(dial_spec(profile.transport).connect)


_OPTION_NAMES = (
    "profile", "zenoh_config", "rate", "record", "duration", "take_control", "wait_daemon"
)  # fmt: skip


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
            common["take_control"] = bool(common["take_control"])
            if common["wait_daemon"] is None:
                common["wait_daemon"] = WAIT_DAEMON
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
                type=FiniteFloat(min=0.0, min_open=True),
                help="Stop after this many seconds (default: until Ctrl-C or SIGTERM).",
            ),
            click.option(
                "--take-control",
                is_flag=True,
                help="Take the operator lease from whoever holds it, at start (the daemon's "
                "take_control command; its access control must let this identity send "
                "commands).",
            ),
            click.option(
                "--wait-daemon",
                type=FiniteFloat(min=0.0, max=600.0, min_open=True),
                default=WAIT_DAEMON,
                show_default=True,
                help="Seconds to wait for the daemon's first status; none by then is an "
                "error (exit 2) saying where it looked.",
            ),
        ]
        if rate:
            options.insert(
                2,
                click.option(
                    "--rate",
                    type=FiniteFloat(min=0.0, max=1000.0, min_open=True),
                    help="Publishing rate, Hz (default: the profile's control rate).",
                ),
            )
        for option in reversed(options):
            wrapper = option(wrapper)
        return wrapper

    return decorate


@contextlib.contextmanager
def watching(
    pub: Publisher, profile: ProfileSpec, options: PublisherOptions, *, line: bool = True
) -> Iterator[StatusWatch]:
    """The daemon's status on the publisher's session, for the block: the first one waited
    for (none within ``--wait-daemon``: :class:`InputError`, exit 2), then — ``line`` — one
    line on standard error saying what the daemon does."""
    from legws_daemon.joystick.daemon_status import StatusLine, StatusWatch, wait_for_status
    from legws_daemon.transport.session import keys

    watch = StatusWatch(keys(profile.robot)["status"])
    sub = pub.session.declare_subscriber(watch.key, lambda s: watch.offer(s.payload.to_bytes()))
    try:
        wait_for_status(
            watch, options.wait_daemon, options.dialled(profile),
            lambda text: echo(f"legws: {text}", err=True),
        )  # fmt: skip
        with (
            StatusLine(watch, sys.stderr, lambda: pub.session_id, "legws: daemon: ")
            if line
            else (contextlib.nullcontext())
        ):
            yield watch
    finally:
        sub.undeclare()  # type: ignore[no-untyped-call]


def _started(pub: Publisher, what: str) -> None:
    """Say what runs."""
    echo(f"legws: {what} on {pub.key}; Ctrl-C or SIGTERM stops", err=True)


@click.group(
    "joystick",
    cls=LazyGroup,
    lazy={"sim-user": "legws_daemon.cli.sim_user:sim_user_cmd"},
)
def joystick_group() -> None:
    """Publish joystick messages to the daemon: keyboard, CAN device or a recording."""


@joystick_group.command("keyboard")
@publisher_options()
@click.option(
    "--step",
    type=FiniteFloat(min=0.0, max=1.0, min_open=True),
    default=1.0,
    show_default=True,
    help="Deflection a key sets on its axis.",
)
@click.option(
    "--hold",
    type=FiniteFloat(min=0.0, max=10.0, min_open=True),
    default=0.3,
    show_default=True,
    help="Seconds a key's deflection (and the enable) lasts unless the key repeats.",
)
@click.option(
    "--hold-to-run/--no-hold-to-run",
    default=True,
    show_default=True,
    help="Enable only while a steering key or space is held (assistance runs while you hold "
    "space); --no-hold-to-run: the running publisher itself is the dead-man signal.",
)
def keyboard_cmd(options: PublisherOptions, step: float, hold: float, hold_to_run: bool) -> None:
    """Steer from this terminal: w/s +x/-x, a/d +y/-y, r/f +z/-z, space zero, Enter confirm,
    c cancel, q quit.

    A terminal reports no key releases: a key's deflection decays to zero unless the key
    repeats within --hold seconds (holding a key down repeats it; the terminal's repeat
    delay must be shorter than --hold). Hold-to-run: the arm moves only while you steer or
    hold space; after a commit, hold space to let the assistance finish.
    """
    from legws_daemon.joystick.daemon_status import status_text
    from legws_daemon.joystick.keyboard import (
        KeyboardState,
        RawTerminal,
        run_keyboard,
        stdin_terminal_fd,
    )
    from legws_daemon.joystick.publisher import stop_on_signals

    profile = options.load_profile()
    state = KeyboardState(step=step, hold=hold, hold_to_run=hold_to_run)
    fd = stdin_terminal_fd()
    rate = options.rate_for(profile)
    with (
        stop_on_signals() as stop,
        options.publisher(profile, "keyboard") as pub,
        watching(pub, profile, options, line=False) as watch,
    ):
        _started(pub, f"keyboard at {rate:g} Hz")

        def daemon() -> str | None:
            status = watch.newest
            return None if status is None else status_text(status, pub.session_id)

        with RawTerminal(fd) as terminal:
            run_keyboard(
                pub, terminal, state, rate=rate, duration=options.duration,
                stop_event=stop, daemon=daemon,
            )  # fmt: skip


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
        with (
            stop_on_signals() as stop,
            options.publisher(profile, f"can-{channel}") as pub,
            watching(pub, profile, options),
        ):
            _started(
                pub, f"CAN {interface} {channel} id 0x{profile.can.arbitration_id:X} at {rate:g} Hz"
            )
            published = run_can(pub, reader, rate=rate, duration=options.duration, stop_event=stop)
    finally:
        bus.shutdown()
    summary = f"{reader.frames} frames, {reader.rejected} rejected, {published} messages published"
    if reader.last_error:
        summary += f"; last rejection: {reader.last_error}"
    echo(f"legws: CAN joystick stopped: {summary}", err=True)


@joystick_group.command("replay")
@publisher_options(rate=False)
@click.argument("file", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--speed",
    type=FiniteFloat(min=0.0, max=1000.0, min_open=True),
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
    with (
        stop_on_signals() as stop,
        options.publisher(profile, "replay") as pub,
        watching(pub, profile, options),
    ):
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
    echo(f"legws: replay stopped: {published} messages published", err=True)


@joystick_group.command("evdev")
@publisher_options()
@click.option(
    "--mapping",
    metavar="NAME|FILE",
    help="Device mapping: a name in hw_profiles/input/ (xbox, playstation, spacemouse, "
    "hid_joystick) or a .toml path. Default: the first shipped mapping that recognises a "
    "plugged-in device.",
)
@click.option(
    "--device",
    "device_path",
    type=click.Path(dir_okay=False),
    metavar="PATH",
    help="The event node to read, e.g. /dev/input/by-id/usb-...-event-joystick (a by-id path "
    "survives replugging). Default: the first device the mapping recognises.",
)
@click.option(
    "--list",
    "list_only",
    is_flag=True,
    help="List the input devices, and the mapping that recognises each, then exit "
    "(no zenoh session).",
)
def evdev_cmd(
    options: PublisherOptions, mapping: str | None, device_path: str | None, list_only: bool
) -> None:
    """Steer with a gamepad, a 3Dconnexion SpaceMouse or a HID joystick (python-evdev).

    Hold-to-run: only while the mapping's enable button is held (Xbox pad: LB, HID joystick:
    the trigger, SpaceMouse: the left button) are the deflection, confirm and cancel sent;
    released, every message is zero with enable released, which the daemon takes as no
    input (after a commit, keep it held while the arm finishes). Xbox pad: left stick
    up/left = +x/+y, right stick or d-pad up = +z, A confirm, B cancel. SpaceMouse: push the
    cap away/left/up = +x/+y/+z, right button confirm, push against the motion to cancel.

    Unplugging the device sends zero with enable released at once; the device is picked up
    again when it comes back, without a restart. Reading /dev/input needs the 'input' group
    or a udev rule. Start with --list; mapping files and their format: hw_profiles/input/,
    docs/daemon.md.
    """
    from legws_daemon.joystick.evdev_input import (
        EvdevReader,
        choose_mapping,
        input_dir,
        list_devices,
        none_found_reason,
        run_evdev,
    )
    from legws_daemon.joystick.publisher import stop_on_signals

    if list_only:
        found = list_devices()
        for dev in found:
            echo(dev.describe())
        if not found:
            echo(none_found_reason())
        return
    profile = options.load_profile()
    rate = options.rate_for(profile)
    name, spec = choose_mapping(mapping, device_path)
    reader = EvdevReader(spec, device=device_path, folder=input_dir(), label=name)
    reader.open()  # a missing device is bad input (exit 2) before any zenoh session
    enable = spec.buttons.enable
    hold = (
        "hold " + " or ".join(b.code for b in enable) + " to steer"
        if enable
        else "no enable button: every message is enabled"
    )
    published = 0
    try:
        with (
            stop_on_signals() as stop,
            options.publisher(profile, f"evdev-{name}") as pub,
            watching(pub, profile, options),
        ):
            reader.start()
            _started(
                pub,
                f'{name} mapping on "{reader.name}" ({reader.path}) at {rate:g} Hz; {hold}',
            )
            published = run_evdev(
                pub, reader, rate=rate, duration=options.duration, stop_event=stop
            )
    finally:
        reader.close()
    state = reader.state
    echo(
        f"legws: evdev joystick stopped: {state.events} events, {state.dropped} dropped "
        f"(SYN_DROPPED), {reader.unplugged} unplugged, {reader.reconnected} reconnected, "
        f"{published} messages published",
        err=True,
    )
