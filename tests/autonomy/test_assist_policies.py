"""Help before the commit and the way back, on the real MuJoCo stand-in: ``blend`` and
``hindsight`` move the arm toward the likely goal while inference reads the operator's own
input; an override hands control back without a jump in velocity."""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np
import pytest

from legws_daemon.autonomy.inputs import TickRecord
from legws_daemon.autonomy.override import HANDBACK_ACCELERATION, OVERRIDE_SECONDS
from legws_daemon.core.geometry import rotation_angle
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.task.runner import scene_graph
from tests.autonomy.rig import Rig, stand_in_profile


def _with(profile: ProfileSpec, assist: str) -> ProfileSpec:
    control = profile.control.model_copy(update={"assist": assist})
    return profile.model_copy(update={"control": control})


@pytest.fixture(scope="module")
def desk() -> Scene:
    return load_scene("desk")


@pytest.fixture(params=["commit", "blend", "hindsight"])
def rig(request: pytest.FixtureRequest, desk: Scene) -> Iterator[Rig]:
    r = Rig(_with(stand_in_profile(), request.param), desk)
    yield r
    r.c.shutdown()


@pytest.fixture
def blend_rig(desk: Scene) -> Iterator[Rig]:
    r = Rig(_with(stand_in_profile(), "blend"), desk)
    yield r
    r.c.shutdown()


def _steps(records: list[TickRecord]) -> list[float]:
    return [float(np.linalg.norm(b.command - a.command)) for a, b in itertools.pairwise(records)]


def test_every_policy_picks_the_goal_steered_to(rig: Rig) -> None:
    goal = "white_mug"
    rig.commit(goal)
    rig.until(lambda: rig.c.mode != "assist")
    assert rig.c.mode == "idle"
    assert rig.adapter.held == goal
    assert "override" not in rig.kinds()


def test_blend_moves_the_arm_toward_the_likely_goal_before_any_commit(blend_rig: Rig) -> None:
    rig, c = blend_rig, blend_rig.c
    goal = "white_mug"
    start = rig.adapter.read_state().ee_position
    speeds, robot = [], []
    records: list[TickRecord] = []
    shadow = np.array(start)
    for _ in range(400):
        inp = rig.toward(goal)
        assert c.inference.shadow is not None
        np.testing.assert_allclose(c.inference.shadow, shadow, atol=1e-12)
        rec = c.tick(inp)
        if c.mode != "teleop":
            break
        shadow = shadow + c.profile.control.v_max * inp.axes * c.dt  # the observer's path
        speeds.append(float(np.linalg.norm(rec.command)))
        records.append(rec)
        assert rec.robot_velocity is not None
        robot.append(rec.robot_velocity)
    assert c.mode == "assist" and c.committed == goal
    # the robot's part points at the goal and adds speed the stick alone cannot give
    assert max(speeds) > 1.2 * c.profile.control.v_max
    biggest = int(np.argmax([float(np.linalg.norm(r)) for r in robot]))
    help_ = robot[biggest] / np.linalg.norm(robot[biggest])
    at = records[biggest].state
    assert at is not None
    d = c.stage.target(goal).position - at.ee_position
    assert float(help_ @ d) / float(np.linalg.norm(d)) > 0.9
    # its share never jumps
    steps = [float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(robot)]
    assert max(steps) <= HANDBACK_ACCELERATION * c.dt + 1e-9


def test_a_centred_stick_stops_a_blending_arm(blend_rig: Rig) -> None:
    rig, c = blend_rig, blend_rig.c
    rig.drive("white_mug", 30)
    assert max(c.posterior().values()) > 0.3 and c.mode == "teleop"
    rec = c.tick(rig.hands_off())
    np.testing.assert_array_equal(rec.command, 0.0)
    rec = c.tick(None)
    np.testing.assert_array_equal(rec.command, 0.0)


def test_holding_the_stick_against_the_committed_goal_overrides_without_a_jump(rig: Rig) -> None:
    c = rig.c
    rig.drive_to_commit("white_mug")
    records = [c.tick(rig.hands_off()) for _ in range(30)]  # the approach under way, fast
    assert c.mode == "assist" and not c.assistant.gripper_acted  # type: ignore[union-attr]
    away = -(c.stage.target("white_mug").position - rig.adapter.read_state().ee_position)
    away /= np.linalg.norm(away)
    held = 0
    while c.mode == "assist" and held < 100:
        records.append(c.tick(rig.sample(0.9 * away)))
        held += 1
    before = len(records) - 2  # the last assisted tick
    assert c.mode == "teleop"
    kind, detail = rig.events[-1]
    assert kind == "override"
    assert detail["goal"] == "white_mug" and detail["during"] == "assist"
    assert held * c.dt >= OVERRIDE_SECONDS - 1e-9
    assert c.committed is None and c.inference.observer is not None  # inference re-opened
    at = records[-1].state  # where the override found the EE
    assert at is not None
    np.testing.assert_allclose(c.inference.observer.goals.x0.position, at.ee_position)
    for _ in range(20):
        records.append(c.tick(rig.sample(0.9 * away)))
    # from the assisted motion to the operator's, at the bound per tick at most
    steps = _steps(records[before:])
    assert max(steps) <= HANDBACK_ACCELERATION * c.dt + 1e-9
    assert float(np.linalg.norm(records[before].command)) > 0.09  # it was moving fast
    jump = float(np.linalg.norm(records[-1].command - records[before].command))
    assert jump > 1.5 * HANDBACK_ACCELERATION * c.dt  # in one tick it would have jumped
    mine = 0.9 * c.profile.control.v_max * away
    if c.policy == "commit":  # the operator's command, caught up
        np.testing.assert_allclose(records[-1].command, mine, atol=1e-9)
    else:  # the operator's, with whatever help the re-opened inference gives
        assert c.mode == "teleop" and rig.kinds()[-1] == "override"  # no commit since


