"""``legws recording finish FILE [--out OTHER]``: add the footer to a daemon recording by hand.

The daemon finishes its ``save:`` recording when it exits (:mod:`~legws_daemon.telemetry.rrd_file`).
A daemon that was killed (SIGKILL, a power cut) or whose finishing step failed leaves the
raw stream: the viewer opens it, but ``rerun rrd verify`` wants the footer. This command
adds it, in place (atomically; a symbolic link's target, in the target's folder, the link
kept), when every message of the file is kept.

A file that cannot be finished whole (cut off in the middle of a message, a damaged length
or payload) is never changed: the command says what is damaged and what could be
recovered (so many chunks, up to a time), exits 2, and ``--out OTHER`` writes that part to
another file. A file that is no daemon recording (no legws telemetry in it) is left alone.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import click

from legws_daemon.cli.numbers import FiniteFloat
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import echo
from legws_daemon.telemetry.rerun_log import GOALS_DOC
from legws_daemon.telemetry.rrd_file import FINISH_TIMEOUT, finish_recording

#: The entities of which a daemon recording holds at least one: the robot, logged at start,
#: and the stage documents.
LEGWS_ENTITIES = ("meta/robot", GOALS_DOC)


@click.group("recording")
def recording_group() -> None:
    """Daemon recordings (.rrd)."""


def _mib(n: int) -> str:
    return f"{n / 2**20:.1f} MiB"


@recording_group.command("finish")
@click.argument("file", type=click.Path(path_type=Path))
@click.option(
    "--timeout",
    type=FiniteFloat(),
    default=FINISH_TIMEOUT * 10,
    show_default=True,
    help="seconds the rewrite may take",
)
@click.option(
    "--out",
    type=click.Path(path_type=Path),
    help="Write the finished recording (of a damaged one: what can be recovered) to this "
    "file instead; FILE is never changed.",
)
def finish_cmd(file: Path, timeout: float, out: Path | None) -> int:
    """Add rerun's footer to FILE (in place, atomically; compacts the chunks).

    Only when every message of FILE is kept: a damaged file is left as it is, with what
    could be recovered of it; --out writes that to another file.
    """
    if not (math.isfinite(timeout) and timeout > 0):
        raise InputError(
            f"expected a positive number of seconds, got {timeout!r}", field="--timeout"
        )
    done = finish_recording(file, timeout, out=out, needs=LEGWS_ENTITIES)
    name = f"{file} (-> {done.source})" if os.path.islink(file) else str(file)
    if done.written is None:
        echo(f"{name}: already finished ({_mib(done.before)}); left as it is")
    elif done.whole and out is None:
        echo(f"{name}: finished ({_mib(done.before)} -> {_mib(done.after)})")
    elif done.whole:
        echo(
            f"{name}: finished into {out} ({_mib(done.before)} -> {_mib(done.after)}); "
            f"{file} is left as it is"
        )
    else:
        upto = "" if done.seconds is None else f", up to time {done.seconds:.2f} s"
        echo(
            f"{name}: damaged ({done.damage}); wrote what could be recovered, {done.chunks} "
            f"of {done.of} chunks{upto}, to {out} ({_mib(done.after)}); {file} is left as it is"
        )
    return 0
