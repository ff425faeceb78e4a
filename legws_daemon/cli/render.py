"""``legws render``: a PNG picture of a scene layout, top-down or in perspective."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click

from legws_daemon.cli.robot import robot_option
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path
from legws_daemon.formats.printable import echo
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.layout_file import load_layout

if TYPE_CHECKING:
    from legws_daemon.robot.render import View

#: Largest picture side, pixels (kept in step with ``legws_daemon.robot.render.MAX_SIZE``).
MAX_SIZE = 4096


@click.command("render")
@click.option("--scene", required=True, help="Scene name (see `legws scenes`) or .toml path.")
@click.option(
    "--layout",
    "layout_file",
    type=click.Path(path_type=Path),
    help="Layout JSON (default: the scene's shipped layout).",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="PNG file to write; its folder is created when missing.",
)
@click.option(
    "--width", type=click.IntRange(16, MAX_SIZE), default=800, show_default=True, help="Pixels."
)
@click.option(
    "--height", type=click.IntRange(16, MAX_SIZE), default=600, show_default=True, help="Pixels."
)
@click.option(
    "--view",
    type=click.Choice(["top", "perspective"]),
    default="top",
    show_default=True,
    help="top: straight down on the table; perspective: from the robot's front-left.",
)
@robot_option("sawyer", what="the arm drawn at its home pose")
def render_cmd(
    scene: str,
    layout_file: Path | None,
    output: Path,
    width: int,
    height: int,
    view: str,
    robot: str,
) -> None:
    """Render a scene's layout to a PNG: table, objects, the robot at home, grasp markers.

    The grasp pose of every candidate goal is drawn in magenta: a dot at the grasp point,
    a stem back along the approach direction and a bar across the closing direction.
    Needs offscreen OpenGL (MUJOCO_GL=egl by default; MUJOCO_GL=osmesa also works).
    """
    sc = load_scene(scene)
    layout = load_layout(layout_file, sc) if layout_file else None
    if os.path.lexists(output):
        output_path(output)  # a device or folder there: one line before any rendering

    # mujoco and the GL stack load only here: the other commands never pay for them
    from legws_daemon.robot.render import render_layout, save_png

    start = time.perf_counter()
    shown: View = "top" if view == "top" else "perspective"
    image = render_layout(sc, layout, width, height, shown, robot)
    try:
        path = save_png(image, output)
    except OSError as err:
        detail = err.strerror or str(err)
        if err.filename and str(err.filename) != str(output):
            detail += f" ({err.filename})"
        raise InputError(f"cannot write: {detail}", source=str(output)) from None
    ms = (time.perf_counter() - start) * 1000
    echo(f"wrote {path} ({width}x{height}, {view} view, {ms:.0f} ms)")
