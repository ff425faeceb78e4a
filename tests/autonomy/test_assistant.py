"""Assistance plans as pure math: on an ideal robot a plan converges, pauses and times out."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.arms import arm
from legws_daemon.autonomy.assistant import (
    JOINT_SPEED_FRACTION,
    MAX_VIAS,
    MAX_WITHDRAWALS,
    PRIMITIVE_TIMEOUT,
    Assistant,
)
from legws_daemon.autonomy.cancel import CancelDetector
from legws_daemon.autonomy.inputs import Cartesian, Joints
from legws_daemon.errors import InfeasibleError
from legws_daemon.robot.motion import FALLBACK_PATIENCE, Grip, JointMove, Move

SAWYER = arm("sawyer")
JOINT_SPEED_LIMITS = np.array(SAWYER.speed_limits)


DOWN = np.diag([1.0, -1.0, -1.0])  # approach axis (z) pointing down
Q0 = np.zeros(7)


def run(
    a: Assistant, p: np.ndarray, q: np.ndarray, limit: int = 2000
) -> tuple[np.ndarray, np.ndarray, list[str], list[bool]]:
    """An ideal robot: the EE follows Cartesian commands, the joints joint commands."""
    phases, grips = [], []
    for _ in range(limit):
        step = a.step(q, p, DOWN)
        if step.grip is not None:
            grips.append(step.grip)
        phases.append(step.phase)
        match step.command:
            case Cartesian(velocity):
                assert np.linalg.norm(velocity) <= a.speed + 1e-12
                p = p + velocity * a.dt
            case Joints(qdot):
                assert np.all(np.abs(qdot) <= JOINT_SPEED_FRACTION * JOINT_SPEED_LIMITS + 1e-12)
                q = q + qdot * a.dt
        if step.done or step.failed:
            break
    return p, q, phases, grips


def test_a_plan_runs_its_primitives_in_order_to_the_end() -> None:
    q_pre = np.array([0.3, -0.5, 0.2, 1.2, -0.4, 0.9, 1.0])
    grasp = np.array([0.7, 0.1, 0.05])
    plan = [
        JointMove("carry", q_pre),
        Move("reach", grasp, DOWN),
        Grip("grasp", closed=True),
        Move("lift", grasp + np.array([0.0, 0.0, 0.1]), DOWN),
    ]
    a = Assistant(plan, speed=0.1, dt=0.05, target="cup")
    end, q, phases, grips = run(a, np.array([0.5, 0.0, 0.3]), Q0.copy())
    assert a.finished
    assert grips and all(grips)
    assert list(dict.fromkeys(phases)) == ["carry", "reach", "grasp", "lift"]
    np.testing.assert_allclose(q, q_pre, atol=0.002)
    np.testing.assert_allclose(end, grasp + np.array([0, 0, 0.10]), atol=0.005)


def test_a_joint_move_keeps_a_straight_line_in_joint_space() -> None:
    target = np.array([1.0, -0.5, 0.0, 0.5, 2.0, 0.0, -1.0])
    a = Assistant([JointMove("j", target)], speed=0.1, dt=0.05)
    q = Q0.copy()
    step = a.step(q, np.zeros(3), DOWN)
    assert isinstance(step.command, Joints)
    direction = step.command.qdot / np.linalg.norm(step.command.qdot)
    np.testing.assert_allclose(direction, target / np.linalg.norm(target), atol=1e-12)


def test_paused_ticks_do_not_move_or_time_out() -> None:
    for prim in (Move("m", np.array([1.0, 0, 0]), DOWN), JointMove("j", np.ones(7))):
        a = Assistant([prim], speed=0.1, dt=0.05)
        for _ in range(int(2 * PRIMITIVE_TIMEOUT / 0.05)):
            step = a.step(Q0, np.zeros(3), DOWN, active=False)
            assert isinstance(step.command, Cartesian)
            np.testing.assert_array_equal(step.command.velocity, 0.0)
            assert step.command.hold is None
            assert step.failed is None


def test_a_move_that_cannot_arrive_fails() -> None:
    a = Assistant([Move("m", np.array([1.0, 0, 0]), DOWN)], speed=0.1, dt=0.05)
    for _ in range(int(PRIMITIVE_TIMEOUT / 0.05) + 2):
        step = a.step(Q0, np.zeros(3), DOWN)  # the robot never moves
        if step.failed:
            break
    assert step.failed is not None
    assert "timed out" in step.failed


def test_a_blocked_joint_move_withdraws_first_and_is_checked_again_from_there() -> None:
    """The way home from the box's edge: no joint path from where the arm stands, a straight
    withdrawal toward home, then the joint move checked again from where the withdrawal ended."""
    home = np.array([0.2, -0.4, 0.1, 0.9, 0.0, 0.6, 0.0])
    edge, inside = np.array([0.4, -0.55, 0.3]), np.array([0.55, 0.0, 0.3])
    checked: list[np.ndarray] = []
    asked: list[np.ndarray] = []

    def path(q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray]:
        checked.append(q0.copy())
        if len(checked) == 1:  # from the edge: every joint line leaves the box
            raise InfeasibleError("no clear joint-space path: the straight one leaves the box")
        return []

    def withdraw(q0: np.ndarray, q1: np.ndarray) -> list[Move] | None:
        asked.append(q0.copy())
        return [Move("withdraw", inside, DOWN, 0.004, 2.0, optional=True)]

    q_edge = np.array([-0.6, -0.3, 0.0, 1.2, 0.0, 0.7, 0.0])
    a = Assistant([JointMove("home", home)], 0.1, 0.05, "cereal_box", path, withdraw)
    end, q, phases, _ = run(a, edge, q_edge.copy())
    assert a.finished
    assert list(dict.fromkeys(phases)) == ["withdraw", "home"]
    np.testing.assert_allclose(end, inside, atol=0.005)  # the withdrawal, in a straight line
    np.testing.assert_allclose(q, home, atol=0.002)
    assert len(asked) == 1 and np.array_equal(asked[0], q_edge)
    assert len(checked) == 2 and np.array_equal(checked[0], q_edge)


@pytest.mark.parametrize("offered", [True, False])
def test_a_joint_move_still_blocked_fails_after_at_most_two_withdrawals(offered: bool) -> None:
    def path(q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray]:
        raise InfeasibleError("no clear joint-space path: the straight one leaves the box")

    asked = []

    def withdraw(q0: np.ndarray, q1: np.ndarray) -> list[Move] | None:
        asked.append(q0)
        return [Move("withdraw", np.array([0.5, 0.0, 0.3]), DOWN, 0.004, 2.0)] if offered else None

    a = Assistant([JointMove("home", np.ones(7))], 0.1, 0.05, "box", path, withdraw)
    p, phases = np.array([0.4, -0.5, 0.3]), []
    for _ in range(400):
        step = a.step(Q0, p, DOWN)
        phases.append(step.phase)
        if isinstance(step.command, Cartesian):
            p = p + step.command.velocity * a.dt
        if step.failed or step.done:
            break
    assert step.failed is not None and step.failed.startswith("'home': no clear joint-space path")
    # asked again once from where the first withdrawal ended, then no more
    assert len(asked) == (MAX_WITHDRAWALS if offered else 1)
    assert ("withdraw" in phases) == offered
    np.testing.assert_allclose(p, [0.5, 0.0, 0.3] if offered else [0.4, -0.5, 0.3], atol=0.005)


def test_a_planner_that_keeps_offering_vias_fails_the_move_instead_of_circling() -> None:
    """A via that leads nowhere (the line from it is found blocked again when the arm gets
    there, and another via offered) would grow the plan by one move a tick for ever: at most
    MAX_VIAS vias per joint move, then a failure that says so."""
    target = np.full(7, 0.5)
    offered: list[np.ndarray] = []

    def path(q0: np.ndarray, q1: np.ndarray) -> list[np.ndarray]:
        via = q0 + 0.01  # a via near where the arm already is
        offered.append(via)
        return [via]

    a = Assistant([JointMove("carry", target)], 0.1, 0.05, "box", path)
    q, p = Q0.copy(), np.array([0.5, 0.0, 0.3])
    for _ in range(400):
        step = a.step(q, p, DOWN)
        if step.failed or step.done:
            break
        if isinstance(step.command, Joints):  # (a zero Cartesian step as a via is passed)
            q = q + step.command.qdot * a.dt
    assert step.failed == f"'carry': still no clear way after {MAX_VIAS} vias"
    assert len(offered) == MAX_VIAS + 1 and len(a.plan) == 1 + MAX_VIAS


def test_grip_waits_its_time() -> None:
    a = Assistant([Grip("g", closed=True, seconds=0.3)], speed=0.1, dt=0.05)
    steps = [a.step(Q0, np.zeros(3), DOWN) for _ in range(6)]
    assert [s.done for s in steps] == [False] * 5 + [True]
    assert all(s.grip is True for s in steps)


def test_a_final_approach_carries_its_floor() -> None:
    a = Assistant([Move("reach", np.array([0.6, 0, 0.01]), DOWN, floor=0.006)], 0.1, 0.05)
    step = a.step(Q0, np.array([0.6, 0, 0.09]), DOWN)
    assert isinstance(step.command, Cartesian)
    assert step.command.floor == 0.006
    assert step.command.velocity[2] < 0


@pytest.mark.parametrize(
    ("axes", "expected"),
    [([-0.9, 0, 0], "opposed"), ([0.9, 0, 0], None), ([-0.3, 0, 0], None), ([0, 0.9, 0], None)],
)
def test_cancel_detector(axes: list[float], expected: str | None) -> None:
    d = CancelDetector(dt=0.05)
    v = np.array([0.1, 0.0, 0.0])
    out = [d.update(np.array(axes), v, button=False) for _ in range(20)]
    assert out[-1] == expected
    if expected:
        assert out.index(expected) == 7  # 0.4 s at 20 Hz: the eighth tick
    assert d.update(None, v, button=True) == "button"


def test_a_reach_held_short_takes_its_joint_space_fallback() -> None:
    """A straight move in that makes no progress (a joint at its limit holds the EE) turns
    into the joint-space move to the check's configuration after FALLBACK_PATIENCE; a
    move that arrives never does."""
    q_grasp = np.array([0.3, -0.5, 0.2, 1.2, -0.4, 0.9, 1.0])
    goal = np.array([0.7, 0.1, 0.05])
    a = Assistant([Move("reach", goal, DOWN, fallback=q_grasp)], 0.1, 0.05, "bottle")
    p, q, phases = np.array([0.67, 0.1, 0.05]), Q0.copy(), []
    for _ in range(400):
        step = a.step(q, p, DOWN)  # the EE stays where it is: Cartesian commands do nothing
        phases.append(step.phase)
        if isinstance(step.command, Joints):
            q = q + step.command.qdot * a.dt
        if step.done or step.failed:
            break
    assert step.done and step.failed is None
    np.testing.assert_allclose(q, q_grasp, atol=0.002)
    assert isinstance(a.plan[0], JointMove) and a.plan[0].label == "reach"
    assert len(phases) * a.dt >= FALLBACK_PATIENCE  # it waited that long first
    # a straight move that gets there keeps its way
    b = Assistant([Move("reach", goal, DOWN, fallback=q_grasp)], 0.1, 0.05, "bottle")
    _, q_b, _, _ = run(b, np.array([0.6, 0.1, 0.05]), Q0.copy())
    assert b.finished and isinstance(b.plan[0], Move)
    np.testing.assert_array_equal(q_b, Q0)
