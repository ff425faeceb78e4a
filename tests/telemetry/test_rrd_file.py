"""Finishing a recording: the daemon writes ``save:`` files without rerun's footer (whose
manifest would grow in memory all session) and adds it at close, atomically."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from legws_daemon.telemetry import rrd_file
from legws_daemon.telemetry.recording import read_commits, read_ee_path, read_stages
from legws_daemon.telemetry.rerun_log import RerunLog
from tests.telemetry.helpers import log_episode, raw_recording, straight_episode, verify

LEGWS = [sys.executable, "-m", "legws_daemon"]


def _raw(path: Path) -> Path:
    return raw_recording(path, robot="r")


def _content(path: Path) -> tuple[object, ...]:
    stages = [(s.index, s.name, s.scene, s.candidates) for s in read_stages(path)]
    ee = read_ee_path(path)
    return stages, ee.ticks.tolist(), ee.positions.round(9).tolist(), read_commits(path)


def test_close_finishes_the_file_and_keeps_every_stage(tmp_path: Path) -> None:
    path = tmp_path / "run.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        first = straight_episode("breakfast_easy", "banana", hold=2)
        log_episode(log, first, stage="easy")
        second = straight_episode("desk", "white_mug", hold=2)
        log_episode(log, second, tick0=len(first.positions), stage="desk")
    assert log.finished is True
    result = verify(path)
    assert result.returncode == 0, result.stderr
    stages = read_stages(path)
    # compaction keeps only the newest *static* goals document: the history is on the timeline
    assert [(s.index, s.name) for s in stages] == [(0, "easy"), (1, "desk")]
    assert not list(tmp_path.glob(".*finishing"))


def test_a_raw_file_lacks_the_footer_until_finished_and_the_data_is_unchanged(
    tmp_path: Path,
) -> None:
    path = _raw(tmp_path / "raw.rrd")
    result = verify(path)
    assert result.returncode != 0 and "footer" in (result.stderr + result.stdout).lower()
    before = _content(path)  # the raw stream is readable as it is
    assert rrd_file.finish(path) is None
    assert verify(path).returncode == 0
    assert _content(path) == before
    assert rrd_file.finish(path) is None  # finishing a finished file is harmless
    assert _content(path) == before


def test_a_file_cut_off_by_a_crash_is_kept_and_its_whole_messages_can_be_recovered(
    tmp_path: Path,
) -> None:
    full = _raw(tmp_path / "full.rrd")  # the first stage flushed before the second
    data = full.read_bytes()
    all_ticks = read_ee_path(full).ticks.tolist()
    kept = []
    for fraction in (0.45, 0.7, 0.95):
        cut = tmp_path / f"cut{fraction}.rrd"
        cut.write_bytes(data[: int(len(data) * fraction)])  # a kill in the middle of a message
        problem = rrd_file.finish(cut)
        assert problem is not None and "cannot be finished whole" in problem, problem
        assert "recoverable" in problem and "--out" in problem
        assert cut.read_bytes() == data[: int(len(data) * fraction)]  # never shrunk
        out = tmp_path / f"recovered{fraction}.rrd"
        done = rrd_file.finish_recording(cut, out=out)
        assert not done.whole and done.written == out and 0 < done.chunks <= done.of
        assert cut.read_bytes() == data[: int(len(data) * fraction)]
        assert verify(out).returncode == 0
        ticks = read_ee_path(out).ticks.tolist()
        assert ticks == all_ticks[: len(ticks)]
        kept.append(len(ticks))
    assert 0 < kept[0] < len(all_ticks)  # the first stage is there, the second is lost
    assert kept == sorted(kept)


def test_what_cannot_be_finished_is_left_as_it_was(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.rrd"
    garbage.write_bytes(b"not a recording at all")
    problem = rrd_file.finish(garbage)
    assert problem is not None and "not a rerun recording" in problem
    assert garbage.read_bytes() == b"not a recording at all"

    assert "no such file" in (rrd_file.finish(tmp_path / "missing.rrd") or "")

    path = _raw(tmp_path / "raw.rrd")
    raw = path.read_bytes()
    problem = rrd_file.finish(path, timeout=1e-4)  # the rewrite cannot finish in time
    assert problem is not None and "took over" in problem and "raw file is kept" in problem
    assert path.read_bytes() == raw
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_close_reports_a_file_it_could_not_finish(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(rrd_file, "rerun_cli", lambda: str(tmp_path / "no-such-rerun"))
    path = tmp_path / "run.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        log_episode(log, straight_episode(hold=1))
    assert log.finished is False
    assert log.last_error is not None and "legws recording finish" in log.last_error
    assert verify(path).returncode != 0  # raw, but still a readable stream
    assert read_stages(path)


@pytest.mark.slow  # five `legws recording finish` processes: ~5 s
def test_the_cli_finishes_a_file_and_refuses_what_is_not_a_recording(tmp_path: Path) -> None:
    path = _raw(tmp_path / "raw.rrd")
    out = subprocess.run(
        [*LEGWS, "recording", "finish", str(path)], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"{path}: finished (")
    assert verify(path).returncode == 0

    bad = tmp_path / "bad.rrd"
    bad.write_text("hello")
    for args in (
        [str(bad)],
        [str(tmp_path)],
        [str(tmp_path / "none.rrd")],
        [str(path), "--timeout", "-1"],
    ):
        out = subprocess.run(
            [*LEGWS, "recording", "finish", *args], capture_output=True, text=True, timeout=60
        )
        assert out.returncode == 2, (args, out.stderr)
        lines = out.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("legws: error: "), out.stderr
