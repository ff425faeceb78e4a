"""``legws view RECORDING.rrd``: look at a daemon recording.

* ``--screenshot OUT.png`` (with ``--time T``, ``--size WxH``): a picture of the
  viewer at time ``T`` s (by default the recording's last posterior value, where the
  posterior plot has its curves; the end without one), rendered headless
  (:mod:`legws_daemon.telemetry.screenshot`); prints its path.
* ``--web [HOST:]PORT``: serves the file to Rerun's web viewer on ``HOST`` (127.0.0.1 by
  default), the page on ``PORT`` and the gRPC stream on ``PORT+1``
  (:mod:`legws_daemon.telemetry.web_viewer`); prints the page's URL and runs until Ctrl-C.
* neither: the native viewer, which needs a display (``DISPLAY`` or ``WAYLAND_DISPLAY``).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import click

from legws_daemon.cli.numbers import FiniteFloat, PixelSize
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.telemetry.screenshot import (
    MAX_SIDE,
    MIN_SIDE,
    check_recording,
    screenshot_recording,
)
from legws_daemon.telemetry.web_viewer import (
    WebViewer,
    child_error,
    parse_web_target,
    spawn,
    stop_process,
    viewer_binary,
)

DEFAULT_SIZE = (1600, 1000)


@click.command("view")
@click.argument("recording", type=click.Path(path_type=Path))
@click.option(
    "--screenshot",
    "screenshot",
    type=click.Path(path_type=Path),
    help="write a PNG of the viewer (headless) instead of showing it",
)
@click.option(
    "--time",
    "at",
    type=FiniteFloat(),
    help="seconds on the recording's `time` timeline (with --screenshot; default: its last "
    "posterior value, else the end)",
)
@click.option(
    "--size",
    type=PixelSize(MIN_SIDE, MAX_SIDE),
    help=f"window size WIDTHxHEIGHT in pixels (default {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]})",
)
@click.option(
    "--web",
    metavar="[HOST:]PORT",
    help="serve it to the web viewer: the page on PORT, gRPC on PORT+1, HOST 127.0.0.1",
)
def view_cmd(
    recording: Path,
    screenshot: Path | None,
    at: float | None,
    size: tuple[int, int] | None,
    web: str | None,
) -> int:
    """Show a recording: native viewer, web viewer (--web) or a PNG (--screenshot)."""
    if at is not None and screenshot is None:
        raise click.UsageError("--time goes with --screenshot")
    if web is not None and screenshot is not None:
        raise click.UsageError("--web and --screenshot exclude each other")
    if web is not None and size is not None:
        raise click.UsageError("--size goes with --screenshot or the native viewer, not --web")
    if screenshot is not None:
        written = screenshot_recording(recording, screenshot, time=at, size=size or DEFAULT_SIZE)
        echo(str(written))
        return 0
    check_recording(recording)
    if web is not None:
        return _serve_web(recording, web)
    return _native(recording, size)


def _serve_web(recording: Path, web: str) -> int:
    target = parse_web_target(web, field="--web")
    with WebViewer.start(target, recording=recording.resolve(), field="--web") as viewer:
        echo(target.page_url)
        echo("serving until Ctrl-C", err=True)
        code = viewer.wait()
        raise InputError(
            f"the Rerun web viewer stopped (code {code}): {child_error(viewer.log) or 'no output'}",
            field="--web",
        )


def _native(recording: Path, size: tuple[int, int] | None) -> int:
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError(
            "no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset); use "
            "--screenshot OUT.png for a picture or --web [HOST:]PORT for a browser"
        )
    args = [str(viewer_binary()), "--bind", "127.0.0.1", "--port", "auto"]
    if size is not None:
        args += ["--window-size", f"{size[0]}x{size[1]}"]
    args.append(str(recording.resolve()))
    workdir = Path(tempfile.mkdtemp(prefix="legws-viewer-"))
    try:
        proc = spawn(args, workdir / "rerun.log")
        try:
            code = proc.wait()
        finally:
            stop_process(proc)
        if code != 0:
            raise InputError(
                f"the Rerun viewer failed (code {code}): "
                f"{child_error(workdir / 'rerun.log') or 'no output'}"
            )
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0
