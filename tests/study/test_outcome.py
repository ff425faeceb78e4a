"""A person's trial measured from the daemon's events and statuses (docs/messages.md)."""

from __future__ import annotations

from typing import Any

import pytest

from legws_daemon.study.outcome import Outcome, TrialWatch

T0 = 1000.0  # the started event's stamp (the daemon's clock)


def commit(goal: str, seconds: float = 1.0, waited: float = 0.5, **more: Any) -> dict[str, Any]:
    """A commit event's detail as the daemon sends it."""
    return {"goal": goal, "p": 0.93, "tick": 120, "seconds": seconds, "waited": waited,
            "stage": "pick", "confirmed": False, "single": False, **more}  # fmt: skip


def started(watch: TrialWatch, stamp: float = T0) -> None:
    watch.event("started", {"adapter": "sim", "scene": "desk", "certificate": 0.2}, stamp)


def test_a_trial_done_gives_its_times_from_the_started_stamp() -> None:
    w = TrialWatch(("mug",))
    w.status(True, T0 - 5.0)  # before started: ignored
    assert w.outcome.time_to_grasp_s is None
    started(w)
    assert w.started == T0 and not w.over
    w.status(False, T0 + 1.0)
    w.event("commit", commit("mug", seconds=2.25, waited=0.75), T0 + 2.3)
    w.status(False, T0 + 3.0)
    w.status(True, T0 + 3.5)  # the first closed gripper: the grasp
    w.status(False, T0 + 4.0)
    w.status(True, T0 + 6.0)  # later closings do not move it
    assert not w.over
    w.event("task_done", {}, T0 + 8.5)
    assert w.over
    assert w.hesitation_s == 0.75
    cols = w.outcome.columns(("mug",))
    assert cols == {
        "chosen": "mug", "commit_time_s": 2.25, "correct": True, "wrong": 0, "confirms": 0,
        "cancels": 0, "overrides": 0, "time_to_grasp_s": 3.5, "time_to_task_s": 8.5,
        "effort_s": 0.0, "completed": True, "failure": "",
    }  # fmt: skip


def test_several_choices_average_their_commit_times_and_hesitation_is_the_first_wait() -> None:
    w = TrialWatch(("green_tea", "mug"))
    started(w)
    w.event("commit", commit("green_tea", seconds=1.0, waited=0.4), T0 + 2.0)
    w.event("commit", commit("mug", seconds=3.0, waited=2.0), T0 + 9.0)
    w.event("task_done", {}, T0 + 15.0)
    cols = w.outcome.columns(w.targets)
    assert cols["chosen"] == "green_tea;mug" and cols["correct"] and cols["wrong"] == 0
    assert cols["commit_time_s"] == pytest.approx(2.0)
    assert w.hesitation_s == 0.4
    assert cols["time_to_task_s"] == 15.0


def test_single_candidate_commits_are_ignored() -> None:
    w = TrialWatch(("bowl", "mug"))
    started(w)
    # a decision of one candidate: no inference, no choice of the person's
    w.event("commit", commit("plate", seconds=0.0, waited=5.0, single=True), T0 + 0.1)
    w.event("commit", commit("bowl", seconds=1.5, waited=0.5), T0 + 3.0)
    w.event("commit", commit("tray", seconds=0.0, waited=0.0, single=True), T0 + 4.0)
    w.event("commit", commit("mug", seconds=2.5, waited=0.1), T0 + 7.0)
    assert w.outcome.chosen == ["bowl", "mug"]
    assert w.outcome.commit_times == [1.5, 2.5]
    assert w.hesitation_s == 0.5  # not the single commit's wait
    assert w.outcome.columns(w.targets)["correct"]


def test_a_wrong_goal_is_counted_and_the_trial_not_correct() -> None:
    w = TrialWatch(("mug", "bowl"))
    started(w)
    w.event("commit", commit("stapler"), T0 + 2.0)
    w.event("commit", commit("bowl"), T0 + 4.0)
    w.event("task_done", {}, T0 + 6.0)
    cols = w.outcome.columns(w.targets)
    assert cols["wrong"] == 1 and cols["correct"] is False
    assert cols["chosen"] == "stapler;bowl" and cols["completed"] is True
    # a commit beyond the asked targets is wrong too
    w.event("commit", commit("mug"), T0 + 7.0)
    assert w.outcome.wrong == 2


def test_the_right_goals_in_the_wrong_order_are_not_correct() -> None:
    w = TrialWatch(("mug", "bowl"))
    started(w)
    w.event("commit", commit("bowl"), T0 + 2.0)
    w.event("commit", commit("mug"), T0 + 4.0)
    assert w.outcome.wrong == 2 and not w.outcome.columns(w.targets)["correct"]


