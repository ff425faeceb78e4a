"""Velocity control, limits, IK and the autonomous approach on the real MuJoCo model."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.core.geometry import symmetric_angle
from legws_daemon.robot.feasibility import check_grasps
from legws_daemon.robot.kinematics import (
    home_configuration,
    rotation_error,
    small_rotation_error,
    solve_ik,
    velocity_step,
)
from legws_daemon.robot.world import JOINT_SPEED_LIMITS, World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.sim.approach import approach


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


@pytest.mark.parametrize("name", ["white_mug", "black_stapler", "maroon_pen_cup"])
def test_approach_reaches_the_grasp_pose(desk: tuple[World, np.ndarray], name: str) -> None:
    w, q_home = desk
    g = load_scene("desk").goal_set()
    i = g.index(name)
    check = check_grasps(w, g, q_home)[name]
    w.set_q(q_home)
    r = approach(w, g.positions[i], g.rotations[i], int(g.symmetry[i]), q_grasp=check.q)
    assert r.reached
    assert np.linalg.norm(w.ee_position() - g.positions[i]) < 2.5e-3
    assert symmetric_angle(w.ee_rotation(), g.rotations[i], g.symmetry[i]) < 0.02
    assert w.arm_contacts(ignore=frozenset({name})) == []
