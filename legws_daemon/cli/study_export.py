"""``legws study export``: a study's trials as a LeRobotDataset (v3.0, docs/study.md)."""

from __future__ import annotations

from pathlib import Path

import click

from legws_daemon.cli.robot import robot_option
from legws_daemon.formats.printable import echo


@click.command("export")
@click.argument("folder", type=click.Path(path_type=Path, file_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The dataset folder: meta/info.json, meta/stats.json, meta/tasks.parquet, "
    "meta/episodes/, data/.",
)
@click.option("--force", is_flag=True, help="Write into a folder that is not empty.")
@robot_option("sawyer", what="the arm the study ran on (the dataset's robot_type)")
def export_cmd(folder: Path, out: Path, force: bool, robot: str) -> None:
    """Export the study in FOLDER (its trials.parquet and every participant's frames/) as a
    LeRobotDataset v3.0: one episode per trial with frames (practice included), one frame
    per control tick (the EE position as observation.state, the joystick axes as action),
    the trial table's columns (pseudonym, condition, layout, certificates, measures) in
    the episodes' metadata."""
    from legws_daemon.core.params import Params
    from legws_daemon.study.lerobot import export_lerobot

    fps = round(1.0 / Params().dt)
    done = export_lerobot(folder, out, fps=fps, robot_type=robot, force=force)
    echo(
        f"legws: {done['episodes']} episodes ({done['frames']} frames at {fps} Hz, "
        f"{done['tasks']} tasks) of {done['participants']} participants -> {out} "
        "(LeRobotDataset v3.0)",
        err=True,
    )
