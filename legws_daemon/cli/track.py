"""``legws track``: where the objects really stand, from a camera, for the daemon.

Finds the scene's fiducial markers (``[markers]`` in the scene file) in every frame,
measures each object's planar pose in the robot base frame, and publishes them on
``legws/<robot>/objects``; the daemon judges the placed layout from them (status
``placement``, ``warning`` events naming each misplaced object with its correction).

* ``legws track --camera 0 --scene tea --calibration cam.json`` — a UVC camera.
* ``legws track --source sim:tea[:LAYOUT.json]`` — the stand-in's camera over the scene,
  objects where the running daemon's layout says (its status ``layout``: the plan's layout
  of the current decision, or its ``--layout``), rendered again when it changes; a layout
  file's objects and ``--move OBJ=DX,DY[,DYAW]`` put objects elsewhere (edit the file and
  the next frame shows it); ``--layout-from scene`` renders the scene file's poses
  instead, without a daemon.
* ``legws track calibrate …`` — the camera's intrinsics from views of a ChArUco board.

SIGINT or SIGTERM ends a run cleanly (the session closed, exit 0).
"""

from __future__ import annotations

import time
from contextlib import closing
from pathlib import Path
from typing import TYPE_CHECKING

import click

from legws_daemon.cli.joystick import DEFAULT_PROFILE, WAIT_DAEMON
from legws_daemon.cli.numbers import FiniteFloat, PixelSize
from legws_daemon.cli.track_calibrate import calibrate_cmd
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.formats.profile import load_profile_named

if TYPE_CHECKING:
    from legws_daemon.formats.profile import ProfileSpec
    from legws_daemon.scene.scene import Scene
    from legws_daemon.tracking.follow import DaemonLayout
    from legws_daemon.tracking.stream import FrameSource, TrackStats, Warnings
    from legws_daemon.tracking.tracker import TrackFrame

#: Default tracking (and publishing) rate, Hz.
DEFAULT_RATE = 15.0
#: A progress line on standard error this often, s.
PROGRESS_EVERY = 5.0


@click.group("track", invoke_without_command=True)
@click.option(
    "--source",
    help="sim:SCENE[:LAYOUT_FILE]: the stand-in's rendered camera, objects where the running "
    "daemon's layout puts them (the layout file's where it says).",
)
@click.option("--camera", type=click.IntRange(0, 63), help="A UVC camera: /dev/videoN.")
@click.option("--scene", help="The scene (name or .toml) the camera looks at (with --camera).")
@click.option(
    "--calibration",
    type=click.Path(path_type=Path, dir_okay=False),
    help="The camera's calibration file (legws track calibrate), with --camera.",
)
@click.option(
    "--profile",
    type=click.Path(path_type=Path, dir_okay=False),
    default=DEFAULT_PROFILE,
    show_default=True,
    help="Hardware profile: the robot's name and the daemon's endpoints.",
)
@click.option(
    "--zenoh-config",
    type=click.Path(path_type=Path, dir_okay=False),
    help="JSON5 zenoh configuration, used as is (instead of the profile's endpoints).",
)
@click.option(
    "--rate",
    type=FiniteFloat(min=0.0, max=60.0, min_open=True),
    default=DEFAULT_RATE,
    show_default=True,
    help="Frames tracked and published per second, at most.",
)
@click.option(
    "--size",
    type=PixelSize(16, 4096),
    default="640x480",
    show_default=True,
    help="Picture size of sim:, WIDTHxHEIGHT.",
)
@click.option(
    "--duration",
    type=FiniteFloat(min=0.0, min_open=True),
    help="Stop after this many seconds (default: until Ctrl-C or SIGTERM).",
)
@click.option(
    "--layout-from",
    type=click.Choice(["daemon", "scene"]),
    help="sim: where the objects stand before a layout file and --move: the layout the "
    "running daemon runs (default; from its status) or the scene file's poses.",
)
@click.option(
    "--move",
    "moves",
    multiple=True,
    metavar="OBJ=DX,DY[,DYAW]",
    help="sim: shift an object from where it would stand, metres along x (away from the "
    "robot) and y (its left), degrees anticlockwise; repeat for several.",
)
@click.option(
    "--wait-daemon",
    type=FiniteFloat(min=0.0, max=600.0, min_open=True),
    default=WAIT_DAEMON,
    show_default=True,
    help="sim: seconds to wait for the daemon's first status (its layout); none by then "
    "is an error (exit 2) saying where it looked.",
)
@click.pass_context
def track_group(
    ctx: click.Context,
    source: str | None,
    camera: int | None,
    scene: str | None,
    calibration: Path | None,
    profile: Path,
    zenoh_config: Path | None,
    rate: float,
    size: tuple[int, int],
    duration: float | None,
    layout_from: str | None,
    moves: tuple[str, ...],
    wait_daemon: float,
) -> None:
    """Track the objects' markers with a camera; publish their poses to the daemon."""
    if ctx.invoked_subcommand is not None:
        return
    from legws_daemon.joystick.publisher import process_source, stop_on_signals
    from legws_daemon.tracking.stream import ObjectsPublisher, Warnings, track
    from legws_daemon.tracking.tracker import Tracker

    prof = load_profile_named(profile)
    warn = Warnings(lambda text: echo(f"legws: warning: {text}", err=True))
    if source is None and (layout_from is not None or moves):
        raise InputError("--layout-from and --move go with --source sim:")
    follow = _follow(prof, source, layout_from)
    the_scene, src = _open_source(source, camera, scene, calibration, size, warn, follow, moves)
    with closing(src):
        tracker = Tracker(the_scene, src.intrinsics)
        with (
            ObjectsPublisher(prof, zenoh_config, process_source("tracker")) as pub,
            stop_on_signals() as stop,
        ):
            if follow is not None:
                pub.subscribe(follow.key, follow.offer)
                note = lambda text: echo(f"legws: {text}", err=True)  # noqa: E731
                if follow.wait(wait_daemon, _dialled(prof, zenoh_config), stop, note) is None:
                    echo("legws: stopped before the daemon's layout came", err=True)
                    return  # nothing was published
            k = src.intrinsics.matrix
            echo(
                f"legws: tracking '{the_scene.name}' from {src.name} "
                f"({src.intrinsics.width}x{src.intrinsics.height}, fx {k[0, 0]:.1f} px) at "
                f"{rate:g} Hz",
                err=True,
            )
            if follow is not None:
                echo(
                    f"legws: rendering the layout the daemon runs (stage {follow.stage}, "
                    f"decision {follow.decision}; from {follow.key}), again when it changes",
                    err=True,
                )
            echo(f"legws: publishing on {pub.key}; Ctrl-C or SIGTERM stops", err=True)

            def send(frame: TrackFrame, unseen: list[str], stamp: float) -> None:
                pub.put(pub.message(frame, unseen, stamp))

            stats = track(
                src, tracker, send, rate=rate, stop=stop, duration=duration, warn=warn,
                on_frame=_Progress(len(tracker.markers.objects)),
            )  # fmt: skip
    waited = f", {stats.waited} times nothing to show" if stats.waited else ""
    echo(
        f"legws: tracked {stats.frames} frames ({stats.rate():.1f} Hz), "
        f"{stats.dropped} unreadable, {stats.published} messages{waited}",
        err=True,
    )


