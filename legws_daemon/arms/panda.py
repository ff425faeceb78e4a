"""Franka Emika Panda / FR3 (7 DoF). Limits from Franka's datasheet (FCI documentation);
mounted at the table's near edge, 0.12 m in front of the Sawyer's base (its reach, 0.855 m,
is shorter than the Sawyer's 1.26 m)."""

from __future__ import annotations

from legws_daemon.arms.spec import ArmSpec, Mount

ARM = ArmSpec(
    name="panda",
    title="Franka Panda",
    asset_folder="panda",
    joint_names=tuple(f"joint{i}" for i in range(1, 8)),
    position_limits=(
        (-2.8973, 2.8973),
        (-1.7628, 1.7628),
        (-2.8973, 2.8973),
        (-3.0718, -0.0698),
        (-2.8973, 2.8973),
        (-0.0175, 3.7525),
        (-2.8973, 2.8973),
    ),
    speed_limits=(2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
    ready_posture=(0.0, 0.0, 0.0, -2.0, 0.0, 2.0, 0.0),
    home_seeds=((0.0, 0.3, 0.0, -1.8, 0.0, 2.1, 0.0), (0.0, -0.3, 0.0, -2.4, 0.0, 2.1, 0.0)),
    # the hand turned so that the last joint is mid-range (not 2.3 rad) at the home pose
    flange_yaw=2.3,
    free_joints=(6,),
    mount=Mount(x=0.12),
    # nearer than 25 cm to its axis the elbow (joint 4, at most -0.07 rad) folds against its
    # limit and a straight approach stalls (measured: picks 18 cm from the axis fail, from
    # 26 cm on every one completes; benchmarks/arms.py, docs/robots.md)
    min_reach=0.25,
    hardware_joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)),
)
