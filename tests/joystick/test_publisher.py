"""The shared publisher: validated messages, seq, recording, the fixed-rate loop, signals."""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.messages import Buttons, JoystickMessage, parse
from legws_daemon.formats.profile import TransportSpec, load_profile
from legws_daemon.joystick.publisher import (
    Publisher,
    Sample,
    clip_norm,
    dial_spec,
    process_source,
    publisher_config,
    stop_on_signals,
)
from legws_daemon.transport.session import config_from_spec
from tests.joystick.helpers import KEY, daemon_side
from tests.joystick.helpers import dial_spec as dial_port
from tests.net import free_port

REPO = Path(__file__).resolve().parents[2]


def isolated() -> Publisher:
    """A publisher whose session has no endpoints at all (nothing leaves the process)."""
    return Publisher(config_from_spec(TransportSpec(listen=[])), KEY, source="test")


def isolated_recording(path: Path) -> Publisher:
    return Publisher(config_from_spec(TransportSpec(listen=[])), KEY, source="test", record=path)


def read_record(path: Path) -> list[JoystickMessage]:
    lines = path.read_text(encoding="utf-8").splitlines()
    return [parse(JoystickMessage, line, f"{path}:{i}") for i, line in enumerate(lines, 1)]


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@given(st.tuples(finite, finite, finite))
def test_clip_norm_keeps_direction_and_bounds_the_norm(axes: tuple[float, float, float]) -> None:
    out = clip_norm(axes)
    norm_in = math.sqrt(sum(a * a for a in axes))
    norm_out = math.sqrt(sum(a * a for a in out))
    assert norm_out <= 1.0 + 1e-9
    assert all(-1.0 <= a <= 1.0 for a in out)
    if norm_in <= 1.0:
        assert out == pytest.approx(axes, abs=1e-12)
    else:
        assert norm_out == pytest.approx(1.0, abs=1e-9)
        assert [o * norm_in for o in out] == pytest.approx(list(axes), rel=1e-9, abs=1e-9)
    JoystickMessage.model_validate({"schema": 1, "seq": 0, "stamp": 0.0, "axes": list(out)})


@pytest.mark.parametrize("bad", [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.1, 0.2)])
def test_clip_norm_rejects_non_finite_or_wrong_length(bad: tuple[float, ...]) -> None:
    with pytest.raises(InputError, match="axes"):
        clip_norm(bad)


def test_dial_spec_connects_to_what_the_daemon_listens_on() -> None:
    profile = load_profile(REPO / "hw_profiles" / "sim.toml")
    spec = dial_spec(profile.transport)
    assert spec.listen == []
    assert spec.connect == ["tcp/127.0.0.1:7447"]
    assert spec.multicast_scouting is False
    assert spec.mode == profile.transport.mode
    both = TransportSpec(listen=["tcp/127.0.0.1:1"], connect=["tcp/127.0.0.1:2", "tcp/127.0.0.1:1"])
    assert dial_spec(both).connect == ["tcp/127.0.0.1:2", "tcp/127.0.0.1:1"]


def test_publisher_config_prefers_the_file(tmp_path: Path) -> None:
    profile = load_profile(REPO / "hw_profiles" / "sim.toml")
    with pytest.raises(InputError, match="no such file"):
        publisher_config(profile, tmp_path / "missing.json5")
    config = publisher_config(profile)
    assert '"tcp/127.0.0.1:7447"' in config.get_json("connect/endpoints")
    assert config.get_json("listen/endpoints").replace(" ", "") == "[]"


def test_process_source_is_a_valid_label_unique_to_the_process() -> None:
    label = process_source("keyboard" * 20)
    assert label.endswith(f":{os.getpid()}")
    assert 1 <= len(label) <= 64


