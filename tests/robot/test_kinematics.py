"""Velocity control, limits and IK on the real MuJoCo model."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.arms import arm
from legws_daemon.robot.kinematics import (
    _redundant_solve,
    home_configuration,
    rotation_error,
    small_rotation_error,
    solve_ik,
    velocity_step,
)
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene

SAWYER = arm("sawyer")
JOINT_SPEED_LIMITS = np.array(SAWYER.speed_limits)
READY_POSTURE = np.array(SAWYER.ready_posture)


@pytest.fixture(scope="module")
def desk() -> tuple[World, np.ndarray]:
    sc = load_scene("desk")
    w = World(sc)
    return w, home_configuration(w, sc.home.position, sc.home.rotation).q


def test_velocity_control_reaches_a_target_and_holds_orientation(
    desk: tuple[World, np.ndarray],
) -> None:
    w, q_home = desk
    w.set_q(q_home)
    R0 = w.ee_rotation().copy()
    target = w.ee_position() + np.array([0.15, 0.2, -0.18])
    for _ in range(400):
        d = target - w.ee_position()
        dist = np.linalg.norm(d)
        if dist < 1e-3:
            break
        v = d / dist * min(0.05, dist / 0.05)
        velocity_step(w, np.concatenate([v, 2.0 * small_rotation_error(w.ee_rotation(), R0)]), 0.05)
    assert np.linalg.norm(target - w.ee_position()) < 1e-3
    assert np.linalg.norm(rotation_error(w.ee_rotation(), R0)) < 0.01


def test_commanded_velocity_is_tracked(desk: tuple[World, np.ndarray]) -> None:
    w, q_home = desk
    w.set_q(q_home)
    v = np.array([0.03, -0.02, -0.035])
    p0 = w.ee_position()
    for _ in range(20):
        velocity_step(w, np.concatenate([v, np.zeros(3)]), 0.05)
    np.testing.assert_allclose(w.ee_position() - p0, v * 1.0, atol=2e-3)


def test_joint_speed_and_position_limits_hold(desk: tuple[World, np.ndarray]) -> None:
    w, q_home = desk
    w.set_q(q_home)
    # an impossible command: 5 m/s sideways and a fast spin, for 4 seconds
    for _ in range(80):
        q0 = w.q
        res = velocity_step(w, np.array([0.0, 5.0, 0.0, 0.0, 0.0, 6.0]), 0.05)
        assert np.all(np.abs(res.qdot) <= JOINT_SPEED_LIMITS * (1 + 1e-9))
        assert np.all(np.abs(w.q - q0) <= JOINT_SPEED_LIMITS * 0.05 + 1e-9)
        assert np.all(w.q >= w.arm.lower) and np.all(w.q <= w.arm.upper)


def test_ik_reaches_a_pose(desk: tuple[World, np.ndarray]) -> None:
    w, q_home = desk
    sc = load_scene("desk")
    g = sc.goal_set()
    i = g.index("black_stapler")
    r = solve_ik(w, g.positions[i], g.rotations[i], q_home)
    assert r.converged
    np.testing.assert_allclose(w.ee_position(), g.positions[i], atol=1e-3)


def test_the_posture_pull_does_not_move_the_ee(desk: tuple[World, np.ndarray]) -> None:
    """The redundancy's drift toward the ready posture lies in the exact null space of the
    EE task: to first order it moves no part of the EE, even near a singular direction
    (the damped projector leaked centimetres per second there)."""
    w, q_home = desk
    rng = np.random.default_rng(3)
    for q in [q_home, *rng.uniform(w.arm.lower * 0.9, w.arm.upper * 0.9, (20, 7))]:
        w.set_q(q)
        J = w.jacobian()
        pull = 0.5 * (READY_POSTURE - q)
        qdot = _redundant_solve(J, np.zeros(6), pull)
        assert np.linalg.norm(J @ qdot) < 1e-6 * max(1.0, float(np.linalg.norm(pull)))
    # with the pull switched off, a zero twist is no motion at all
    w.set_q(q_home)
    res = velocity_step(w, np.zeros(6), 0.05, posture=False)
    np.testing.assert_array_equal(res.qdot, 0.0)
    np.testing.assert_array_equal(w.q, q_home)
