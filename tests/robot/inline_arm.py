"""A small arm given inline (six hinges, capsules, no meshes): for tests of the arm-generic
code where the full robot is not the point — it compiles in milliseconds and needs no
fetched model. Its joints turn about the x, y and z axes of their bodies, so the generic
paths (not only turns about z) are exercised; like most hand-written MJCF it reads angles
in MuJoCo's default degrees, which the world's joint ranges (radians) are converted to."""

from __future__ import annotations

import math

from legws_daemon.arms import ArmSpec, Mount

XML = """
<mujoco model="small_arm">
  <worldbody>
    <body name="base">
      <geom type="cylinder" size="0.06 0.15" pos="0 0 0.15"/>
      <body name="l1" pos="0 0 0.3">
        <joint name="j1" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.05" size="0.05"/>
        <body name="l2" pos="0 0 0.05">
          <joint name="j2" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.45 0 0" size="0.04"/>
          <body name="l3" pos="0.45 0 0">
            <joint name="j3" axis="0 1 0"/>
            <geom type="capsule" fromto="0 0 0 0.35 0 0" size="0.035"/>
            <body name="l4" pos="0.35 0 0">
              <joint name="j4" axis="1 0 0"/>
              <geom type="capsule" fromto="0 0 0 0.06 0 0" size="0.03"/>
              <body name="l5" pos="0.06 0 0">
                <joint name="j5" axis="0 1 0"/>
                <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.03"/>
                <body name="l6" pos="0.05 0 0">
                  <joint name="j6" axis="1 0 0"/>
                  <geom type="cylinder" fromto="0 0 0 0.02 0 0" size="0.035"/>
                  <body name="right_hand" pos="0.02 0 0" quat="0.7071068 0 0.7071068 0"/>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

SMALL_ARM = ArmSpec(
    name="small",
    title="small test arm",
    asset_folder="(inline)",
    joint_names=tuple(f"j{i}" for i in range(1, 7)),
    position_limits=(
        (-3.0, 3.0),
        (-2.0, 2.0),
        (-2.6, 2.6),
        (-3.0, 3.0),
        (-2.2, 2.2),
        (-math.pi, math.pi),
    ),
    speed_limits=(2.0, 2.0, 2.0, 3.0, 3.0, 3.0),
    ready_posture=(0.0, -1.1, 1.9, 0.0, 0.8, 0.0),
    free_joints=(5,),
    flange_yaw=-math.pi / 2,  # the flange roll mid-range at the home pose
    mount=Mount(x=0.05),
    model_xml=XML,
)
