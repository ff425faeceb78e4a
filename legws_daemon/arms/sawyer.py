"""Rethink Robotics Sawyer (7 DoF): the arm of the paper. Limits from the Intera
specification and robosuite's description; its base defines table coordinates."""

from __future__ import annotations

from legws_daemon.arms.spec import ArmSpec

ARM = ArmSpec(
    name="sawyer",
    title="Rethink Sawyer",
    asset_folder="sawyer",
    joint_names=tuple(f"right_j{i}" for i in range(7)),
    position_limits=(
        (-3.0503, 3.0503),
        (-3.8095, 2.2736),
        (-3.0426, 3.0426),
        (-3.0439, 3.0439),
        (-2.9761, 2.9761),
        (-2.9761, 2.9761),
        (-4.7124, 4.7124),
    ),
    speed_limits=(1.74, 1.328, 1.957, 1.957, 3.485, 3.485, 4.545),
    ready_posture=(0.0, -0.6, 0.0, 1.4, 0.0, 0.8, 0.0),
    home_seeds=((0.0, -1.0, 0.0, 2.0, 0.0, 0.6, 0.0), (0.0,) * 7),
    free_joints=(6,),
    # the meshes' convex hulls collide: tighter than the description's primitives, which make
    # every side grasp below ~7 cm hit the table; base, shoulder and head keep the primitives
    mesh_collision_bodies=frozenset(f"right_l{i}" for i in range(1, 7)),
    primitive_bodies=frozenset({"right_l1_2", "right_l2_2", "right_l4_2"}),
)
