"""Kinova Gen3 (7 DoF). Speed limits from Kinova's specification (80 °/s the large
actuators, 70 °/s the small ones); its continuous joints are kept within ±2π (the bridge
and the planner never wrap). Mounted at the table's near edge (reach 0.90 m)."""

from __future__ import annotations

import math

from legws_daemon.arms.spec import ArmSpec, Mount

_TURN = (-2 * math.pi, 2 * math.pi)

ARM = ArmSpec(
    name="kinova3",
    title="Kinova Gen3",
    asset_folder="kinova3",
    joint_names=tuple(f"Actuator{i}" for i in range(1, 8)),
    position_limits=(_TURN, (-2.41, 2.41), _TURN, (-2.66, 2.66), _TURN, (-2.23, 2.23), _TURN),
    speed_limits=(1.396, 1.396, 1.396, 1.396, 1.222, 1.222, 1.222),
    ready_posture=(0.0, 0.26, 3.14, -2.27, 0.0, 0.96, 1.57),
    home_seeds=((0.0, 0.6, 3.14, -2.0, 0.0, 1.2, 1.57), (0.0,) * 7),
    free_joints=(6,),
    mount=Mount(x=0.10),
    hardware_joint_names=tuple(f"joint_{i}" for i in range(1, 8)),
)
