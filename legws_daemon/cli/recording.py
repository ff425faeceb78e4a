"""``legws recording finish FILE``: add the footer to a daemon recording by hand.

The daemon finishes its ``save:`` recording when it exits (:mod:`~legws_daemon.telemetry.rrd_file`).
A daemon that was killed (SIGKILL, a power cut) or whose finishing step failed leaves the
raw stream: the viewer opens it, but ``rerun rrd verify`` wants the footer. This command
adds it (the data up to where the file ends, a cut-off last message dropped).
"""

from __future__ import annotations

import math
from pathlib import Path

import click

from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.errors import InputError
from legws_daemon.formats.files import regular_file
from legws_daemon.telemetry.rrd_file import FINISH_TIMEOUT, finish


@click.group("recording")
def recording_group() -> None:
    """Daemon recordings (.rrd)."""


@recording_group.command("finish")
@click.argument("file", type=click.Path(path_type=Path))
@click.option(
    "--timeout",
    type=FiniteFloat(),
    default=FINISH_TIMEOUT * 10,
    show_default=True,
    help="seconds the rewrite may take",
)
def finish_cmd(file: Path, timeout: float) -> int:
    """Add rerun's footer to FILE (in place, atomically; compacts the chunks)."""
    if not (math.isfinite(timeout) and timeout > 0):
        raise InputError(
            f"expected a positive number of seconds, got {timeout!r}", field="--timeout"
        )
    try:
        regular_file(file, "recording")
    except InputError as err:
        raise InputError(f"{err}; expected a rerun recording (.rrd)") from None
    before = file.stat().st_size
    problem = finish(file, timeout, tolerant=True)
    if problem is not None:
        raise InputError(problem)
    after = file.stat().st_size
    click.echo(f"{file}: finished ({before / 2**20:.1f} MiB -> {after / 2**20:.1f} MiB)")
    return 0
