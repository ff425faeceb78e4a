"""Recordings are files like any other: their documents validated as on disk, their framing
and decoding checked before this process decodes them, rerun's log lines kept off the
terminal, and a file that cannot be finished whole never changed (the generated corpus:
tests/reliability/test_hostile_recordings.py)."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from legws_daemon.errors import InputError
from legws_daemon.formats.recording_doc import parse_stage_doc
from legws_daemon.telemetry import rrd_file
from legws_daemon.telemetry.recording import read_ee_path, read_stages
from legws_daemon.telemetry.rerun_log import GOALS_DOC, TELEMETRY_FORMAT, RerunLog
from tests.reliability.recording_corpus import doc_texts, valid_doc, write_recording
from tests.telemetry.helpers import verify


def _raw(path: Path, frames: int = 30) -> Path:
    """A recording without footer (as a killed daemon leaves it), flushed chunk by chunk."""
    stream = rr.RecordingStream("legws")
    stream.set_sinks(rr.FileSink(path, write_footer=False))
    doc = json.dumps(valid_doc())
    stream.log("meta/robot", rr.TextDocument("sawyer-sim"), static=True)
    stream.log(GOALS_DOC, rr.TextDocument(doc), static=True)
    for k in range(frames):
        stream.set_time("tick", sequence=k)
        stream.log("points", rr.Points3D(np.random.default_rng(k).random((20, 3))))
        stream.flush()
    stream.disconnect()
    return path


def test_a_stage_document_is_validated_as_the_goal_set_on_disk() -> None:
    texts = doc_texts()
    where = "run.rrd: meta/goals"
    doc, _ = parse_stage_doc(json.dumps(valid_doc()), where, TELEMETRY_FORMAT)
    assert doc.stage_index == 0 and doc.p_thresh == 0.9
    for label, expected in {
        "p-thresh-2": "p_thresh: Input should be less than 1",
        "version-negative": "telemetry format -1 is not supported",
        "version-huge": "is not supported",
        "duplicate-p-thresh": "the key 'p_thresh' appears twice",
        "nested-5000": "nested",
        "stage-escape": "U+001B",
        "stage-line-break": "printable",
        "stage-index-negative": "stage_index: Input should be greater than or equal to 0",
        "type-goals": "goals: Input should be a valid list",
        "goal-far-away": "goals[0].position[0]",
        "nan-p-thresh": "params.p_thresh",  # two fields, one line
    }.items():
        with pytest.raises(InputError) as err:
            parse_stage_doc(texts[label], where, TELEMETRY_FORMAT)
        message = str(err.value)
        assert message.startswith(where) and expected in message, (label, message)
        assert "\n" not in message and "\x1b" not in message


def test_scan_reads_the_framing_and_finds_where_it_breaks(tmp_path: Path) -> None:
    path = _raw(tmp_path / "raw.rrd")
    data = path.read_bytes()
    whole = rrd_file.scan(path)
    assert whole.damage is None and not whole.footer and whole.intact == len(data)
    assert whole.chunks >= 30 and whole.ends[-1] == len(data)
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: whole.ends[10] + 20])  # 4 bytes into a message's payload
    found = rrd_file.scan(cut)
    assert found.damage is not None and "cut off" in found.damage
    assert found.intact == whole.ends[10] and len(found.ends) == 11
    bad = bytearray(data)
    struct.pack_into("<Q", bad, whole.ends[5], 77)  # a kind that is no message
    cut.write_bytes(bytes(bad))
    assert "not a message (kind 77)" in (rrd_file.scan(cut).damage or "")
    for head, expected in (
        (b"\0" * 12, "does not start with b'RRF2'"),
        (data[:8] + b"\x09\x02\0\0", "unknown encoding options"),
        (data[:4] + bytes([9, 9, 0, 0]) + data[8:12], "newer than the rerun"),
    ):
        cut.write_bytes(head + data[12:])
        with pytest.raises(InputError, match=expected):
            rrd_file.scan(cut)


def test_rerun_log_lines_never_reach_the_terminal(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    capfd.readouterr()
    with rrd_file.quiet_stderr() as captured:
        os.write(2, b"\x1b[33m WARN\x1b[0m re_log_encoding::rrd::frames: a line of rerun\n")
    assert "a line of rerun" in captured.text and captured.reason == "a line of rerun"
    assert capfd.readouterr().err == ""
    path = write_recording(tmp_path / "newer.rrd", json.dumps(valid_doc()))
    data = bytearray(path.read_bytes())
    data[6] = 9  # written by a newer patch release of this rerun: rerun warns as it reads
    path.write_bytes(bytes(data))
    assert read_stages(path)[0].name == "pick"
    assert read_ee_path(path).ticks.tolist() == [0, 1, 2, 3, 4]
    assert capfd.readouterr().err == ""


def test_a_damaged_file_is_never_changed_and_its_whole_messages_can_be_recovered(
    tmp_path: Path,
) -> None:
    path = _raw(tmp_path / "raw.rrd")
    data = path.read_bytes()
    ends = rrd_file.scan(path).ends
    damaged = tmp_path / "cut.rrd"
    damaged.write_bytes(data[: ends[-3] + 40])
    with pytest.raises(InputError) as err:
        rrd_file.finish_recording(damaged)
    message = str(err.value)
    assert "cannot be finished whole" in message and "it is left as it is" in message
    assert "recoverable:" in message and " chunks" in message and "--out" in message
    assert damaged.read_bytes() == data[: ends[-3] + 40]
    with pytest.raises(InputError, match="not a readable rerun recording"):
        read_stages(damaged)
    out = tmp_path / "recovered.rrd"
    done = rrd_file.finish_recording(damaged, out=out)
    assert not done.whole and done.written == out and done.chunks == done.of
    assert damaged.read_bytes() == data[: ends[-3] + 40]
    assert verify(out).returncode == 0 and read_stages(out)[0].name == "pick"
    with pytest.raises(InputError, match="--out must name another file"):
        rrd_file.finish_recording(damaged, out=damaged)
    with pytest.raises(InputError, match="folder"):
        rrd_file.finish_recording(damaged, out=tmp_path)
    assert damaged.read_bytes() == data[: ends[-3] + 40]
    # a healthy raw file is finished (compacted: the test is data kept, not size)
    done = rrd_file.finish_recording(path)
    assert done.whole and done.written == path and verify(path).returncode == 0
    assert rrd_file.finish_recording(path).written is None  # already finished: left as it is


def test_a_save_link_is_written_and_finished_through_the_link(tmp_path: Path) -> None:
    (tmp_path / "disk").mkdir()
    target = tmp_path / "disk" / "session.rrd"
    link = tmp_path / "session.rrd"
    link.symlink_to(target)  # dangling: the recording creates its target
    with RerunLog(f"save:{link}", robot="sawyer-sim") as log:
        log.log_text(0, 0.0, "info", "hello")
    assert log.finished is True
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert verify(target).returncode == 0
    assert not list(tmp_path.glob(".*finishing")) and not list(target.parent.glob(".*finishing"))