def test_messages_arrive_validated_with_increasing_seq_and_are_recorded(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    port = free_port()
    pub = Publisher(config_from_spec(dial_port(port)), KEY, source="unit", record=record)
    with daemon_side(port) as inbox, pub:
        assert pub.wait_matched(10.0)
        before = time.time()
        sent = [
            pub.publish((0.6, 0.0, -0.8)),
            pub.publish([0.0, 0.5, 0.0], Buttons(cancel=True)),
            pub.publish((0.0, 0.0, 0.0), Buttons(confirm=True)),
        ]
        after = time.time()
        got = inbox.wait_for(3)
    assert [m.seq for m in sent] == [0, 1, 2]
    assert got == sent
    assert all(before <= m.stamp <= after for m in got)
    assert got[0].axes == (0.6, 0.0, -0.8)
    assert got[1].buttons == Buttons(cancel=True)
    assert got[2].buttons == Buttons(confirm=True)
    assert {m.source for m in got} == {"unit"}
    assert read_record(record) == sent
    assert inbox.rejected == []


def test_invalid_deflection_is_refused_and_nothing_is_sent(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    with isolated_recording(record) as pub:
        with pytest.raises(InputError, match="norm <= 1"):
            pub.publish((0.8, 0.8, 0.0))
        with pytest.raises(InputError, match="axes"):
            pub.publish((1.5, 0.0, 0.0))
        with pytest.raises(InputError, match="axes"):
            pub.publish((math.nan, 0.0, 0.0))
        assert pub.seq == 0
        assert pub.publish((0.1, 0.0, 0.0)).seq == 0
    assert [m.axes for m in read_record(record)] == [(0.1, 0.0, 0.0)]


def test_record_appends_to_an_existing_file(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    for _ in range(2):
        with isolated_recording(record) as pub:
            pub.publish((0.2, 0.0, 0.0))
    assert [m.seq for m in read_record(record)] == [0, 0]


def test_unwritable_record_is_one_line_naming_the_file(tmp_path: Path) -> None:
    record = tmp_path / "missing-dir" / "rec.jsonl"
    with pytest.raises(InputError) as info, isolated_recording(record):
        pass
    assert str(info.value).startswith(str(record))
    assert "\n" not in str(info.value)


def test_publishing_needs_an_open_publisher() -> None:
    pub = isolated()
    with pytest.raises(LegwsError, match="not open"):
        pub.publish((0.0, 0.0, 0.0))
    with pub:
        pub.publish((0.0, 0.0, 0.0))
    with pytest.raises(LegwsError, match="not open"):
        pub.publish((0.0, 0.0, 0.0))


def test_bad_source_label_is_refused() -> None:
    config = config_from_spec(TransportSpec(listen=[]))
    with pytest.raises(InputError, match="source"):
        Publisher(config, KEY, source="")
    with pytest.raises(InputError, match="source"):
        Publisher(config, KEY, source="x" * 65)


def test_nobody_subscribed_is_reported() -> None:
    with isolated() as pub:
        assert pub.matched() is False
        assert pub.wait_matched(0.05) is False


def test_run_publishes_at_the_rate_for_the_duration_then_zero(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    calls = 0

    def sample() -> Sample:
        nonlocal calls
        calls += 1
        return (0.0, 0.3, 0.0), Buttons()

    with isolated_recording(record) as pub:
        start = time.monotonic()
        published = pub.run(sample, rate=50.0, duration=0.4)
        elapsed = time.monotonic() - start
    messages = read_record(record)
    assert 0.38 <= elapsed < 10.0  # (the upper bound: it ended, not a rate)
    assert published == calls
    assert 8 <= published <= 21  # 20 ticks in 0.4 s at 50 Hz; a busy machine may skip some
    assert len(messages) == published + 1
    assert [m.seq for m in messages] == list(range(published + 1))
    assert all(m.axes == (0.0, 0.3, 0.0) for m in messages[:-1])
    assert messages[-1].axes == (0.0, 0.0, 0.0)
    assert messages[-1].buttons == Buttons(enable=False)  # the goodbye
    assert messages[-1].bye and not any(m.bye for m in messages[:-1])
    assert len({m.session for m in messages}) == 1 and messages[0].session is not None
    stamps = [m.stamp for m in messages]
    assert stamps == sorted(stamps)


def test_run_publishes_nothing_for_none_but_the_final_zero(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    with isolated_recording(record) as pub:
        assert pub.run(lambda: None, rate=100.0, duration=0.1) == 0
    assert [m.axes for m in read_record(record)] == [(0.0, 0.0, 0.0)]


def test_run_stops_promptly_on_the_stop_event(tmp_path: Path) -> None:
    record = tmp_path / "rec.jsonl"
    stop = threading.Event()
    calls = 0

    def sample() -> Sample:
        nonlocal calls
        calls += 1
        if calls == 3:
            stop.set()
        return (0.5, 0.0, 0.0), Buttons()

    with isolated_recording(record) as pub:
        start = time.monotonic()
        assert pub.run(sample, rate=5.0, stop_event=stop) == 3
        assert time.monotonic() - start < 1.5  # two periods (0.4 s) plus slack, not forever
    assert [m.axes for m in read_record(record)] == [(0.5, 0.0, 0.0)] * 3 + [(0.0, 0.0, 0.0)]


def test_run_stopped_from_another_thread() -> None:
    stop = threading.Event()
    with isolated() as pub:
        timer = threading.Timer(0.2, stop.set)
        timer.start()
        start = time.monotonic()
        pub.run(lambda: ((0.0, 0.0, 0.1), Buttons()), rate=2.0, stop_event=stop)
        assert time.monotonic() - start < 1.0  # the 0.5 s wait is cut short
        timer.join(1.0)


@pytest.mark.parametrize(
    ("rate", "duration", "field"),
    [(0.0, 1.0, "rate"), (math.inf, 1.0, "rate"), (2000.0, 1.0, "rate"), (10.0, 0.0, "duration")],
)
def test_run_rejects_bad_rate_or_duration(
    tmp_path: Path, rate: float, duration: float, field: str
) -> None:
    record = tmp_path / "rec.jsonl"
    with isolated_recording(record) as pub, pytest.raises(InputError, match=field):
        pub.run(lambda: None, rate=rate, duration=duration)
    assert record.read_text() == ""


def _interrupt_and_wait() -> None:
    """SIGINT to this process; the handler runs (and may raise) during the sleep."""
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(1.0)


def test_signals_set_the_stop_event_and_handlers_are_restored() -> None:
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with stop_on_signals() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.wait(2.0)
    assert {s: signal.getsignal(s) for s in before} == before
    with stop_on_signals() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.wait(2.0)
        with pytest.raises(KeyboardInterrupt):  # a second Ctrl-C is not swallowed
            _interrupt_and_wait()
    assert {s: signal.getsignal(s) for s in before} == before


def test_signal_helper_outside_the_main_thread_only_yields_the_event() -> None:
    seen: list[bool] = []

    def body() -> None:
        with stop_on_signals() as stop:
            seen.append(stop.is_set())

    before = signal.getsignal(signal.SIGTERM)
    thread = threading.Thread(target=body)
    thread.start()
    thread.join(5.0)
    assert seen == [False]
    assert signal.getsignal(signal.SIGTERM) is before
