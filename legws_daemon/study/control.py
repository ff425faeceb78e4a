"""What the participant's page and the session share: what to show, and what the person
(or the experimenter beside them) asks for — start, pause, resume, a questionnaire's
answers.

The session (:mod:`.session`) runs in one thread and sets the :attr:`Control.view`; the page
(:mod:`.web`) reads it from its own threads and posts requests. Every method takes the one
lock; the session waits on its condition, so a request wakes it at once, and every wait has
a timeout (the session also watches the robot meanwhile).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from legws_daemon.errors import InputError
from legws_daemon.study.answers import check_answers
from legws_daemon.study.protocol import QuestionnaireSpec

#: The page's phases (``view["phase"]``).
PHASES = (
    "starting", "ready", "calibrating", "preparing", "running", "questionnaire", "break",
    "paused", "done", "failed",
)  # fmt: skip


class Control:
    """The shared state of a session and its page.

    Args:
        questionnaire: the protocol's questionnaire (answers are checked against it).
        clock: monotonic seconds (injected in tests).
    """

    def __init__(
        self, questionnaire: QuestionnaireSpec, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.questionnaire = questionnaire
        self.clock = clock
        self._cond = threading.Condition()
        self._view: dict[str, Any] = {"phase": "starting", "message": "Starting the session"}
        self._version = 0
        self._start = False
        self._pause = False
        self._answers: dict[str, Any] | None = None
        self._asking = False
        self._served = -1  # the newest version the page has read

    # -- the session's side ---------------------------------------------------------------
    def show(self, **view: Any) -> None:
        """Replace what the page shows (its ``phase`` one of :data:`PHASES`)."""
        assert view.get("phase") in PHASES, view.get("phase")
        with self._cond:
            self._view = view
            self._version += 1
            self._cond.notify_all()

    def update(self, **fields: Any) -> None:
        """Change some fields of what the page shows (live progress)."""
        with self._cond:
            self._view = {**self._view, **fields}
            self._version += 1

    def wait_start(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for Start (not while paused); ``True`` once pressed
        (then cleared)."""
        with self._cond:
            if self._cond.wait_for(lambda: self._start and not self._pause, timeout):
                self._start = False
                return True
            return False

    def ask(self) -> None:
        """A questionnaire is on the page: answers are taken from now on."""
        with self._cond:
            self._answers, self._asking = None, True

    def wait_answers(self, timeout: float) -> dict[str, Any] | None:
        """The checked answers once submitted (``None`` after ``timeout`` s)."""
        with self._cond:
            if self._cond.wait_for(lambda: self._answers is not None, timeout):
                answers, self._answers, self._asking = self._answers, None, False
                return answers
            return None

    @property
    def pause_requested(self) -> bool:
        with self._cond:
            return self._pause

    def wait_resume(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for Resume; ``True`` when not paused (any more)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._pause, timeout)

    # -- the page's side ------------------------------------------------------------------
    def view(self) -> dict[str, Any]:
        """What the page shows now, with its version (it changes with every update) and
        whether the session is paused."""
        with self._cond:
            self._served = self._version
            self._cond.notify_all()
            return {**self._view, "version": self._version, "paused": self._pause}

    def wait_seen(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s until the page has read what is shown now (the session's
        last words: done, or why it stopped); ``True`` once it has."""
        with self._cond:
            return self._cond.wait_for(lambda: self._served >= self._version, timeout)

    def start(self) -> None:
        """The participant is ready (Start)."""
        with self._cond:
            if self._pause:
                raise InputError("the session is paused: resume it first", field="start")
            self._start = True
            self._cond.notify_all()

    def pause(self) -> None:
        """Pause: a trial under way is stopped (the robot stops) and run again on resume."""
        with self._cond:
            self._pause, self._start = True, False
            self._version += 1
            self._cond.notify_all()

    def resume(self) -> None:
        with self._cond:
            self._pause = False
            self._version += 1
            self._cond.notify_all()

    def submit(self, data: Any) -> dict[str, Any]:
        """A questionnaire's answers from the page, checked (:func:`.answers.check_answers`).

        Raises:
            InputError: no questionnaire is asked now, or an answer is not valid (one line,
                naming the field).
        """
        with self._cond:
            if not self._asking:
                raise InputError("no questionnaire is open now", field="answers")
            answers = check_answers(self.questionnaire, data, "the questionnaire")
            self._answers = answers
            self._cond.notify_all()
            return answers
