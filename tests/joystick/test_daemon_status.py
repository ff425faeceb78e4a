"""What a publisher shows of the daemon: the status line, a line per change, the first wait."""

from __future__ import annotations

import io
import time
from typing import Any

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import StatusMessage
from legws_daemon.joystick.daemon_status import (
    StatusLine,
    StatusWatch,
    fit,
    status_text,
    top_goal,
    wait_for_status,
)
from tests.joystick.helpers import status


def message(**fields: Any) -> StatusMessage:
    return StatusMessage.model_validate_json(status(1, **fields))


def test_the_line_says_mode_top_goal_commit_phase_operator_and_deadman() -> None:
    s = message(
        stage="choose_tea", posterior={"green_tea": 0.72, "black_tea": 0.28},
        operator={"source": "keyboard:42", "session": "abc"}, deadman=False,
    )  # fmt: skip
    assert status_text(s, "abc") == (
        "teleop · stage choose_tea · top green_tea 0.72 · commit - · phase - · "
        "operator keyboard:42 (you) · deadman off"
    )
    assert "operator keyboard:42 (not you)" in status_text(s, "other")
    s = message(mode="assist", posterior={"a": 0.9, "b": 0.1}, committed="a", phase="grasp",
                deadman=True)  # fmt: skip
    assert status_text(s) == (
        "assist · top a 0.90 · commit a · phase grasp · operator none · deadman on"
    )
    fault = message(mode="fault", fault="read_state: estop")
    assert "fault read_state: estop" in status_text(fault)
    assert top_goal(message()) is None
    # a tie goes to the first name, whatever the dict's order
    assert top_goal(message(posterior={"b": 0.5, "a": 0.5})) == ("a", 0.5)


class Pipe(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_a_pipe_gets_a_line_per_change_a_terminal_one_line_rewritten() -> None:
    watch = StatusWatch("legws/test_robot/status")
    pipe = StatusLine(watch, Pipe(False), prefix="daemon: ")
    pipe.show()
    assert pipe.stream.getvalue() == ""  # type: ignore[attr-defined]
    for p in (0.6, 0.7, 0.8):  # the probability alone changes: no new line
        watch.offer(status(1, posterior={"a": p, "b": 1 - p}))
        pipe.show()
    watch.offer(status(2, mode="assist", posterior={"a": 0.9, "b": 0.1}, committed="a"))
    pipe.show()
    lines = pipe.stream.getvalue().splitlines()  # type: ignore[attr-defined]
    assert lines == [
        "daemon: teleop · top a 0.60 · commit - · phase - · operator none · deadman off",
        "daemon: assist · top a 0.90 · commit a · phase - · operator none · deadman off",
    ]
    term = StatusLine(watch, Pipe(True))
    watch.offer(status(3, posterior={"a": 0.5, "b": 0.5}))
    term.show()
    watch.offer(status(4, posterior={"a": 0.6, "b": 0.4}))
    term.show()
    term.show()  # unchanged: not written again
    out = term.stream.getvalue()  # type: ignore[attr-defined]
    assert out.count("\r") == 2 and "\n" not in out
    assert out.endswith("top a 0.60 · commit - · phase - · operator none · deadman off\x1b[K")


def test_no_status_within_the_wait_is_one_line_naming_the_key_and_the_endpoints() -> None:
    watch = StatusWatch("legws/test_robot/status")
    started = time.monotonic()
    with pytest.raises(InputError) as err:
        wait_for_status(watch, 0.2, ["tcp/127.0.0.1:7447"])
    assert time.monotonic() - started >= 0.2
    assert str(err.value) == (
        "no status from the daemon on legws/test_robot/status within 0.2 s (dialled "
        "tcp/127.0.0.1:7447): is it running, for this robot, listening there?"
    )
    watch.offer(b"not a status")  # ignored
    assert watch.newest is None
    watch.offer(status(1))
    assert wait_for_status(watch, 0.2, []).seq == 1


def test_a_terminal_line_is_cut_to_the_terminal_width() -> None:
    import fcntl
    import os
    import pty
    import struct
    import termios

    master, slave = pty.openpty()
    try:
        with os.fdopen(slave, "w", closefd=False) as tty:
            assert fit("x" * 300, tty) == "x" * 300  # unsized: the whole line
            fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
            assert fit("x" * 300, tty) == "x" * 78 + "…"
            assert fit("short", tty) == "short"
        assert fit("x" * 300, io.StringIO()) == "x" * 300  # not a terminal
    finally:
        os.close(master)
        os.close(slave)


def test_the_line_follows_a_publisher_that_keys_a_fresh_session() -> None:
    # a publisher re-keys when a daemon restarts under it: "(you)" follows its session now
    watch = StatusWatch("legws/test_robot/status")
    mine = ["old"]
    line = StatusLine(watch, Pipe(False), lambda: mine[0])
    watch.offer(status(1, operator={"source": "keyboard:42", "session": "new"}))
    line.show()
    mine[0] = "new"
    watch.offer(status(2, mode="assist", operator={"source": "keyboard:42", "session": "new"}))
    line.show()
    lines = line.stream.getvalue().splitlines()  # type: ignore[attr-defined]
    assert "(not you)" in lines[0] and "(you)" in lines[1] and "(not you)" not in lines[1]
