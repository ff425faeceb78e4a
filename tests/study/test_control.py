"""The state a session and its page share: Start, Pause/Resume and a questionnaire's answers,
across threads."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from legws_daemon.errors import InputError
from legws_daemon.study.answers import check_answers
from legws_daemon.study.control import PHASES, Control
from tests.study.person import ANSWERS, Q


@pytest.fixture
def control() -> Control:
    return Control(Q, clock=lambda: 0.0)


@pytest.fixture
def later() -> Iterator[Callable[[float, Callable[[], Any]], None]]:
    """Run a call from another thread after a delay; every thread is joined at the end."""
    timers: list[threading.Timer] = []

    def schedule(delay: float, call: Callable[[], Any]) -> None:
        timer = threading.Timer(delay, call)
        timer.start()
        timers.append(timer)

    yield schedule
    for timer in timers:
        timer.join(5.0)


def test_it_starts_in_the_starting_phase_unpaused(control: Control) -> None:
    view = control.view()
    assert view["phase"] == "starting" and view["paused"] is False
    assert view["version"] == 0 and not control.pause_requested


def test_start_while_paused_is_refused_and_taken_after_resume(control: Control) -> None:
    control.pause()
    with pytest.raises(InputError, match="resume it first") as info:
        control.start()
    assert info.value.field == "start"
    assert not control.wait_start(0.05)
    control.resume()
    control.start()
    assert control.wait_start(0.05)


def test_wait_start_returns_once_start_is_pressed_from_another_thread(
    control: Control, later: Callable[[float, Callable[[], Any]], None]
) -> None:
    assert not control.wait_start(0.02)  # nothing pressed: it times out
    later(0.1, control.start)
    began = time.monotonic()
    assert control.wait_start(5.0)
    assert time.monotonic() - began < 4.0  # woken, not timed out
    assert not control.wait_start(0.02)  # a press is taken once


def test_pause_clears_a_pending_start(control: Control) -> None:
    control.start()
    control.pause()
    control.resume()
    assert not control.wait_start(0.05)


def test_wait_resume_waits_while_paused_and_returns_on_resume(
    control: Control, later: Callable[[float, Callable[[], Any]], None]
) -> None:
    assert control.wait_resume(0.0)  # not paused: at once
    control.pause()
    assert control.pause_requested
    assert not control.wait_resume(0.05)
    later(0.1, control.resume)
    assert control.wait_resume(5.0)
    assert not control.pause_requested


def test_answers_without_a_questionnaire_open_are_refused(control: Control) -> None:
    with pytest.raises(InputError, match="no questionnaire is open") as info:
        control.submit(ANSWERS)
    assert info.value.field == "answers"
    assert control.wait_answers(0.02) is None


def test_invalid_answers_are_refused_and_nothing_is_kept(control: Control) -> None:
    control.ask()
    with pytest.raises(InputError) as info:
        control.submit({**ANSWERS, "likert_1": 9})
    assert info.value.field == "likert_1"
    assert control.wait_answers(0.05) is None
    # the questionnaire is still open: valid answers are taken after a refusal
    assert control.submit(ANSWERS) == check_answers(Q, ANSWERS, "x")
    assert control.wait_answers(0.05) == check_answers(Q, ANSWERS, "x")


def test_valid_answers_wake_wait_answers_and_close_the_questionnaire(control: Control) -> None:
    control.ask()
    got: list[dict[str, Any] | None] = []
    waiter = threading.Thread(target=lambda: got.append(control.wait_answers(5.0)))
    waiter.start()
    time.sleep(0.05)
    began = time.monotonic()
    kept = control.submit(ANSWERS)
    waiter.join(5.0)
    assert not waiter.is_alive() and time.monotonic() - began < 4.0
    assert got == [kept] and kept["tlx_raw"] == pytest.approx(230 / 6)
    with pytest.raises(InputError, match="no questionnaire is open"):
        control.submit(ANSWERS)  # taken: a second submission is refused


def test_ask_forgets_answers_not_taken(control: Control) -> None:
    control.ask()
    control.submit(ANSWERS)
    control.ask()  # the next questionnaire: the earlier answers are not its answers
    assert control.wait_answers(0.02) is None


def test_the_view_has_a_version_that_grows_with_every_change_and_the_paused_flag(
    control: Control,
) -> None:
    versions = [control.view()["version"]]
    control.show(phase="ready", message="Press Start", step=3)
    view = control.view()
    versions.append(view["version"])
    assert view == {"phase": "ready", "message": "Press Start", "step": 3,
                    "version": versions[-1], "paused": False}  # fmt: skip
    control.update(mode="teleop")
    view = control.view()
    versions.append(view["version"])
    assert view["mode"] == "teleop" and view["step"] == 3  # update keeps the rest
    control.pause()
    view = control.view()
    versions.append(view["version"])
    assert view["paused"] is True
    control.resume()
    versions.append(control.view()["version"])
    assert control.view()["paused"] is False
    control.show(phase="running")
    view = control.view()
    versions.append(view["version"])
    assert "step" not in view and "mode" not in view  # show replaces the view
    assert versions == sorted(set(versions)) and len(versions) == 6


def test_view_is_a_copy(control: Control) -> None:
    control.show(phase="done", message="Thank you")
    control.view()["message"] = "changed"
    assert control.view()["message"] == "Thank you"


def test_show_with_an_unknown_phase_fails(control: Control) -> None:
    assert "running" in PHASES
    with pytest.raises(AssertionError):
        control.show(phase="dancing")
    with pytest.raises(AssertionError):
        control.show(message="no phase")
    assert control.view()["phase"] == "starting" and control.view()["version"] == 0


def test_the_session_knows_when_the_page_has_read_its_last_words() -> None:
    c = Control(Q)
    c.show(phase="done", message="The session is complete.")
    assert not c.wait_seen(0.05)  # nobody has looked yet
    done = threading.Event()

    def session() -> None:
        if c.wait_seen(5.0):
            done.set()

    t = threading.Thread(target=session)
    t.start()
    assert c.view()["phase"] == "done"  # the page's poll
    t.join(5.0)
    assert done.is_set()
    c.update(reach=1)
    assert not c.wait_seen(0.05)  # a newer view than the one read