def test_confirmed_commits_count_as_confirms_not_as_commit_times() -> None:
    w = TrialWatch(("mug", "bowl"))
    started(w)
    w.event("commit", commit("mug", seconds=0.8, waited=0.3, confirmed=True), T0 + 1.0)
    w.event("commit", commit("bowl", seconds=2.0, waited=1.0), T0 + 5.0)
    cols = w.outcome.columns(w.targets)
    assert cols["confirms"] == 1 and w.outcome.commit_times == [2.0]
    assert cols["commit_time_s"] == 2.0 and cols["correct"]
    assert w.hesitation_s == 0.3  # a confirmed commit still ends the first wait
    only = TrialWatch(("mug",))
    started(only)
    only.event("commit", commit("mug", confirmed=True), T0 + 1.0)
    assert only.outcome.columns(only.targets)["commit_time_s"] is None


def test_cancels_and_overrides_are_counted() -> None:
    w = TrialWatch(("mug",))
    started(w)
    w.event("commit", commit("bowl"), T0 + 1.0)
    w.event("cancel", {"goal": "bowl"}, T0 + 1.5)
    w.event("override", {"goal": "mug", "during": "blend", "phase": None}, T0 + 2.0)
    w.event("override", {"goal": "mug", "during": "assist", "phase": "reach"}, T0 + 3.0)
    cols = w.outcome.columns(w.targets)
    assert (cols["cancels"], cols["overrides"]) == (1, 2)
    assert not w.over


def test_a_fault_ends_the_trial_as_a_failure() -> None:
    w = TrialWatch(("mug",))
    started(w)
    w.event("fault", {"error": "bridge timeout"}, T0 + 4.0)
    assert w.over
    cols = w.outcome.columns(w.targets)
    assert cols["completed"] is False and cols["failure"] == "fault: bridge timeout"
    assert cols["time_to_task_s"] is None
    w.event("shutdown", {}, T0 + 5.0)  # the daemon then stops: the fault stays the reason
    assert w.outcome.failure == "fault: bridge timeout"


def test_a_shutdown_before_the_task_is_done_is_a_failure_and_after_it_is_not() -> None:
    w = TrialWatch(("mug",))
    started(w)
    w.event("commit", commit("mug"), T0 + 2.0)
    w.event("shutdown", {}, T0 + 3.0)
    assert w.over and not w.outcome.completed
    assert w.outcome.failure == "the daemon shut down before the task was done"
    done = TrialWatch(("mug",))
    started(done)
    done.event("task_done", {}, T0 + 4.0)
    done.event("shutdown", {}, T0 + 5.0)
    assert done.outcome.completed and done.outcome.failure == ""


def test_give_up_ends_a_trial_not_done_and_keeps_a_completed_one() -> None:
    w = TrialWatch(("mug",))
    started(w)
    w.give_up("the time limit of 180 s")
    assert w.over and w.outcome.failure == "the time limit of 180 s"
    assert not w.outcome.completed
    done = TrialWatch(("mug",))
    started(done)
    done.event("task_done", {}, T0 + 4.0)
    done.give_up("the daemon exited (code 0): bye")
    assert done.outcome.completed and done.outcome.failure == ""
    assert done.outcome.time_to_task_s == 4.0
    faulted = TrialWatch(("mug",))
    started(faulted)
    faulted.event("fault", {"error": "e-stop"}, T0 + 1.0)
    faulted.give_up("the time limit")
    assert faulted.outcome.failure == "fault: e-stop"  # the first reason stays


def test_statuses_before_started_are_ignored() -> None:
    w = TrialWatch(("mug",))
    w.status(True, T0 - 1.0)  # the gripper still closed from an earlier trial's process
    w.status(True, T0 - 0.5)
    assert w.outcome.time_to_grasp_s is None
    started(w)
    w.status(True, T0 + 2.0)
    assert w.outcome.time_to_grasp_s == 2.0


def test_a_task_done_without_started_has_no_time() -> None:
    w = TrialWatch(("mug",))
    w.event("task_done", {}, T0)
    assert w.over and w.outcome.completed and w.outcome.time_to_task_s is None


def test_assist_warnings_are_notes_and_other_warnings_nothing() -> None:
    w = TrialWatch(("mug",))
    started(w)
    w.event("warning", {"message": "slow tick"}, T0 + 1.0)
    assert w.notes == []
    w.event("warning", {"assist": "commit", "phase": "grasp", "error": "no IK"}, T0 + 2.0)
    assert w.notes == ["assist_failed: grasp: no IK"]
    assert not w.over and w.outcome.failure == ""  # control went back to the person


def test_unknown_events_change_nothing() -> None:
    w = TrialWatch(("mug",))
    started(w)
    before = Outcome()
    w.event("loaded", {"scene": "desk"}, T0 + 1.0)
    w.event("stage", {"stage": "pick"}, T0 + 1.0)
    assert w.outcome == before and not w.over
