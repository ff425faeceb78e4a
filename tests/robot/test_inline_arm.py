"""The arm-generic robot code on a small inline arm (tests/robot/inline_arm.py): no fetched
model, six joints about x, y and z, compiled in milliseconds."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.robot.batch_kinematics import BatchKinematics, batch_ik
from legws_daemon.robot.kinematics import home_configuration, velocity_step
from legws_daemon.robot.mink_ik import MinkVelocityIK
from legws_daemon.robot.reachability import cache_key
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from tests.robot.inline_arm import SMALL_ARM

LIMITS = np.array(SMALL_ARM.speed_limits)


@pytest.fixture
def world(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> World:
    monkeypatch.setenv("LEGWS_ASSETS", str(tmp_path / "nothing-fetched"))
    scene = load_scene("tea")
    w = World(scene, arm=SMALL_ARM)
    home_configuration(w, scene.home.position, scene.home.rotation)
    return w


def test_the_inline_arm_is_a_world_without_any_fetched_model(world: World) -> None:
    assert world.dof == 6 and world.jacobian().shape == (6, 6)
    np.testing.assert_allclose(world.ee_position(), world.scene.home.position, atol=1e-3)
    assert world.arm_contacts() == []
    # the mount is where the base stands; the joint ranges are the description's
    np.testing.assert_allclose(world.data.xpos[world.model.body("small/base").id], [0.05, 0, 0])
    np.testing.assert_allclose(world.model.jnt_range[:6], SMALL_ARM.position_limits)
    # the free joint (the flange roll) is mid-range at home
    assert abs(world.q[5]) < 0.1


def test_batched_kinematics_and_ik_are_mujocos_on_joints_about_x_y_and_z(world: World) -> None:
    kin = BatchKinematics(world)
    assert not all(lk.about_z for lk in kin.links)  # the general path is exercised
    rng = np.random.default_rng(3)
    qs = rng.uniform(world.arm.lower, world.arm.upper, size=(8, 6))
    ee, R, J = kin.forward(qs)
    for i, q in enumerate(qs):
        world.set_q(q)
        np.testing.assert_allclose(ee[i], world.ee_position(), atol=1e-12)
        np.testing.assert_allclose(R[i], world.ee_rotation(), atol=1e-12)
        np.testing.assert_allclose(J[i], world.jacobian(), atol=1e-12)
    # IK back to the poses of random configurations near the ready posture
    seeds = np.array(SMALL_ARM.ready_posture) + rng.normal(0, 0.2, size=(8, 6))
    ee, R, _ = kin.forward(seeds)
    q, ep, er = batch_ik(world, ee, R, np.array(SMALL_ARM.ready_posture), tol_position=1e-4,
                         tol_rotation=1e-3, max_iterations=200)  # fmt: skip
    assert q.shape == (8, 6) and np.all(ep < 1e-4) and np.all(er < 1e-3)


def test_a_velocity_step_tracks_the_twist_within_the_arms_limits(world: World) -> None:
    start = world.ee_position()
    twist = np.array([0.05, 0.03, -0.02, 0.0, 0.0, 0.0])
    for _ in range(20):
        res = velocity_step(world, twist, 0.05)
        assert np.all(np.abs(res.qdot) <= LIMITS * (1 + 1e-9))
    moved = world.ee_position() - start
    np.testing.assert_allclose(moved, twist[:3] * 1.0, atol=5e-3)
    assert np.all(world.q >= world.arm.lower) and np.all(world.q <= world.arm.upper)


def test_minks_ik_keeps_to_the_arms_joint_speeds(world: World) -> None:
    ik = MinkVelocityIK(world)
    np.testing.assert_array_equal(ik.speed_limits, LIMITS)
    dq = ik.joint_velocity(world.q, np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0]), 0.05)
    assert dq.shape == (6,) and np.all(np.abs(dq) <= LIMITS + 1e-12)
    assert np.any(np.isclose(np.abs(dq), LIMITS))  # a fast twist saturates a joint
    assert not ik.joint_velocity(world.q, np.zeros(6), 0.05).any()


def test_the_reachability_key_is_the_arms(world: World) -> None:
    key = cache_key(world, world.q)
    longer = dataclasses.replace(
        SMALL_ARM,
        model_xml=SMALL_ARM.model_xml.replace('0.45 0 0"', '0.46 0 0"'),  # type: ignore[union-attr]
    )
    other = World(world.scene, arm=longer)
    assert cache_key(other, world.q) != key  # another model, another map


def test_an_inline_model_mujoco_refuses_is_one_line_naming_the_arm() -> None:
    bad = dataclasses.replace(SMALL_ARM, model_xml="<mujoco><worldbody><body>")
    with pytest.raises(InputError, match="MuJoCo cannot load the inline model of arm small"):
        World(load_scene("tea"), arm=bad)
