"""Teleoperation traces (interfaces.md): written whole lines, read line by line, every bad
line refused naming the file, the line and the field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.trace import Segment, read_trace, tick_line, write_trace

GOOD = {"segment": 0, "ee": [0.55, 0.0, 0.30], "u": [0.41, 0.12, -0.80], "goal": [0.62, 0.21, 0.07]}


def _write(tmp_path: Path, *lines: str) -> Path:
    path = tmp_path / "trace.jsonl"
    path.write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return path


def test_the_interfaces_example_line_reads() -> None:
    assert json.loads(tick_line(0, GOOD["ee"], GOOD["u"], GOOD["goal"])) == GOOD


def test_segments_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    segments = [
        Segment(k, rng.uniform(0, 1, (n, 3)), rng.uniform(-0.5, 0.5, (n, 3)), rng.uniform(0, 1, 3))
        for k, n in ((0, 5), (3, 1), (7, 12))
    ]
    path = tmp_path / "t.jsonl"
    assert write_trace(path, segments) == 18
    back = read_trace(path)
    assert [s.label for s in back] == [0, 3, 7]
    for a, b in zip(segments, back, strict=True):
        np.testing.assert_allclose(b.ee, a.ee, atol=1e-7)
        np.testing.assert_allclose(b.u, a.u, atol=1e-6)
        np.testing.assert_allclose(b.goal, a.goal, atol=1e-7)


def test_extra_fields_and_blank_lines_are_allowed(tmp_path: Path) -> None:
    path = _write(tmp_path, json.dumps(GOOD | {"tick": 4, "note": "ok"}), "", json.dumps(GOOD))
    (seg,) = read_trace(path)
    assert seg.ticks == 2


@pytest.mark.parametrize(
    ("line", "field", "expected"),
    [
        ("{not json", None, "invalid JSON"),
        ("[1, 2]", None, "expected a JSON object"),
        (json.dumps({k: v for k, v in GOOD.items() if k != "u"}), "u", "missing"),
        (json.dumps(GOOD | {"segment": -1}), "segment", "integer >= 0"),
        (json.dumps(GOOD | {"segment": 1.5}), "segment", "integer >= 0"),
        (json.dumps(GOOD | {"ee": [0.1, 0.2]}), "ee", "three numbers"),
        (json.dumps(GOOD | {"ee": [0.1, "x", 0.3]}), "ee", "three numbers"),
        (json.dumps(GOOD | {"u": [0.9, 0.9, 0.0]}), "u", "norm at most 1"),
        (json.dumps(GOOD | {"goal": [0.1, 0.2, float("nan")]}), "goal", "finite"),
        (
            '{"segment": 0, "segment": 1, "ee": [0,0,0], "u": [0,0,0], "goal": [0,0,0]}',
            "segment",
            "twice",
        ),
        (json.dumps(GOOD | {"note": "a\x1b[31mred"}), "note", "control character"),
    ],
)
def test_a_bad_line_names_the_file_the_line_and_the_field(
    tmp_path: Path, line: str, field: str | None, expected: str
) -> None:
    path = _write(tmp_path, json.dumps(GOOD), line)
    with pytest.raises(InputError, match=expected) as err:
        read_trace(path)
    assert str(err.value).startswith(f"{path}:2: ")
    assert err.value.field == field
    assert "\n" not in str(err.value)


def test_a_segment_must_be_consecutive_and_keep_its_goal(tmp_path: Path) -> None:
    again = _write(tmp_path, json.dumps(GOOD), json.dumps(GOOD | {"segment": 1}), json.dumps(GOOD))
    with pytest.raises(InputError) as err:
        read_trace(again)
    assert str(err.value) == (
        f"{again}:3: segment: segment 0 started earlier: a segment's lines must be consecutive"
    )
    moved = _write(tmp_path, json.dumps(GOOD), json.dumps(GOOD | {"goal": [0.1, 0.1, 0.1]}))
    with pytest.raises(InputError) as err:
        read_trace(moved)
    assert str(err.value).startswith(f"{moved}:2: goal: segment 0 changed its goal")


def test_an_empty_or_missing_trace_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no ticks"):
        read_trace(_write(tmp_path, ""))
    with pytest.raises(InputError, match="no such file"):
        read_trace(tmp_path / "none.jsonl")
    with pytest.raises(InputError, match="expected a regular file"):
        read_trace(Path("/dev/null"))


def test_a_long_line_is_refused_before_it_is_parsed(tmp_path: Path) -> None:
    path = _write(tmp_path, json.dumps(GOOD), "[" * 70_000)
    with pytest.raises(InputError, match="line 2 is longer than"):
        read_trace(path)
