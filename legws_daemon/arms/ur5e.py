"""Universal Robots UR5e (6 DoF, no redundancy). Joint speed limits from UR's datasheet
(180 °/s every joint); legws keeps the ±2π joints within ±π of their zero, away from the
cable wraps. Mounted at the table's near edge like the Panda (reach 0.85 m)."""

from __future__ import annotations

import math

from legws_daemon.arms.spec import ArmSpec, Mount

ARM = ArmSpec(
    name="ur5e",
    title="Universal Robots UR5e",
    asset_folder="ur5e",
    joint_names=(
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    ),
    position_limits=((-math.pi, math.pi),) * 6,
    speed_limits=(math.pi,) * 6,
    ready_posture=(0.0, -1.3, 1.6, -1.87, -1.57, 0.0),
    home_seeds=((0.0, -1.0, 1.8, -2.4, -1.57, 0.0), (0.3, -1.6, 1.4, -1.4, -1.57, 0.0)),
    free_joints=(5,),
    mount=Mount(x=0.12),
)
