"""Placement guidance: what is off its outline, in words; unseen objects; when to say it."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.autonomy.events import Misplaced, Placed
from legws_daemon.autonomy.layouts import REMIND_EVERY, LayoutBook
from legws_daemon.autonomy.placing import (
    POSITION_TOLERANCE,
    STALE_AFTER,
    PlacementReport,
    correction_text,
    judge,
    verdict,
    wrap,
)
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose
from tests.autonomy.rig import Rig, stand_in_profile


@given(st.floats(-50, 50), st.sampled_from([1, 2, 4, 6]))
def test_wrap_gives_the_smallest_equivalent_turn(angle: float, symmetry: int) -> None:
    period = 2 * math.pi / symmetry
    a = wrap(angle, symmetry)
    assert -period / 2 - 1e-9 <= a <= period / 2 + 1e-9
    turns = (angle - a) / period
    assert turns == pytest.approx(round(turns), abs=1e-6)


def test_a_round_object_never_needs_a_turn() -> None:
    assert wrap(2.0, 0) == 0.0
    placed = judge("cup", ObjectPose(0.5, 0.2, 0.0), ObjectPose(0.5, 0.2, 2.5), 0, 0.1)
    assert placed.state == "placed"


def test_the_correction_reads_as_a_person_moves_it() -> None:
    # the object stands 4 cm to the robot's right of its outline and turned 20° clockwise
    planned, measured = ObjectPose(0.6, 0.10, 0.0), ObjectPose(0.6, 0.06, -math.radians(20))
    o = judge("cup_box", planned, measured, 2, 0.05)
    assert o.state == "misplaced"
    assert o.text == "cup_box: 4 cm left, turn 20° anticlockwise"
    assert o.move == pytest.approx({"x": 0.0, "y": 0.04, "yaw": math.radians(20)})
    assert correction_text("tea", -0.12, 0.0, 0.0) == "tea: 12 cm towards the robot"
    assert (
        correction_text("tea", 0.013, -0.007, 0.0)
        == "tea: 0.7 cm right, 1.3 cm away from the robot"
    )


def test_within_the_tolerances_an_object_is_placed() -> None:
    planned = ObjectPose(0.6, 0.1, 0.3)
    near = ObjectPose(0.6 + 0.7 * POSITION_TOLERANCE, 0.1, 0.3 + math.radians(4))
    assert judge("a", planned, near, 2, 0.0).state == "placed"
    # half a turn of a two-fold box is the same footprint
    assert judge("a", planned, ObjectPose(0.6, 0.1, 0.3 + math.pi), 2, 0.0).state == "placed"
    assert judge("a", planned, ObjectPose(0.6, 0.1, 0.3 + math.pi), 1, 0.0).state == "misplaced"


def _book() -> LayoutBook:
    return LayoutBook({"a": ObjectPose(0.6, 0.2, 0.0), "b": ObjectPose(0.6, -0.2, 0.0)})


SHOULD = {"a": ObjectPose(0.6, 0.2, 0.0), "b": ObjectPose(0.6, -0.2, 0.0)}
KNOWN = ("a", "b", "fixed")


def test_an_unseen_object_is_reported_unseen_and_never_moved() -> None:
    book = _book()
    assert not book.tracking
    book.observe({"a": ObjectPose(0.62, 0.2, 0.0)}, ["b"], KNOWN, ("a", "b"), now=0.0)
    assert book.layout["b"] == SHOULD["b"]  # unseen: where it was
    states = {o.name: o.state for o in book.placements(0.1, SHOULD, {})}
    assert states == {"a": "misplaced", "b": "unseen"}
    # later the tracker sees b, then loses it again: b keeps its last measured pose
    book.observe({"b": ObjectPose(0.6, -0.25, 0.0)}, [], KNOWN, ("a", "b"), now=0.2)
    book.observe({"a": ObjectPose(0.6, 0.2, 0.0)}, ["b"], KNOWN, ("a", "b"), now=0.3)
    assert book.layout["b"] == ObjectPose(0.6, -0.25, 0.0)
    (b,) = [o for o in book.placements(0.3, SHOULD, {}) if o.name == "b"]
    assert b.state == "unseen"
    assert b.age == pytest.approx(0.1)


def test_a_tracker_that_goes_quiet_leaves_every_object_unseen() -> None:
    book = _book()
    book.observe({"a": SHOULD["a"], "b": SHOULD["b"]}, [], KNOWN, ("a", "b"), now=0.0)
    assert {o.state for o in book.placements(STALE_AFTER, SHOULD, {})} == {"placed"}
    later = book.placements(STALE_AFTER + 0.01, SHOULD, {})
    assert {o.state for o in later} == {"unseen"}
    assert book.layout == SHOULD  # their poses stay


def test_reports_of_unknown_objects_are_ignored() -> None:
    book = _book()
    assert not book.observe({"ghost": SHOULD["a"]}, ["phantom"], KNOWN, ("a", "b"), now=0.0)
    assert not book.tracking
    # a fixed object is judged, but never moves what inference uses
    assert book.observe({"fixed": ObjectPose(0.4, 0.0, 0.0)}, [], KNOWN, ("a", "b"), now=0.0)
    assert "fixed" not in book.layout


def _report(
    certified: bool, misplaced: bool, unseen: bool = False, j: float | None = None
) -> PlacementReport:
    objects = [
        judge("a", SHOULD["a"], ObjectPose(0.6, 0.25, 0.0) if misplaced else SHOULD["a"], 1, 0.0)
    ]
    if unseen:
        objects.append(judge("b", SHOULD["b"], None, 1, None))
    j = (1.0 if certified else -0.5) if j is None else j
    return PlacementReport("pick", tuple(objects), j, 1.2, None, None, certified)


def test_the_warning_comes_when_something_changes_and_as_a_reminder() -> None:
    book = _book()
    book.observe({"a": ObjectPose(0.6, 0.25, 0.0)}, [], KNOWN, ("a", "b"), now=0.0)
    cert = lambda layout: 1.0 if layout["a"] == SHOULD["a"] else -0.5  # noqa: E731
    first = book.guide(_report(False, True), 1, 0.0, cert)
    assert isinstance(first, Misplaced)
    assert first.move == "a"
    assert first.corrections == ("a: 5 cm right",)
    assert book.guide(_report(False, True), 1, 1.0, cert) is None  # nothing new
    again = book.guide(_report(False, True, unseen=True), 1, 2.0, cert)  # b lost
    assert isinstance(again, Misplaced)
    assert again.unseen == ("b",)
    assert "b: unseen" in again.text()
    assert book.guide(_report(False, True, unseen=True), 1, 2.0 + REMIND_EVERY, cert) is not None
    placed = book.guide(_report(True, False), 1, 30.0, cert)
    assert isinstance(placed, Placed)
    assert book.guide(_report(True, False), 1, 31.0, cert) is None  # said once
    # certified without a warning before: nothing to say; all in place yet uncertified: neither
    assert _book().guide(_report(True, False), 1, 0.0, cert) is None
    assert _book().guide(_report(False, False), 1, 0.0, cert) is None


def test_a_misplaced_object_is_warned_about_whatever_j_says() -> None:
    book = _book()
    book.observe({"a": ObjectPose(0.6, 0.25, 0.0)}, [], KNOWN, ("a", "b"), now=0.0)
    cert = lambda layout: 1.2 if layout["a"] == SHOULD["a"] else 1.0  # noqa: E731
    warning = book.guide(_report(True, True), 1, 0.0, cert)  # J = +1.0: certified all the same
    assert isinstance(warning, Misplaced)
    assert warning.certified is True and warning.certificate == 1.0
    assert warning.corrections == ("a: 5 cm right",)
    assert warning.move == "a"  # moving it back gains 0.2
    assert warning.detail()["certified"] is True
    text = warning.text()
    assert "NOT certified" not in text
    assert text == (
        "warning placement of pick off the plan, certified all the same (J +1.00, planned "
        "+1.20): a: 5 cm right"
    )
    assert book.guide(_report(True, True), 1, 1.0, cert) is None  # nothing new
    # J turns negative with the same object off: the verdict changed, said at once
    lost = book.guide(_report(False, True), 1, 2.0, cert)
    assert isinstance(lost, Misplaced) and lost.certified is False
    assert "NOT certified (J -0.50" in lost.text()
    # put back: certified and nothing off, after a warning
    assert isinstance(book.guide(_report(True, False), 1, 3.0, cert), Placed)


def test_the_verdict_follows_the_sign_of_j() -> None:
    assert verdict(-0.1, False, False) == "NOT certified"
    assert verdict(0.0, False, True) == "NOT certified"
    # J > 0 but a candidate unseen (a tracker that stopped): not "NOT certified"
    assert verdict(3.23, False, False) == "unconfirmed, a candidate unseen"
    assert verdict(3.23, True, False) == "certified"
    assert verdict(0.05, True, True) == "off the plan, certified all the same"
    book = _book()
    book.observe({"a": SHOULD["a"]}, ["b"], KNOWN, ("a", "b"), now=0.0)
    quiet = book.guide(_report(False, False, unseen=True, j=3.23), 1, 0.0, lambda _: 3.23)
    assert isinstance(quiet, Misplaced)
    assert quiet.text() == (
        "warning placement of pick unconfirmed, a candidate unseen (J +3.23, planned +1.20): "
        "b: unseen"
    )


def test_the_report_reads_as_an_operator_wants_it() -> None:
    r = _report(False, True, unseen=True)
    assert r.lines() == ["placement NOT certified: J -0.50", "a: 5 cm right", "b: unseen"]
    status = r.status()
    assert status["certified"] is False
    assert status["objects"]["a"]["state"] == "misplaced"
    assert status["objects"]["b"] == {"state": "unseen", "text": "b: unseen"}
    assert status["misplaced"] == ["a"]
    assert _report(True, True).lines() == [
        "placement off the plan, certified all the same: J +1.00",
        "a: 5 cm right",
    ]
    assert _report(True, False).status()["misplaced"] == []


# --- the controller: judged against the planned layout while the decision is open ---------
@pytest.fixture
def desk() -> Iterator[Rig]:
    r = Rig(stand_in_profile(), load_scene("desk"))
    yield r
    r.c.shutdown()


def test_a_misplaced_object_is_warned_about_while_the_decision_is_open(desk: Rig) -> None:
    c = desk.c
    mug = c.planned_layout["white_mug"]
    assert c.layout_status() == {
        "scene": "desk",
        "objects": {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in c.planned_layout.items()},
    }
    # 3 cm away from the robot: the goals stay well apart (J > 0), yet it is not the plan
    c.observe({"white_mug": ObjectPose(mug.x + 0.03, mug.y, mug.yaw)})
    kind, detail = desk.events[-1]
    assert kind == "warning"
    assert detail["corrections"] == ["white_mug: 3 cm towards the robot"]
    assert detail["certified"] is True and detail["certificate"] > 0
    assert "NOT certified" not in desk.typed[-1].text()
    report = c.placement
    assert report is not None and report.certified is True
    assert report.status()["misplaced"] == ["white_mug"]
    # decided: the robot moves objects now; no guidance until the next decision
    desk.drive_to_commit("black_stapler")
    assert c.committed is not None
    n = len(desk.events)
    c.observe({"white_mug": ObjectPose(mug.x + 0.08, mug.y, mug.yaw)})
    assert c.placement is not None and c.placement.status()["misplaced"] == ["white_mug"]
    assert len(desk.events) == n


def test_an_object_the_task_picked_is_not_judged(desk: Rig) -> None:
    c = desk.c
    mug = c.planned_layout["white_mug"]
    c.observe({"white_mug": ObjectPose(mug.x, mug.y + 0.2, mug.yaw)})
    assert c.placement is not None and c.placement.status()["misplaced"] == ["white_mug"]
    c.task.consumed.add("white_mug")  # picked: where the robot put it, not the plan's
    report = c.check_placement()
    assert report is not None
    assert "white_mug" not in {o.name for o in report.objects}
