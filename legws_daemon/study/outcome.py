"""What one trial measured: the trial table's measured columns.

:class:`Outcome` is filled by the simulator (:mod:`.simulate`, from the controller's events
in simulated time) and, for a person, by :class:`TrialWatch` from the daemon's events and
status messages (docs/messages.md) as they arrive: times from the daemon's ``started``
event (the trial's start: the arm at home, the participant told to go) on the daemon's
clock, the commit's own control-time fields, the gripper from the status stream (10 Hz: a
grasp time is known to a status period).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class Outcome:
    """What one trial measured (the trial table's measured columns)."""

    chosen: list[str] = field(default_factory=list)
    commit_times: list[float] = field(default_factory=list)
    wrong: int = 0
    confirms: int = 0
    cancels: int = 0
    overrides: int = 0
    time_to_grasp_s: float | None = None
    time_to_task_s: float | None = None
    effort_s: float = 0.0
    completed: bool = False
    failure: str = ""

    def columns(self, targets: tuple[str, ...]) -> dict[str, Any]:
        return {
            "chosen": ";".join(self.chosen),
            "commit_time_s": float(np.mean(self.commit_times)) if self.commit_times else None,
            "correct": self.wrong == 0 and list(self.chosen) == list(targets),
            "wrong": self.wrong,
            "confirms": self.confirms,
            "cancels": self.cancels,
            "overrides": self.overrides,
            "time_to_grasp_s": self.time_to_grasp_s,
            "time_to_task_s": self.time_to_task_s,
            "effort_s": self.effort_s,
            "completed": self.completed,
            "failure": self.failure,
        }


class TrialWatch:
    """A person's trial, from the daemon's messages.

    Args:
        targets: the objects the participant is asked for, one per choice, in order.

    Feed it every event (:meth:`event`) and status (:meth:`status`) of the trial's daemon;
    :attr:`over` says when the trial has ended (the task done, a fault, the daemon's
    shutdown); :attr:`outcome` is what it measured.
    """

    def __init__(self, targets: tuple[str, ...]) -> None:
        self.targets = targets
        self.outcome = Outcome()
        self.started: float | None = None  # the started event's stamp
        self.hesitation_s: float | None = None
        self.notes: list[str] = []  # assistance warnings: control went back to the person
        self.over = False
        self._choice = 0

    def _since(self, stamp: float) -> float | None:
        return None if self.started is None else max(0.0, stamp - self.started)

    def event(self, kind: str, detail: dict[str, Any], stamp: float) -> None:
        """One event (``kind``, ``detail``, the daemon's ``stamp``)."""
        out = self.outcome
        if kind == "started":
            self.begin(stamp)
        elif kind == "commit":
            if detail.get("single"):
                return
            goal = str(detail.get("goal", ""))
            out.chosen.append(goal)
            asked = self.targets[self._choice] if self._choice < len(self.targets) else None
            self._choice += 1
            if goal != asked:
                out.wrong += 1
            if detail.get("confirmed"):
                out.confirms += 1
            elif isinstance(detail.get("seconds"), int | float):
                out.commit_times.append(float(detail["seconds"]))
            if self.hesitation_s is None and isinstance(detail.get("waited"), int | float):
                self.hesitation_s = float(detail["waited"])
        elif kind == "cancel":
            out.cancels += 1
        elif kind == "override":
            out.overrides += 1
        elif kind == "task_done":
            out.completed, out.time_to_task_s = True, self._since(stamp)
            self.over = True
        elif kind == "fault":
            out.failure = f"fault: {detail.get('error', '')}"
            self.over = True
        elif kind == "warning" and "assist" in detail:
            self.notes.append(f"assist_failed: {detail.get('phase')}: {detail.get('error')}")
        elif kind == "shutdown":
            if not out.completed and not out.failure:
                out.failure = "the daemon shut down before the task was done"
            self.over = True

    def begin(self, started: float) -> None:
        """The trial's daemon started at ``started`` (its clock): the ``started`` event, or
        the ``started`` field of its first status — the event is published before a client
        that was connected to the previous trial's daemon has reconnected, so it may never
        arrive; the status stream repeats it."""
        if self.started is None:
            self.started = started

    def status(self, gripper_closed: bool, stamp: float) -> None:
        """One status message's gripper state and stamp."""
        if gripper_closed and self.outcome.time_to_grasp_s is None and self.started is not None:
            self.outcome.time_to_grasp_s = self._since(stamp)

    def give_up(self, why: str) -> None:
        """End the trial from outside (its time limit): ``why`` is the failure."""
        if not self.outcome.completed and not self.outcome.failure:
            self.outcome.failure = why
        self.over = True
