"""Keyboard joystick: the pure key -> deflection state, and the terminal on a pseudo-terminal."""

from __future__ import annotations

import io
import math
import os
import pty
import termios
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons, JoystickMessage, parse
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.joystick.keyboard import (
    HELP,
    KeyboardState,
    RawTerminal,
    keys_of,
    run_keyboard,
    status_line,
    stdin_terminal_fd,
)
from legws_daemon.joystick.publisher import Publisher
from legws_daemon.transport.session import config_from_spec
from tests.joystick.helpers import KEY


@pytest.mark.parametrize(
    ("key", "axes"),
    [
        ("w", (1.0, 0.0, 0.0)),
        ("s", (-1.0, 0.0, 0.0)),
        ("a", (0.0, 1.0, 0.0)),
        ("d", (0.0, -1.0, 0.0)),
        ("r", (0.0, 0.0, 1.0)),
        ("f", (0.0, 0.0, -1.0)),
        ("W", (1.0, 0.0, 0.0)),
    ],
)
def test_each_key_sets_its_axis(key: str, axes: tuple[float, float, float]) -> None:
    state = KeyboardState()
    assert state.press(key, 10.0)
    assert state.axes(10.1) == axes


def test_deflection_decays_after_the_hold_time_unless_repeated() -> None:
    state = KeyboardState(step=0.5, hold=0.3)
    state.press("w", 0.0)
    assert state.axes(0.29) == (0.5, 0.0, 0.0)
    assert state.axes(0.31) == (0.0, 0.0, 0.0)
    for t in (0.0, 0.2, 0.4, 0.6):  # key repeat keeps it alive
        state.press("w", t)
        assert state.axes(t + 0.25) == (0.5, 0.0, 0.0)
    assert state.axes(0.95) == (0.0, 0.0, 0.0)


def test_axes_are_independent_and_the_opposite_key_flips_the_sign() -> None:
    state = KeyboardState(step=0.5)
    state.press("w", 0.0)
    state.press("d", 0.2)
    assert state.axes(0.25) == (0.5, -0.5, 0.0)
    assert state.axes(0.4) == (0.0, -0.5, 0.0)  # x expired, y still held
    state.press("s", 0.45)
    assert state.axes(0.46) == (-0.5, -0.5, 0.0)


def test_several_full_axes_are_scaled_to_norm_one() -> None:
    state = KeyboardState(step=1.0)
    for key in "wdr":
        state.press(key, 1.0)
    x, y, z = state.axes(1.0)
    assert math.sqrt(x * x + y * y + z * z) == pytest.approx(1.0)
    assert x == pytest.approx(-y) == pytest.approx(z) == pytest.approx(1 / math.sqrt(3))


def test_space_zeroes_everything_at_once() -> None:
    state = KeyboardState()
    state.press("w", 0.0)
    state.press("r", 0.0)
    assert state.press(" ", 0.1)
    assert state.axes(0.1) == (0.0, 0.0, 0.0)
    state.press("a", 0.2)
    assert state.axes(0.2) == (0.0, 1.0, 0.0)


def test_cancel_is_sent_in_exactly_one_sample() -> None:
    state = KeyboardState()
    state.press("c", 0.0)
    state.press("w", 0.0)
    first = state.sample(0.05)
    assert first == ((1.0, 0.0, 0.0), Buttons(cancel=True, enable=True))
    assert state.sample(0.1) == ((1.0, 0.0, 0.0), Buttons(enable=True))


@pytest.mark.parametrize("enter", ["\r", "\n"])
def test_enter_confirms_in_exactly_one_sample_and_enabled(enter: str) -> None:
    state = KeyboardState()
    assert state.press(enter, 0.0)
    assert state.sample(5.0) == ((0.0, 0.0, 0.0), Buttons(confirm=True, enable=True))
    assert state.sample(5.1) == ((0.0, 0.0, 0.0), Buttons(enable=False))


def test_hold_to_run_enable_lasts_the_hold_time_after_a_steering_key_or_space() -> None:
    state = KeyboardState(hold=0.3)
    assert not state.sample(0.0)[1].enable  # nothing pressed yet: no input for the daemon
    state.press("w", 1.0)
    assert state.sample(1.2) == ((1.0, 0.0, 0.0), Buttons(enable=True))
    assert state.sample(1.31) == ((0.0, 0.0, 0.0), Buttons(enable=False))  # let go
    for t in (2.0, 2.03, 2.06):  # space held: auto-repeat keeps the assistance running
        state.press(" ", t)
        assert state.sample(t + 0.02) == ((0.0, 0.0, 0.0), Buttons(enable=True))
    assert not state.sample(2.4)[1].enable


def test_without_hold_to_run_every_message_is_enabled() -> None:
    state = KeyboardState(hold_to_run=False)
    assert state.sample(0.0)[1].enable is None  # no enable button: every message is input
    state.press("w", 1.0)
    assert state.sample(9.0) == ((0.0, 0.0, 0.0), Buttons())


def test_quit_keys_and_unknown_keys() -> None:
    state = KeyboardState()
    assert not state.press("x", 0.0)
    assert not state.press("\t", 0.0)
    assert not state.quit
    assert state.axes(0.0) == (0.0, 0.0, 0.0)
    assert state.press("q", 0.0)
    assert state.quit
    ctrl_c = KeyboardState()
    ctrl_c.press("\x03", 0.0)
    assert ctrl_c.quit


