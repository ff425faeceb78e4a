"""Replay: loading recordings (errors name file:line and field), timing, and a zenoh round trip."""

from __future__ import annotations

import itertools
import json
import math
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons, JoystickMessage, dump, parse
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.joystick.publisher import Publisher, Sample
from legws_daemon.joystick.replay import load_recording, nominal_interval, replay, schedule
from legws_daemon.transport.session import config_from_spec
from tests.joystick.helpers import KEY, daemon_side, dial_spec
from tests.net import free_port


def message(
    seq: int, stamp: float, axes: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> JoystickMessage:
    return JoystickMessage.model_validate(
        {"schema": 1, "seq": seq, "stamp": stamp, "axes": list(axes), "source": "rec"}
    )


def write_lines(path: Path, lines: list[str]) -> Path:
    path.write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return path


def good(seq: int, stamp: Any, **extra: Any) -> str:
    data: dict[str, Any] = {"schema": 1, "seq": seq, "stamp": stamp, "axes": [0.1, 0.0, 0.0]}
    data.update(extra)
    return json.dumps(data)


def recording_publisher(path: Path) -> Publisher:
    return Publisher(config_from_spec(TransportSpec(listen=[])), KEY, source="t", record=path)


def read_record(path: Path) -> list[JoystickMessage]:
    return [parse(JoystickMessage, line, "rec") for line in path.read_text().splitlines()]


def test_a_recording_loads_back_exactly(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    with recording_publisher(record) as pub:
        sent = [pub.publish((0.1 * i, 0.0, 0.0), Buttons(cancel=i == 2)) for i in range(5)]
    assert load_recording(record) == sent


def test_blank_lines_are_skipped(tmp_path: Path) -> None:
    path = write_lines(tmp_path / "r.jsonl", ["", good(0, 1.0), "   ", good(1, 1.1), ""])
    assert [m.seq for m in load_recording(path)] == [0, 1]


@pytest.mark.parametrize(
    ("bad", "needle"),
    [
        ("{not json", ": not JSON"),
        (good(1, 1.1, axes=[0.9, 0.9, 0.0]), ": axes: "),
        (good(1, 1.1, axes=[0.1, 0.0]), ": axes[2]: "),
        (good(1, 1.1, schema=2), ": schema: unsupported schema 2"),
        (good(1, "late"), ": stamp: "),
        (good(1, 1.1, colour="red"), ": colour: "),
        (good(-1, 1.1), ": seq: "),
        (good(1, 0.5), ": stamp: 0.5 is earlier than the previous message's 1.0"),
        ("[1, 2, 3]", ":3: "),
    ],
)
def test_bad_lines_name_file_line_and_field(tmp_path: Path, bad: str, needle: str) -> None:
    path = write_lines(tmp_path / "r.jsonl", [good(0, 1.0), "", bad, good(2, 1.2)])
    with pytest.raises(InputError) as info:
        load_recording(path)
    text = str(info.value)
    assert text.startswith(f"{path}:3: "), text
    assert needle in text, text
    assert "\n" not in text


def test_empty_and_missing_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no joystick messages"):
        load_recording(write_lines(tmp_path / "empty.jsonl", ["", " "]))
    with pytest.raises(InputError, match="no such file"):
        load_recording(tmp_path / "missing.jsonl")


def test_too_many_messages_are_refused_before_any_is_parsed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import legws_daemon.joystick.replay as module

    monkeypatch.setattr(module, "MAX_MESSAGES", 4)
    lines = ["{broken", "", *[good(i, 1.0 + 0.05 * i) for i in range(1, 4)], good(4, 1.2)]
    path = write_lines(tmp_path / "r.jsonl", lines)
    with pytest.raises(InputError) as info:
        load_recording(path)
    # the fifth message (line 6) is one too many; the broken first line is never parsed
    assert str(info.value).startswith(f"{path}:6: more than 4 messages"), str(info.value)
    assert [m.seq for m in load_recording(write_lines(tmp_path / "ok.jsonl", lines[2:]))] == [
        1, 2, 3, 4,
    ]  # fmt: skip


def test_schedule_keeps_intervals_within_a_recording_and_bridges_between() -> None:
    # two recordings appended: seq 0..2 at t = 10.0, 10.1, 10.3, then seq 0..1 an hour later
    msgs = [message(0, 10.0), message(1, 10.1), message(2, 10.3), message(0, 3610.0)]
    msgs.append(message(1, 3610.05))
    assert schedule(msgs, gap=0.5) == pytest.approx([0.0, 0.1, 0.3, 0.8, 0.85])
    assert nominal_interval(msgs, default=1.0) == pytest.approx(0.1)
    assert nominal_interval(msgs[:1], default=0.05) == 0.05
    # equal stamps within a recording are due together
    assert schedule([message(0, 1.0), message(1, 1.0)], gap=0.5) == [0.0, 0.0]


def test_stamp_going_back_in_a_new_recording_is_fine(tmp_path: Path) -> None:
    path = write_lines(tmp_path / "r.jsonl", [good(0, 5.0), good(1, 5.1), good(0, 1.0)])
    assert [m.stamp for m in load_recording(path)] == [5.0, 5.1, 1.0]


def test_replay_keeps_the_recorded_timing_scaled_by_speed(tmp_path: Path) -> None:
    msgs = [
        message(0, 50.0, (0.1, 0, 0)),
        message(1, 50.2, (0.2, 0, 0)),
        message(2, 50.6, (0, 0, 0.3)),
    ]
    out = tmp_path / "out.jsonl"
    with recording_publisher(out) as pub:
        start = time.time()
        assert replay(pub, msgs, gap=0.05, speed=2.0) == 3
        elapsed = time.time() - start
    got = read_record(out)
    assert [m.axes for m in got] == [m.axes for m in msgs] + [(0.0, 0.0, 0.0)]
    assert [m.seq for m in got] == [0, 1, 2, 3]
    assert got[0].stamp >= start  # fresh stamps
    offsets = [m.stamp - got[0].stamp for m in got[:3]]
    assert offsets == pytest.approx([0.0, 0.1, 0.3], abs=0.06)
    assert 0.28 <= elapsed < 10.0  # (the upper bound: it ended, not a rate)


def test_loop_repeats_until_the_duration(tmp_path: Path) -> None:
    msgs = [message(0, 0.0, (0.5, 0, 0)), message(1, 0.05, (0, 0.5, 0))]
    out = tmp_path / "out.jsonl"
    with recording_publisher(out) as pub:
        start = time.monotonic()
        published = replay(pub, msgs, gap=0.05, loop=True, duration=0.5)
        assert 0.45 <= time.monotonic() - start < 1.5
    got = read_record(out)
    assert 6 <= published <= 11  # one message per 0.05 s for 0.5 s
    assert len(got) == published + 1
    pattern = [m.axes for m in msgs]
    assert [m.axes for m in got[:-1]] == (pattern * 10)[:published]
    assert got[-1].axes == (0.0, 0.0, 0.0)


def test_stop_event_ends_a_replay_with_a_zero_message(tmp_path: Path) -> None:
    msgs = [message(i, i * 1.0, (0.2, 0, 0)) for i in range(10)]  # 9 s long
    out = tmp_path / "out.jsonl"
    stop = threading.Event()
    timer = threading.Timer(0.3, stop.set)
    with recording_publisher(out) as pub:
        timer.start()
        start = time.monotonic()
        assert replay(pub, msgs, gap=1.0, stop_event=stop) == 1
        assert time.monotonic() - start < 2.0
        timer.join(1.0)
    assert [m.axes for m in read_record(out)] == [(0.2, 0.0, 0.0), (0.0, 0.0, 0.0)]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"speed": 0.0}, "speed"),
        ({"speed": math.nan}, "speed"),
        ({"gap": 0.0}, "gap"),
        ({"duration": -1.0}, "duration"),
    ],
)
def test_bad_replay_settings(tmp_path: Path, kwargs: dict[str, float], field: str) -> None:
    args: dict[str, Any] = {"gap": 0.05, **kwargs}
    with recording_publisher(tmp_path / "o.jsonl") as pub, pytest.raises(InputError, match=field):
        replay(pub, [message(0, 0.0)], **args)