def _follow(prof: ProfileSpec, source: str | None, layout_from: str | None) -> DaemonLayout | None:
    """The daemon's layout to follow: with ``sim:`` unless ``--layout-from scene``."""
    if source is None or layout_from == "scene":
        return None
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.tracking.follow import DaemonLayout
    from legws_daemon.tracking.stream import parse_sim_source
    from legws_daemon.transport.session import keys

    return DaemonLayout(load_scene(parse_sim_source(source).scene), keys(prof.robot)["status"])


def _dialled(prof: ProfileSpec, zenoh_config: Path | None) -> list[str]:
    """Where the session looks for the daemon, for messages."""
    if zenoh_config is not None:
        return [f"the endpoints of {zenoh_config}"]
    from legws_daemon.joystick.publisher import dial_spec

    return list(dial_spec(prof.transport).connect)


def _open_source(
    source: str | None,
    camera: int | None,
    scene: str | None,
    calibration: Path | None,
    size: tuple[int, int],
    warn: Warnings,
    follow: DaemonLayout | None = None,
    moves: tuple[str, ...] = (),
) -> tuple[Scene, FrameSource]:
    """The scene and the frame source the options name; one-line errors for what does not
    fit."""
    from legws_daemon.scene.catalog import load_scene
    from legws_daemon.tracking.stream import (
        CameraSource,
        SimSource,
        parse_move,
        parse_sim_source,
    )

    if (source is None) == (camera is None):
        raise InputError("give either --camera N or --source sim:SCENE[:LAYOUT]")
    if source is not None:
        spec = parse_sim_source(source)
        if scene is not None or calibration is not None:
            raise InputError("--scene and --calibration go with --camera; sim: has both")
        the_scene = follow.scene if follow is not None else load_scene(spec.scene)
        shifts = dict(parse_move(m, the_scene) for m in moves)
        say = lambda text: echo(f"legws: {text}", err=True)  # noqa: E731
        src = SimSource(the_scene, spec.layout, *size, warn, follow=follow, moves=shifts, say=say)
        return the_scene, src
    if scene is None or calibration is None:
        raise InputError("--camera needs --scene and --calibration (legws track calibrate)")
    from legws_daemon.tracking.calibration import load_calibration

    the_scene = load_scene(scene)
    cal = load_calibration(calibration)
    assert camera is not None
    return the_scene, CameraSource(camera, cal.intrinsics, str(calibration))


class _Progress:
    """A line on standard error when what is seen changes, and every few seconds."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.text = ""
        self.at = 0.0

    def __call__(self, frame: TrackFrame, stats: TrackStats) -> None:
        missing = f"; not seen: {', '.join(frame.unseen)}" if frame.unseen else ""
        text = (
            f"{len(frame.poses)}/{self.total} objects, {frame.table_markers} table "
            f"marker(s){missing}"
        )
        now = time.monotonic()
        if text != self.text or now - self.at >= PROGRESS_EVERY:
            self.text, self.at = text, now
            echo(f"legws: {stats.rate():.1f} Hz: {text}", err=True)


track_group.add_command(calibrate_cmd)