def test_pushing_against_the_blends_guess_overrides_it(blend_rig: Rig) -> None:
    rig, c = blend_rig, blend_rig.c
    goal = "white_mug"
    records: list[TickRecord] = []

    def helping() -> bool:  # fully, and sure enough not to change its mind at once
        r = records[-1].robot_velocity if records else None
        sure = max(c.posterior().values()) >= 0.6
        return sure and r is not None and float(np.linalg.norm(r)) > 0.03

    while c.mode == "teleop" and not helping():
        records.append(c.tick(rig.toward(goal)))
        assert len(records) < 400
    guess = max(c.posterior(), key=c.posterior().get)
    away = -(c.stage.target(guess).position - rig.adapter.read_state().ee_position)
    away = away / np.linalg.norm(away)
    for _ in range(40):
        records.append(c.tick(rig.sample(away)))
        if "override" in rig.kinds():
            break
    at = len(records) - 2  # the last tick helped toward the guess
    detail = next(d for k, d in rig.events if k == "override")
    assert detail == {"goal": guess, "during": "blend", "phase": None}
    for _ in range(10):
        records.append(c.tick(rig.sample(away)))
    assert c.mode == "teleop"
    assert records[-1].robot_velocity is not None
    assert float(np.linalg.norm(records[-1].robot_velocity)) == 0.0  # no help toward it
    np.testing.assert_allclose(records[-1].command, c.profile.control.v_max * away, atol=1e-9)
    # the operator turned the stick at once (their jump); from the override on, no jump
    assert max(_steps(records[at:])) <= HANDBACK_ACCELERATION * c.dt + 1e-9


@pytest.fixture
def hand_rig(desk: Scene) -> Iterator[Rig]:
    r = Rig(_with(stand_in_profile(), "none"), desk)
    yield r
    r.c.shutdown()


def test_without_assistance_nothing_commits_even_at_the_goal_or_on_confirm(
    hand_rig: Rig,
) -> None:
    rig, c = hand_rig, hand_rig.c
    goal = "white_mug"
    for _ in range(400):
        d = c.stage.target(goal).position - rig.adapter.read_state().ee_position
        n = float(np.linalg.norm(d))
        c.tick(rig.sample(d / n if n > 0.01 else np.zeros(3), confirm=n <= 0.01))
    assert c.mode == "teleop" and c.committed is None and "commit" not in rig.kinds()
    assert max(c.posterior().values()) > 0.9  # it inferred all the same (status shows it)


def test_the_rotation_axes_turn_the_held_orientation_at_w_teleop(hand_rig: Rig) -> None:
    rig, c = hand_rig, hand_rig.c
    before = c.inference.hold.copy()
    ticks = 20
    for _ in range(ticks):
        c.tick(rig.sample([0, 0, 0], rotation=[0.0, 0.0, 1.0]))
    turned = float(rotation_angle(before, c.inference.hold))
    assert turned == pytest.approx(c.profile.control.w_teleop * ticks * c.dt, rel=1e-9)
    held = c.inference.hold.copy()
    for _ in range(5):  # no input: nothing turns, not even the orientation held
        c.tick(None)
    np.testing.assert_array_equal(c.inference.hold, held)
    # the arm follows the held orientation (the envelope caps the turning rate)
    for _ in range(40):
        c.tick(rig.hands_off())
    assert float(rotation_angle(rig.adapter.read_state().ee_rotation, held)) < 0.05


def test_the_gripper_button_acts_in_teleoperation_only(blend_rig: Rig) -> None:
    rig, c = blend_rig, blend_rig.c
    c.tick(rig.sample([0, 0, 0], gripper=True))
    c.tick(rig.sample([0, 0, 0], gripper=True))  # the same request: nothing more
    assert rig.adapter.grips == [True] and c.modes.gripper == "closed"
    assert c.held is None  # closed on nothing
    c.tick(rig.sample([0, 0, 0], gripper=False))
    assert rig.adapter.grips == [True, False]
    rig.drive_to_commit("white_mug")
    grips = list(rig.adapter.grips)
    for _ in range(5):  # during assistance the plan owns the gripper
        c.tick(rig.sample([0, 0, 0], gripper=True))
    assert c.mode == "assist" and rig.adapter.grips == grips


def test_without_assistance_a_single_candidate_is_not_taken_either(desk: Scene) -> None:
    rig = Rig(_with(stand_in_profile(), "none"), desk, graph=scene_graph(desk, ["white_mug"]))
    try:
        for _ in range(20):
            rig.c.tick(rig.sample([0.0, 0.0, 0.0], confirm=True))
        assert rig.c.mode == "teleop" and rig.c.assistant is None
        assert "commit" not in rig.kinds()
    finally:
        rig.c.shutdown()
