"""Assistance plans as pure math: on an ideal point robot a plan converges, pauses and times out."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.core.geometry import rot_z
from legws_daemon.daemon.assist import (
    PREGRASP_DISTANCE,
    PRIMITIVE_TIMEOUT,
    Assistant,
    CancelDetector,
    Grip,
    Move,
    grasp_rotation,
    pick_plan,
)

DOWN = np.diag([1.0, -1.0, -1.0])  # approach axis (z) pointing down


def run(a: Assistant, p: np.ndarray, limit: int = 2000) -> tuple[np.ndarray, list[str], list[bool]]:
    phases, grips = [], []
    for _ in range(limit):
        step = a.step(p, DOWN)
        assert np.linalg.norm(step.velocity) <= a.speed + 1e-12
        if step.grip is not None:
            grips.append(step.grip)
        phases.append(step.phase)
        p = p + step.velocity * a.dt
        if step.done or step.failed:
            break
    return p, phases, grips


def test_pick_plan_reaches_pregrasp_then_grasp_then_lifts() -> None:
    grasp = np.array([0.7, 0.1, 0.05])
    plan = pick_plan(grasp, DOWN, 2, DOWN)
    assert [p.label for p in plan] == ["approach", "reach", "grasp", "lift"]
    first = plan[0]
    assert isinstance(first, Move)
    np.testing.assert_allclose(first.position, grasp + np.array([0, 0, PREGRASP_DISTANCE]))
    a = Assistant(plan, speed=0.1, dt=0.05, target="cup")
    end, phases, grips = run(a, np.array([0.5, 0.0, 0.3]))
    assert a.finished
    assert grips and all(grips)
    assert list(dict.fromkeys(phases)) == ["approach", "reach", "grasp", "lift"]
    np.testing.assert_allclose(end, grasp + np.array([0, 0, 0.10]), atol=0.005)


def test_symmetric_grasp_turns_the_short_way() -> None:
    R = DOWN @ rot_z(np.pi)  # a two-fold symmetric grasp given the other way round
    chosen = grasp_rotation(R, 2, DOWN)
    np.testing.assert_allclose(chosen, DOWN, atol=1e-9)


def test_paused_ticks_do_not_move_or_time_out() -> None:
    a = Assistant([Move("m", np.array([1.0, 0, 0]), DOWN)], speed=0.1, dt=0.05)
    for _ in range(int(2 * PRIMITIVE_TIMEOUT / 0.05)):
        step = a.step(np.zeros(3), DOWN, active=False)
        np.testing.assert_array_equal(step.velocity, 0.0)
        assert step.failed is None


def test_a_move_that_cannot_arrive_fails() -> None:
    a = Assistant([Move("m", np.array([1.0, 0, 0]), DOWN)], speed=0.1, dt=0.05)
    for _ in range(int(PRIMITIVE_TIMEOUT / 0.05) + 2):
        step = a.step(np.zeros(3), DOWN)  # the robot never moves
        if step.failed:
            break
    assert step.failed is not None
    assert "timed out" in step.failed


def test_grip_waits_its_time() -> None:
    a = Assistant([Grip("g", closed=True, seconds=0.3)], speed=0.1, dt=0.05)
    steps = [a.step(np.zeros(3), DOWN) for _ in range(6)]
    assert [s.done for s in steps] == [False] * 5 + [True]
    assert all(s.grip is True for s in steps)


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
