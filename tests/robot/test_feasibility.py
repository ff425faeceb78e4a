"""Grasp feasibility: reachability and collisions, each with its reason."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.robot.feasibility import check_grasps
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene, scene_names
from legws_daemon.scene.scene import ObjectPose


def world_of(name: str) -> tuple[World, np.ndarray]:
    sc = load_scene(name)
    w = World(sc)
    return w, home_configuration(w, sc.home.position, sc.home.rotation).q


@pytest.mark.parametrize("name", scene_names())
def test_default_layouts_are_grasp_feasible(name: str) -> None:
    w, q = world_of(name)
    sc = w.scene
    checks = check_grasps(w, sc.goal_set(goals=list(sc.movable)), q)
    assert {n: c.reason for n, c in checks.items() if not c.feasible} == {}


def test_out_of_reach_is_flagged_with_its_reason() -> None:
    w, q = world_of("desk")
    sc = w.scene
    # the workspace allows x up to 0.85; a stapler turned so that its top grasp needs the
    # wrist far out and low at the table's far corner, plus a mug whose side grasp faces
    # away from the robot: the gripper would have to reach around it from behind
    layout = {"white_mug": ObjectPose(0.84, 0.44, np.pi)}
    goals = sc.goal_set(layout)
    checks = check_grasps(w, goals, q, sc.poses(layout))
    mug = checks["white_mug"]
    assert not mug.feasible
    assert mug.reason.startswith("out of reach")
    assert checks["black_stapler"].feasible


def test_collision_with_a_neighbour_is_flagged_with_its_reason() -> None:
    w, q = world_of("desk")
    sc = w.scene
    # the stapler right in front of the mug's side grasp: the gripper must pass through it
    mug = sc.poses()["white_mug"]
    layout = {"black_stapler": ObjectPose(mug.x - 0.13, mug.y, np.pi / 2)}
    checks = check_grasps(w, sc.goal_set(layout), q, sc.poses(layout))
    assert not checks["white_mug"].feasible
    assert checks["white_mug"].reason.startswith("collides with black_stapler")
    assert w.arm_contacts() == []  # the arm is left at home


def test_a_grasp_under_the_table_top_collides_with_the_table() -> None:
    w, q = world_of("cluttered")
    from legws_daemon.core.geometry import Pose
    from legws_daemon.core.goals import GoalSet

    sc = w.scene
    g = sc.goal_set(goals=["red_block", "blue_block"])
    low = g.positions.copy()
    low[0, 2] = -0.005  # fingertips 5 mm into the table
    goals = GoalSet(
        g.names, low, g.quaternions, g.symmetry, Pose(sc.home.position, sc.home.quaternion)
    )
    checks = check_grasps(w, goals, q)
    assert not checks["red_block"].feasible
    assert "table" in checks["red_block"].reason
