"""The controller on the real MuJoCo stand-in: commit, assistance, deadman, cancel, faults."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from legws_daemon.autonomy.cancel import CANCEL_SECONDS
from legws_daemon.autonomy.decision import CONFIRM_RADIUS
from legws_daemon.errors import HardwareError, InputError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.robot.motion import LIFT_HEIGHT
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose, Scene
from tests.autonomy.rig import Rig, operator_command, stand_in_profile


@pytest.fixture(scope="module")
def profile() -> ProfileSpec:
    return stand_in_profile()


@pytest.fixture(scope="module")
def desk() -> Scene:
    return load_scene("desk")


@pytest.fixture
def rig(profile: ProfileSpec, desk: Scene) -> Iterator[Rig]:
    r = Rig(profile, desk)
    yield r
    r.c.shutdown()


def test_commits_on_the_goal_driven_to_and_picks_it(rig: Rig) -> None:
    goal = "white_mug"
    z0 = rig.adapter.object_poses()[goal][0][2]
    rig.drive_to_commit(goal)
    assert rig.c.mode == "assist"
    kind, detail = rig.events[-1]
    assert kind == "commit"
    assert detail["goal"] == goal
    assert detail["p"] >= 0.9
    assert detail["confirmed"] is False
    for _ in range(1000):
        rig.c.tick(rig.sample([0.0, 0.0, 0.0]))  # hands off, dead-man held
        if rig.c.mode != "assist":
            break
    assert rig.c.mode == "idle"
    assert rig.kinds()[-2:] == ["stage_done", "task_done"]
    assert rig.adapter.held == goal
    # lifted, then carried home, where the next stage's inference would start
    ee = rig.adapter.read_state().ee_position
    np.testing.assert_allclose(ee, rig.c.scene.home.position, atol=0.005)
    obj = rig.adapter.object_poses()[goal][0]
    assert obj[2] - z0 > LIFT_HEIGHT
    assert np.linalg.norm(obj - ee) < 0.06  # in the gripper
    # idle: the robot holds still whatever the stick says
    p = rig.adapter.read_state().ee_position
    rec = rig.c.tick(rig.sample([1.0, 0.0, 0.0]))
    np.testing.assert_array_equal(rec.command, 0.0)
    np.testing.assert_array_equal(rig.adapter.read_state().ee_position, p)


def test_deadman_no_input_moves_nothing_in_teleop_and_pauses_assistance(rig: Rig) -> None:
    q0 = rig.adapter.read_state().q
    for _ in range(10):
        rec = rig.c.tick(None)
        np.testing.assert_array_equal(rec.command, 0.0)
    np.testing.assert_array_equal(rig.adapter.read_state().q, q0)
    rig.drive_to_commit("maroon_pen_cup")
    for _ in range(5):
        rig.c.tick(rig.sample([0.0, 0.0, 0.0]))
    q1 = rig.adapter.read_state().q
    phase = rig.c.assistant.phase if rig.c.assistant else None
    for _ in range(20):
        rec = rig.c.tick(None)
        np.testing.assert_array_equal(rec.command, 0.0)
    np.testing.assert_array_equal(rig.adapter.read_state().q, q1)
    assert rig.c.mode == "assist"
    assert rig.c.assistant is not None
    assert rig.c.assistant.phase == phase


def test_cancel_button_returns_control_and_restarts_inference(rig: Rig) -> None:
    rig.drive_to_commit("white_mug")
    rig.c.tick(rig.sample([0.0, 0.0, 0.0]))
    rig.c.tick(rig.sample([0.0, 0.0, 0.0], cancel=True))
    assert rig.c.mode == "teleop"
    assert rig.c.committed is None
    assert rig.kinds()[-1] == "cancel"
    assert rig.events[-1][1]["reason"] == "button"
    post = list(rig.c.posterior().values())
    assert post == pytest.approx([1 / len(post)] * len(post))
    # inference resumes from where the arm is now
    assert rig.c.inference.observer is not None
    np.testing.assert_allclose(
        rig.c.inference.observer.goals.x0.position, rig.adapter.read_state().ee_position
    )


def test_holding_the_stick_against_the_motion_after_the_grasp_cancels(rig: Rig) -> None:
    rig.drive_to_commit("white_mug")
    rig.until(lambda: rig.c.assistant is not None and rig.c.assistant.gripper_acted)
    rig.c.tick(rig.hands_off())  # the lift starts moving
    back = -rig.c._motion / np.linalg.norm(rig.c._motion)
    ticks = 0
    while rig.c.mode == "assist" and ticks < 100:
        rig.c.tick(rig.sample(0.9 * back))
        ticks += 1
    assert rig.c.mode == "idle"  # the desk's one stage counts as done: the object was taken
    kind, detail = rig.events[-3]
    assert (kind, detail["reason"]) == ("cancel", "opposed")
    assert rig.kinds()[-2:] == ["stage_done", "task_done"]
    assert ticks * rig.c.dt >= CANCEL_SECONDS - 1e-9


def test_confirm_away_from_every_candidate_commits_the_most_likely_goal(rig: Rig) -> None:
    for _ in range(10):
        rig.c.tick(rig.toward("black_stapler"))
    ee = rig.adapter.read_state().ee_position
    gap = min(float(np.linalg.norm(t.position - ee)) for t in rig.c.stage.targets)
    assert gap > CONFIRM_RADIUS  # the hand is at no candidate yet
    rig.c.tick(rig.sample([0.0, 0.0, 0.0], confirm=True))
    assert rig.c.mode == "assist"
    kind, detail = rig.events[-1]
    assert kind == "commit"
    assert detail["confirmed"] is True
    assert detail["goal"] == max(detail["posterior"], key=detail["posterior"].get)


def test_confirm_at_a_candidate_acts_on_the_object_the_hand_is_at(rig: Rig) -> None:
    for _ in range(10):
        rig.c.tick(rig.toward("black_stapler"))
    post = rig.c.posterior()
    likely = max(post, key=post.__getitem__)
    other = next(t for t in rig.c.stage.targets if t.name != likely)
    inference = rig.c.inference
    at = other.position + np.array([0.0, 0.0, 0.9 * CONFIRM_RADIUS])
    assert inference.confirmed(at) == (other.name, pytest.approx(post[other.name]))
    # just outside the radius the hand names nothing: the posterior decides
    off = other.position + np.array([0.0, 0.0, 1.1 * CONFIRM_RADIUS])
    assert inference.confirmed(off)[0] == likely


def test_adapter_failure_is_a_safe_stop_with_one_fault_event(rig: Rig) -> None:
    for _ in range(5):
        rig.c.tick(rig.toward("white_mug"))
    rig.adapter.failing = True
    for _ in range(5):
        rec = rig.c.tick(rig.sample([0.5, 0.0, 0.0]))
        np.testing.assert_array_equal(rec.command, 0.0)
    assert rig.c.mode == "fault"
    assert rig.kinds().count("fault") == 1
    assert "heartbeat" in (rig.c.fault or "")
    with pytest.raises(HardwareError):
        operator_command(rig.c, CommandRequest.model_validate({"schema": 1, "command": "reset"}))
    rig.adapter.failing = False
    operator_command(rig.c, CommandRequest.model_validate({"schema": 1, "command": "reset"}))
    for _ in range(1000):
        rig.c.tick(rig.sample([0.0, 0.0, 0.0]))
        if rig.c.mode == "teleop":
            break
    assert rig.c.mode == "teleop"
    assert rig.kinds()[-1] == "recovered"
    np.testing.assert_allclose(
        rig.adapter.read_state().ee_position, rig.c.scene.home.position, atol=0.005
    )


def test_stop_holds_until_reset_and_load_scene_swaps(rig: Rig) -> None:
    req = CommandRequest.model_validate
    operator_command(rig.c, req({"schema": 1, "command": "stop"}))
    p = rig.adapter.read_state().ee_position
    for _ in range(5):
        rec = rig.c.tick(rig.sample([1.0, 0.0, 0.0]))
        np.testing.assert_array_equal(rec.command, 0.0)
    np.testing.assert_array_equal(rig.adapter.read_state().ee_position, p)
    assert rig.c.mode == "stopped"
    out = operator_command(
        rig.c, req({"schema": 1, "command": "load_scene", "argument": "breakfast_easy"})
    )
    assert out["scene"] == "breakfast_easy"
    assert rig.c.mode == "teleop"
    assert set(rig.c.posterior()) == set(load_scene("breakfast_easy").goal_names)
    with pytest.raises(InputError):
        operator_command(rig.c, req({"schema": 1, "command": "load_scene", "argument": "nope"}))


def test_a_misplaced_object_is_named_when_the_certificate_is_lost(rig: Rig) -> None:
    planned = rig.c.stage.certificate
    assert planned is not None
    assert planned > 0
    stapler = rig.c.layouts.planned["black_stapler"]
    mug = rig.c.layouts.planned["white_mug"]
    # a tracker reports the mug right next to the stapler: the goals can no longer be told apart
    at = ObjectPose(stapler.x + 0.02, stapler.y + 0.01, 0.0)
    rig.c.observe({"white_mug": at})
    kind, detail = rig.events[-1]
    assert kind == "warning"
    assert detail["move"] == "white_mug"
    assert detail["certificate"] <= 0 < detail["planned_certificate"]
    assert detail["to"] == {"x": mug.x, "y": mug.y, "yaw": mug.yaw}
    (text,) = detail["corrections"]
    dy = round(abs(mug.y - at.y) * 100)
    assert text.startswith(f"white_mug: {dy} cm {'left' if mug.y > at.y else 'right'}")
    assert detail["unseen"] == []
    report = rig.c.placement
    assert report is not None
    assert report.certified is False
    assert [o.name for o in report.misplaced] == ["white_mug"]
    n = len(rig.events)
    rig.c.observe({"white_mug": ObjectPose(at.x + 0.001, at.y, 0.0)})
    assert len(rig.events) == n  # the same objects are off: said again only after a while
    # moved back: the certificate is positive again, and the daemon says so once
    rig.c.observe({"white_mug": mug})
    assert rig.c.stage.observed_certificate == pytest.approx(planned)
    kind, detail = rig.events[-1]
    assert kind == "placed"
    assert detail["stage"] == rig.c.stage.name
    assert detail["certificate"] == round(planned, 4)
    assert rig.c.placement is not None
    assert rig.c.placement.certified is True
    n = len(rig.events)
    rig.c.observe({"unknown_thing": mug, "table": mug})  # not objects of the scene: ignored
    assert len(rig.events) == n
