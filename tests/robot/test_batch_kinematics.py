"""Batched numpy kinematics against MuJoCo's own, and batched IK against solve_ik."""

from __future__ import annotations

import numpy as np

from legws_daemon.robot.batch_kinematics import BatchKinematics, batch_ik
from legws_daemon.robot.kinematics import home_configuration, solve_ik
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene


def test_forward_kinematics_and_jacobian_match_mujoco() -> None:
    w = World(load_scene("desk"), visual=False)
    rng = np.random.default_rng(0)
    q = rng.uniform(w.arm.lower, w.arm.upper, size=(50, 7))
    ee, R, J = BatchKinematics(w).forward(q)
    for i in range(len(q)):
        w.set_q(q[i])
        np.testing.assert_allclose(ee[i], w.ee_position(), atol=1e-10)
        np.testing.assert_allclose(R[i], w.ee_rotation(), atol=1e-10)
        np.testing.assert_allclose(J[i], w.jacobian(), atol=1e-10)


def test_batched_ik_equals_one_at_a_time() -> None:
    sc = load_scene("desk")
    w = World(sc, visual=False)
    q_home = home_configuration(w, sc.home.position, sc.home.rotation).q
    goals = sc.goal_set()
    q, ep, er = batch_ik(
        w, goals.positions, goals.rotations, q_home,
        tol_position=1e-3, tol_rotation=1e-2, max_iterations=200,
    )  # fmt: skip
    for i in range(goals.m):
        one = solve_ik(w, goals.positions[i], goals.rotations[i], q_home)
        np.testing.assert_allclose(q[i], one.q, atol=1e-8)
        assert abs(ep[i] - one.position_error) < 1e-9
        assert abs(er[i] - one.rotation_error) < 1e-9
