"""The robot descriptions: every registered arm is complete, consistent with its model, and
importable by a bridge (standard library only, Python 3.8)."""

from __future__ import annotations

import ast
import dataclasses
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from legws_daemon.arms import DEFAULT_ARM, ArmSpec, arm, arm_names
from legws_daemon.robot.batch_kinematics import BatchKinematics
from legws_daemon.robot.feasibility import check_grasp, far_enough, ik_seeds
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World, robot_model
from legws_daemon.scene.catalog import load_scene

ARMS = Path(__file__).parents[2] / "legws_daemon" / "arms"


def test_the_registry_holds_the_four_arms_the_default_first() -> None:
    assert arm_names() == ("sawyer", "kinova3", "panda", "ur5e")
    assert DEFAULT_ARM == "sawyer"
    assert [arm(n).dof for n in arm_names()] == [7, 7, 7, 6]
    with pytest.raises(KeyError, match="expected one of: sawyer, kinova3, panda, ur5e"):
        arm("baxter")


@pytest.mark.parametrize("path", sorted(ARMS.glob("*.py")), ids=lambda p: p.name)
def test_a_description_is_standard_library_python_3_8(path: Path) -> None:
    """What a bridge on the robot's own computer (Python 3.8, no numpy) can import."""
    tree = ast.parse(path.read_text(), feature_version=(3, 8))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import | ast.ImportFrom):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                assert top in sys.stdlib_module_names or name.startswith("legws_daemon.arms"), (
                    path.name,
                    name,
                )
        # annotations stay strings (from __future__ import annotations); nothing else may
        # subscript a builtin at run time on 3.8
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Subscript):
            base = node.value.value
            assert not (isinstance(base, ast.Name) and base.id in {"tuple", "dict", "list"})


def test_a_bad_description_is_refused_naming_the_arm_and_the_field() -> None:
    sawyer = arm("sawyer")
    with pytest.raises(ValueError, match="arm sawyer: speed_limits has 6 entries, expected 7"):
        dataclasses.replace(sawyer, speed_limits=sawyer.speed_limits[:6])
    with pytest.raises(ValueError, match="ready posture out of joint 3's range"):
        dataclasses.replace(sawyer, ready_posture=(0.0, 0.0, 0.0, 9.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="free_joints names a joint it does not have"):
        dataclasses.replace(sawyer, free_joints=(7,))


@pytest.mark.slow
@pytest.mark.parametrize("name", arm_names())
def test_each_arm_is_its_model_and_reaches_the_tea_home_clear_of_the_table(name: str) -> None:
    spec: ArmSpec = arm(name)
    m = robot_model(name)
    for joint, (lo, hi) in zip(spec.joint_names, spec.position_limits, strict=True):
        j = m.joint(joint)
        assert j.type[0] == mujoco.mjtJoint.mjJNT_HINGE
        np.testing.assert_allclose(j.range, [lo, hi])
    scene = load_scene("tea")
    world = World(scene, arm=name)
    assert world.dof == spec.dof and world.jacobian().shape == (6, spec.dof)
    # the base stands at its mount in table coordinates
    base = world.model.body(f"{spec.prefix}base").id
    np.testing.assert_allclose(world.data.xpos[base], [spec.mount.x, spec.mount.y, spec.mount.z])
    home = home_configuration(world, scene.home.position, scene.home.rotation)
    assert home.converged
    np.testing.assert_allclose(world.ee_position(), scene.home.position, atol=1e-3)
    assert world.arm_contacts() == []
    # the free wrist joint sits off its limits at home (room to follow a grasp's yaw)
    for j in spec.free_joints:
        lo, hi = spec.position_limits[j]
        assert min(home.q[j] - lo, hi - home.q[j]) > 1.0, (name, home.q[j])
    # the batched chain is MuJoCo's, whatever the axes of the arm's joints
    rng = np.random.default_rng(1)
    qs = rng.uniform(world.arm.lower, world.arm.upper, size=(3, spec.dof))
    ee, R, J = BatchKinematics(world).forward(qs)
    for i, q in enumerate(qs):
        world.set_q(q)
        np.testing.assert_allclose(ee[i], world.ee_position(), atol=1e-12)
        np.testing.assert_allclose(R[i], world.ee_rotation(), atol=1e-12)
        np.testing.assert_allclose(J[i], world.jacobian(), atol=1e-12)


def test_a_grasp_nearer_the_base_than_the_arm_reaches_is_refused_by_check_and_map() -> None:
    panda = arm("panda")
    assert panda.min_reach == 0.25 and arm("sawyer").min_reach == 0.0
    near = [panda.mount.x + 0.18, 0.0, 0.01]
    far = [panda.mount.x + 0.26, 0.0, 0.01]
    assert far_enough(panda, np.array([near, far])).tolist() == [False, True]
    assert far_enough(arm("sawyer"), np.array([near])).tolist() == [True]
    scene = load_scene("lego")
    world = World(scene, arm="panda", visual=False)
    q_home = home_configuration(world, scene.home.position, scene.home.rotation).q
    check = check_grasp(world, "red_brick", np.array(near), np.diag([1.0, -1.0, -1.0]), 2,
                        scene.home.rotation, ik_seeds(world, q_home))  # fmt: skip
    assert not check.feasible
    assert check.reason == (
        "too close to the arm's base: 18 cm from its axis, the Franka Panda grasps from 25 cm"
    )