def test_a_press_in_the_future_does_not_count_yet() -> None:
    state = KeyboardState()
    state.press("w", 5.0)
    assert state.axes(4.0) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    ("step", "hold", "field"),
    [(0.0, 0.3, "step"), (1.5, 0.3, "step"), (math.nan, 0.3, "step"), (0.5, 0.0, "hold")],
)
def test_bad_settings_are_refused(step: float, hold: float, field: str) -> None:
    with pytest.raises(InputError, match=field):
        KeyboardState(step=step, hold=hold)


@given(
    st.lists(
        st.tuples(st.sampled_from(list("wsadrf c")), st.floats(0.0, 0.1)), min_size=0, max_size=40
    ),
    st.floats(0.0, 1.0),
)
def test_every_sample_is_a_valid_message(presses: list[tuple[str, float]], later: float) -> None:
    state = KeyboardState(step=1.0)
    now = 0.0
    for key, dt in presses:
        now += dt
        state.press(key, now)
    axes, buttons = state.sample(now + later)
    JoystickMessage.model_validate(
        {"schema": 1, "seq": 0, "stamp": 0.0, "axes": list(axes), "buttons": buttons.model_dump()}
    )


def test_escape_sequences_are_not_read_as_letters() -> None:
    assert keys_of("w\x1b[A\x1b[Bs") == ["w", "s"]  # arrow keys carry "A" and "B"
    assert keys_of("\x1bOPa\x1b[15~d") == ["a", "d"]  # F1, F5
    assert keys_of("\x1bq") == []  # Alt+q is not q
    assert keys_of("wr f") == ["w", "r", " ", "f"]


def test_status_line_shows_the_deflection() -> None:
    assert status_line((0.5, -0.25, 0.0), Buttons()) == "x +0.50  y -0.25  z +0.00  run "
    assert status_line((0.0, 0.0, 0.0), Buttons(enable=False)).endswith("hold")
    assert status_line((0.0, 0.0, 0.0), Buttons(confirm=True)).endswith("confirm")
    assert status_line((0.0, 0.0, 0.0), Buttons(cancel=True)).endswith("cancel")


def test_no_terminal_is_a_one_line_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    plain = tmp_path / "in.txt"
    plain.write_text("w")
    with plain.open() as handle:
        monkeypatch.setattr("sys.stdin", handle)
        with pytest.raises(InputError, match="not a terminal") as info:
            stdin_terminal_fd()
    assert "\n" not in str(info.value)
    monkeypatch.setattr("sys.stdin", io.StringIO("w"))  # no file descriptor at all
    with pytest.raises(InputError, match="not a terminal"):
        stdin_terminal_fd()
    with plain.open() as handle, pytest.raises(InputError, match="not a terminal"):
        RawTerminal(handle.fileno())


@pytest.fixture
def pseudo_terminal() -> Iterator[tuple[int, int]]:
    """(master, slave) of a fresh pseudo-terminal; both closed afterwards."""
    master, slave = pty.openpty()
    try:
        yield master, slave
    finally:
        os.close(master)
        os.close(slave)


def test_raw_terminal_reads_keys_and_restores_the_mode(pseudo_terminal: tuple[int, int]) -> None:
    master, slave = pseudo_terminal
    before = termios.tcgetattr(slave)
    assert before[3] & termios.ICANON
    with RawTerminal(slave) as terminal:
        during = termios.tcgetattr(slave)
        assert not during[3] & termios.ICANON
        assert not during[3] & termios.ECHO
        assert during[3] & termios.ISIG  # Ctrl-C stays a signal
        assert terminal.read() == ""
        os.write(master, b"wd")
        deadline = time.monotonic() + 5.0
        text = ""
        while len(text) < 2 and time.monotonic() < deadline:
            text += terminal.read()
            time.sleep(0.01)
        assert text == "wd"  # no line buffering: no Enter needed
    assert termios.tcgetattr(slave) == before


def test_raw_terminal_is_restored_after_an_error(pseudo_terminal: tuple[int, int]) -> None:
    _, slave = pseudo_terminal
    before = termios.tcgetattr(slave)
    with pytest.raises(RuntimeError, match="boom"), RawTerminal(slave):
        raise RuntimeError("boom")
    assert termios.tcgetattr(slave) == before


def test_keyboard_loop_publishes_keys_until_q(
    tmp_path: Path, pseudo_terminal: tuple[int, int]
) -> None:
    master, slave = pseudo_terminal
    record = tmp_path / "rec.jsonl"
    config = config_from_spec(TransportSpec(listen=[]))
    out = io.StringIO()
    timer = threading.Timer(0.5, os.write, args=(master, b"q"))
    with Publisher(config, KEY, source="kb", record=record) as pub, RawTerminal(slave) as term:
        os.write(master, b"wc")
        timer.start()
        start = time.monotonic()
        published = run_keyboard(
            pub, term, KeyboardState(step=0.5, hold=10.0), rate=50.0, duration=5.0, out=out
        )
        assert time.monotonic() - start < 3.0  # ended by q, not by the duration
        timer.join(1.0)
    lines = record.read_text().splitlines()
    messages = [parse(JoystickMessage, line, "rec") for line in lines]
    assert len(messages) == published + 1
    assert published >= 3
    assert messages[0].axes == (0.5, 0.0, 0.0)
    assert [m.buttons.cancel for m in messages].count(True) == 1
    assert all(m.axes == (0.5, 0.0, 0.0) for m in messages[:-1])
    assert messages[-1].axes == (0.0, 0.0, 0.0)
    shown = out.getvalue()
    assert shown.startswith(HELP + "\n")
    assert "\rx +0.50  y +0.00  z +0.00" in shown
    assert shown.endswith("\n")
