"""The help before the commit as pure math: arbitration, blend, hindsight, slew."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from legws_daemon.core.arbitration import (
    ALPHA_MAX,
    FULL_SHARE,
    HUBER_FADE,
    HUBER_ROBOT_COST,
    HUBER_SWITCH,
    against,
    arbitration,
    blend,
    hindsight,
    huber_cost,
    huber_pull,
    slew,
    toward,
)

unit = st.floats(-1.0, 1.0, allow_nan=False)
vec = st.tuples(unit, unit, unit).map(np.array)


def _stick(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1.0 else v


def test_arbitration_is_zero_at_a_uniform_posterior_and_full_before_the_threshold() -> None:
    assert arbitration(0.25, 4, 0.9) == 0.0
    assert arbitration(0.1, 4, 0.9) == 0.0
    full = 0.25 + FULL_SHARE * (0.9 - 0.25)
    assert arbitration(full, 4, 0.9) == pytest.approx(ALPHA_MAX)
    assert arbitration(0.99, 4, 0.9) == pytest.approx(ALPHA_MAX)
    assert arbitration((0.25 + full) / 2, 4, 0.9) == pytest.approx(ALPHA_MAX / 2)


@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.integers(2, 12))
def test_arbitration_grows_with_confidence_within_its_bounds(p: float, q: float, n: int) -> None:
    lo, hi = sorted((p, q))
    a, b = arbitration(lo, n, 0.9), arbitration(hi, n, 0.9)
    assert 0.0 <= a <= b <= ALPHA_MAX


@settings(max_examples=200)
@given(vec, vec, st.lists(st.floats(0.01, 1.0), min_size=2, max_size=6))
def test_the_robot_part_never_outruns_the_stick(
    axes: np.ndarray, ee: np.ndarray, weights: list[float]
) -> None:
    u = _stick(axes)
    rng = np.random.default_rng(len(weights))
    goals = rng.uniform(-1, 1, (len(weights), 3))
    post = np.array(weights) / sum(weights)
    b = blend(u, 0.05, ee, goals, post, 0.9, 0.10)
    np.testing.assert_allclose(b.velocity, b.operator + b.robot)
    assert b.robot_speed <= 0.10 * float(np.linalg.norm(u)) + 1e-12
    h = hindsight(u, 0.05, ee, goals, post, 0.05)
    np.testing.assert_allclose(h.operator, 0.05 * u)
    pull = (2.25 + 0.2) / HUBER_ROBOT_COST
    assert h.robot_speed <= pull * float(np.linalg.norm(u)) + 1e-12


def test_a_centred_stick_stops_the_arm_whatever_the_robot_believes() -> None:
    goals = np.array([[0.5, 0.0, 0.1], [0.5, 0.3, 0.1]])
    sure = np.array([0.999, 0.001])
    for b in (blend(np.zeros(3), 0.05, np.zeros(3), goals, sure, 0.9, 0.1),
              hindsight(np.zeros(3), 0.05, np.zeros(3), goals, sure, 0.05)):  # fmt: skip
        np.testing.assert_array_equal(b.velocity, 0.0)
        assert b.guess is None


def test_blend_moves_toward_the_likely_goal_at_the_arbitrated_share() -> None:
    goals = np.array([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0]])
    u = np.array([0.0, 0.0, 1.0])  # the stick points elsewhere: the robot's part is its own
    b = blend(u, 0.05, np.zeros(3), goals, np.array([0.9, 0.1]), 0.9, 0.1)
    assert b.guess == 0
    alpha = arbitration(0.52, 2, 0.9)
    assert 0 < alpha < ALPHA_MAX
    b = blend(u, 0.05, np.zeros(3), goals, np.array([0.52, 0.48]), 0.9, 0.1)
    assert b.weight == pytest.approx(alpha)
    np.testing.assert_allclose(b.robot, [alpha * 0.1, 0.0, 0.0])
    np.testing.assert_allclose(b.operator, [0.0, 0.0, (1 - alpha) * 0.05])


def test_toward_slows_down_near_the_goal_and_stops_on_it() -> None:
    np.testing.assert_allclose(toward([0, 0, 0], [1, 0, 0], 0.1), [0.1, 0, 0])
    np.testing.assert_allclose(toward([0, 0, 0], [0.025, 0, 0], 0.1), [0.05, 0, 0])
    np.testing.assert_array_equal(toward([1, 2, 3], [1, 2, 3], 0.1), 0.0)


@settings(max_examples=100)
@given(st.floats(HUBER_FADE + 1e-3, 0.6), st.floats(0, 2 * np.pi), st.floats(-1.2, 1.2))
def test_the_huber_pull_is_minus_the_costs_gradient(r: float, yaw: float, pitch: float) -> None:
    assume(abs(r - HUBER_SWITCH) > 1e-4)  # the cost's curvature jumps there
    goal = np.array([0.4, -0.1, 0.2])
    x = goal + r * np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch),
                             np.sin(pitch)])  # fmt: skip
    h = 1e-6

    def cost(y: np.ndarray) -> float:
        return float(huber_cost(np.linalg.norm(y - goal)))

    grad = np.array([(cost(x + h * e) - cost(x - h * e)) / (2 * h) for e in np.eye(3)])
    np.testing.assert_allclose(huber_pull(x, goal[None])[0], -grad / HUBER_ROBOT_COST,
                               atol=1e-7)  # fmt: skip


def test_the_huber_cost_is_continuous_with_its_slope_at_the_switch() -> None:
    s, h = 0.07, 1e-7
    assert float(huber_cost(s - h)) == pytest.approx(float(huber_cost(s + h)), abs=1e-6)
    left = (huber_cost(s) - huber_cost(s - h)) / h
    right = (huber_cost(s + h) - huber_cost(s)) / h
    assert float(left) == pytest.approx(float(right), rel=1e-4)


def test_hindsight_weights_each_goals_pull_by_its_posterior() -> None:
    goals = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    u = np.array([0.0, 1.0, 0.0])
    even = hindsight(u, 0.05, np.zeros(3), goals, np.array([0.5, 0.5]), 0.05)
    np.testing.assert_allclose(even.robot[0], 0.0, atol=1e-12)  # the pulls cancel
    sure = hindsight(u, 0.05, np.zeros(3), goals, np.array([1.0, 0.0]), 0.05)
    assert sure.robot[0] == pytest.approx((2.25 + 0.2) / HUBER_ROBOT_COST, rel=1e-3)


@given(vec, vec, st.floats(1e-4, 0.5))
def test_slew_changes_by_at_most_its_step_and_reaches_what_is_near(
    a: np.ndarray, b: np.ndarray, step: float
) -> None:
    v = slew(a, b, step)
    assert float(np.linalg.norm(v - a)) <= step + 1e-12
    if float(np.linalg.norm(b - a)) <= step:
        np.testing.assert_array_equal(v, b)


def test_against_needs_both_the_angle_and_the_deflection() -> None:
    d = np.array([1.0, 0.0, 0.0])
    assert against([-0.9, 0, 0], d, -0.3, 0.5)
    assert not against([-0.4, 0, 0], d, -0.3, 0.5)  # too little
    assert not against([0, 0.9, 0], d, -0.3, 0.5)  # across, not against
    assert not against([-0.9, 0, 0], np.zeros(3), -0.3, 0.5)