def test_record_then_replay_round_trip_over_zenoh(tmp_path: Path) -> None:
    record = tmp_path / "session.jsonl"
    pattern: list[Sample] = [
        ((0.6, 0.0, -0.8), Buttons()),
        ((0.0, 0.5, 0.0), Buttons()),
        ((0.0, 0.5, 0.0), Buttons(cancel=True)),
        ((-0.3, 0.0, 0.0), Buttons(confirm=True)),
    ]
    ticks = iter(pattern)
    stop = threading.Event()

    def sample() -> Sample | None:
        nxt = next(ticks, None)
        if nxt is None:
            stop.set()
        return nxt

    with recording_publisher(record) as pub:
        pub.run(sample, rate=20.0, stop_event=stop)
    recorded = load_recording(record)
    assert len(recorded) == len(pattern) + 1  # with the final zero

    port = free_port()
    pub = Publisher(config_from_spec(dial_spec(port)), KEY, source="replay-test")
    with daemon_side(port) as inbox, pub:
        assert pub.wait_matched(10.0)
        assert replay(pub, recorded, gap=nominal_interval(recorded, 0.05)) == len(recorded)
        got = inbox.wait_for(len(recorded) + 1)
    assert [(m.axes, m.buttons) for m in got[:-1]] == [(m.axes, m.buttons) for m in recorded]
    assert got[-1].axes == (0.0, 0.0, 0.0)
    assert [m.seq for m in got] == list(range(len(recorded) + 1))
    assert {m.source for m in got} == {"replay-test"}
    assert got[0].stamp > recorded[-1].stamp  # fresh stamps
    # in order; the timing itself is the schedule's (test above), not the machine's load
    assert all(b.stamp >= a.stamp for a, b in itertools.pairwise(got))
    assert dump(got[0]) != dump(recorded[0])
