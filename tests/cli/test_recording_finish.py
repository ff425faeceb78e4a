"""``legws recording finish FILE [--out OTHER]``: a raw recording finished in place (through a
link: its target, the link kept); a damaged one never changed, what can be recovered of it
said, and written elsewhere with ``--out``; a foreign one left alone."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import rerun as rr

from legws_daemon.telemetry import rrd_file
from legws_daemon.telemetry.recording import read_stages
from tests.cli.helpers import Result, assert_bad_input
from tests.telemetry.helpers import verify
from tests.telemetry.test_recording_hostile import _raw

Cli = Callable[..., Result]


def test_a_raw_recording_is_finished_through_its_link(cli: Cli, tmp_path: Path) -> None:
    (tmp_path / "disk").mkdir()
    target = _raw(tmp_path / "disk" / "run.rrd")
    link = tmp_path / "run.rrd"
    link.symlink_to(target)
    result = cli("recording", "finish", link)
    assert result.code == 0, result
    assert result.out.startswith(f"{link} (-> {target}): finished (") and result.err == ""
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert verify(target).returncode == 0
    again = cli("recording", "finish", link)
    assert again.code == 0 and "already finished" in again.out
    assert not list(tmp_path.glob(".*finishing")) and not list(target.parent.glob(".*finishing"))


def test_a_damaged_recording_is_kept_and_out_writes_what_can_be_recovered(
    cli: Cli, tmp_path: Path
) -> None:
    data = _raw(tmp_path / "raw.rrd").read_bytes()
    ends = rrd_file.scan(tmp_path / "raw.rrd").ends
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: ends[-1] - 5])
    line = assert_bad_input(
        cli("recording", "finish", cut), str(cut), "cannot be finished whole", "recoverable:",
        "chunks", "it is left as it is", "--out",
    )  # fmt: skip
    assert "finished (" not in line
    assert cut.read_bytes() == data[: ends[-1] - 5]
    out = tmp_path / "recovered.rrd"
    result = cli("recording", "finish", cut, "--out", out)
    assert result.code == 0, result
    assert result.out.startswith(f"{cut}: damaged (") and f"to {out}" in result.out
    assert cut.read_bytes() == data[: ends[-1] - 5]
    assert verify(out).returncode == 0 and read_stages(out)[0].name == "pick"
    assert_bad_input(cli("recording", "finish", cut, "--out", cut), "--out")
    assert_bad_input(cli("recording", "finish", cut, "--out", tmp_path), "folder")
    assert cut.read_bytes() == data[: ends[-1] - 5]


def test_a_foreign_or_missing_recording_is_refused_in_one_line(cli: Cli, tmp_path: Path) -> None:
    foreign = tmp_path / "points.rrd"
    stream = rr.RecordingStream("someone-else")
    stream.set_sinks(rr.FileSink(foreign, write_footer=False))
    stream.log("points", rr.Points3D(np.zeros((3, 3))))
    stream.disconnect()
    before = foreign.read_bytes()
    assert_bad_input(cli("recording", "finish", foreign), "no legws telemetry")
    assert foreign.read_bytes() == before
    dangling = tmp_path / "gone.rrd"
    dangling.symlink_to(tmp_path / "nothing.rrd")
    assert_bad_input(cli("recording", "finish", dangling), "is a link to", "does not exist")
    assert dangling.is_symlink()
