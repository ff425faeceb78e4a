"""A simulated Sawyer on Intera's own ROS topics, for ``bridge/intera_bridge.py`` without a robot.

A rospy node that behaves like the robot on the topics the bridge uses, its kinematics
legws's MuJoCo stand-in of the Sawyer (:class:`~legws_daemon.robot.world.World`, the
robot's own model):

* publishes ``/robot/joint_states`` (``sensor_msgs/JointState``: ``head_pan`` and
  ``right_j0`` .. ``right_j6``) and ``/robot/limb/right/endpoint_state``
  (``intera_core_msgs/EndpointState``, the EE in the base frame) at 100 Hz, and
  ``/robot/state`` (``RobotAssemblyState``) at 20 Hz;
* follows ``/robot/limb/right/joint_command`` (``JointCommand``): ``VELOCITY_MODE`` at the
  commanded speeds while commands keep coming — a command older than the command timeout
  (``/robot/limb/right/joint_command_timeout``, ``std_msgs/Float64``, 0.2 s until set) and
  the arm holds where it is, in position mode; ``POSITION_MODE`` to the commanded angles at
  0.3 of each joint's speed limit (Intera's default speed ratio); other modes are ignored;
* keeps every joint within its position limits and speed limit;
* ``/robot/set_super_enable`` (``std_msgs/Bool``) enables and disables; disabled or stopped,
  nothing moves; ``/robot/set_super_stop`` (``std_msgs/Empty``) is an e-stop: the arm stops
  at once, the robot is disabled, ``stopped`` with the e-stop source reported in
  ``/robot/state`` until ``/robot/set_super_reset``;
* an electric parallel gripper ``right_gripper`` on the end-effector IO topics
  (``/io/end_effector/state``, ``/io/end_effector/right_gripper/{state,command}``): the
  ``position_m`` signal, moving at 0.1 m/s while the robot is enabled.

Runs in legws's virtual environment with Debian's rospy (``python3-rospy``, the system
Python's packages are appended to the path) and the Intera message classes of
``bridge/ros/genmsgs.py`` on ``PYTHONPATH`` (or in ``.venv-ros/msgs``)::

    roscore &
    .venv/bin/python bridge/ros/sim_sawyer.py [--scene desk]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[2]
#: Debian's ROS 1 Python packages (rospy, genpy, std_msgs, ...), after legws's own.
ROS_DIST = "/usr/lib/python3/dist-packages"
for _path in (str(REPO), str(REPO / ".venv-ros" / "msgs"), ROS_DIST):
    if _path not in sys.path and Path(_path).is_dir():
        sys.path.append(_path)

import rospy  # noqa: E402
from geometry_msgs.msg import Pose, Twist  # noqa: E402
from intera_core_msgs.msg import (  # noqa: E402
    EndpointState,
    IOComponentCommand,
    IOComponentStatus,
    IODataStatus,
    IODeviceStatus,
    IONodeStatus,
    IOStatus,
    JointCommand,
    RobotAssemblyState,
)
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Bool, Empty, Float64  # noqa: E402

from legws_daemon.arms import arm  # noqa: E402
from legws_daemon.robot.kinematics import home_configuration  # noqa: E402
from legws_daemon.robot.world import World  # noqa: E402
from legws_daemon.scene.catalog import load_scene  # noqa: E402

#: The Sawyer's description: the robot's joint names, speed and position limits.
ARM = arm("sawyer")
JOINT_NAMES = tuple(ARM.hardware_joints)
DOF = len(JOINT_NAMES)
SPEED_LIMITS = np.array(ARM.speed_limits)
LOWER = np.array(ARM.lower)
UPPER = np.array(ARM.upper)
#: Intera's defaults: the command timeout, s, and the speed ratio of position moves.
COMMAND_TIMEOUT = 0.2
POSITION_SPEED_RATIO = 0.3
RATE_HZ = 100.0
STATE_RATE_HZ = 20.0
#: The longest step integrated at once, s (a stalled process does not jump the arm).
MAX_STEP = 0.05
GRIPPER = "right_gripper"
GRIPPER_OPEN = 0.041667
GRIPPER_SPEED = 0.1  # m/s


class SimArm:
    """The robot's joint controller (no ROS): modes, the command timeout, enable, e-stop,
    the limits; :meth:`step` integrates it. All methods take the lock."""

    def __init__(self, q0: np.ndarray) -> None:
        self.q = np.array(q0, dtype=np.float64)
        self.v = np.zeros(DOF)
        self.mode = JointCommand.POSITION_MODE
        self.target = self.q.copy()  # position mode's goal
        self.velocity = np.zeros(DOF)  # velocity mode's command
        self.commanded_at = -math.inf
        self.timeout = COMMAND_TIMEOUT
        self.enabled = False
        self.stopped = False
        self.estop_source = RobotAssemblyState.ESTOP_SOURCE_NONE
        self.gripper = GRIPPER_OPEN
        self.gripper_goal = GRIPPER_OPEN
        self.timeouts = 0  # velocity commands that ran out (the arm held)
        self.lock = threading.Lock()

    def command(self, msg: Any, now: float) -> None:
        names = list(msg.names)
        if not self.enabled or self.stopped or sorted(names) != sorted(JOINT_NAMES):
            return  # Intera ignores commands while disabled; the limb's seven joints only
        values = msg.velocity if msg.mode == JointCommand.VELOCITY_MODE else msg.position
        if msg.mode not in (JointCommand.VELOCITY_MODE, JointCommand.POSITION_MODE):
            return
        if len(values) != len(names) or not all(math.isfinite(x) for x in values):
            return
        vector = np.array([values[names.index(n)] for n in JOINT_NAMES])
        with self.lock:
            self.mode = msg.mode
            self.commanded_at = now
            if msg.mode == JointCommand.VELOCITY_MODE:
                self.velocity = np.clip(vector, -SPEED_LIMITS, SPEED_LIMITS)
            else:
                self.target = np.clip(vector, LOWER, UPPER)

    def set_timeout(self, seconds: float) -> None:
        if math.isfinite(seconds) and seconds > 0.0:
            with self.lock:
                self.timeout = seconds

    def enable(self, on: bool) -> None:
        with self.lock:
            if on and self.stopped:
                return  # a stopped robot must be reset first
            self.enabled = on
            self._hold()

    def estop(self) -> None:
        with self.lock:
            self.stopped, self.enabled = True, False
            self.estop_source = RobotAssemblyState.ESTOP_SOURCE_ENGINE
            self._hold()

    def reset(self) -> None:
        with self.lock:
            self.stopped, self.enabled = False, False
            self.estop_source = RobotAssemblyState.ESTOP_SOURCE_NONE
            self._hold()

    def set_gripper(self, opening: float) -> None:
        with self.lock:
            if self.enabled and not self.stopped and math.isfinite(opening):
                self.gripper_goal = min(max(opening, 0.0), GRIPPER_OPEN)

    def _hold(self) -> None:
        """Position mode at the current angles (the lock held)."""
        self.mode = JointCommand.POSITION_MODE
        self.target = self.q.copy()
        self.v = np.zeros(DOF)

    def step(self, dt: float, now: float) -> None:
        with self.lock:
            if not self.enabled or self.stopped:
                self.v = np.zeros(DOF)
                return
            if self.mode == JointCommand.VELOCITY_MODE:
                if now - self.commanded_at > self.timeout:
                    self.timeouts += 1
                    self._hold()
                    return
                v = self.velocity.copy()
            else:
                ratio = POSITION_SPEED_RATIO * SPEED_LIMITS
                v = np.clip((self.target - self.q) / dt, -ratio, ratio)
            q = np.clip(self.q + v * dt, LOWER, UPPER)
            self.v = (q - self.q) / dt
            self.q = q
            step = GRIPPER_SPEED * dt
            self.gripper += float(np.clip(self.gripper_goal - self.gripper, -step, step))

    def snapshot(self) -> tuple[np.ndarray, np.ndarray, float, bool]:
        with self.lock:
            moving = abs(self.gripper_goal - self.gripper) > 1e-6
            return self.q.copy(), self.v.copy(), self.gripper, moving


class SimSawyerNode:
    """The ROS side: the robot's topics around a :class:`SimArm`."""

    def __init__(self, scene: str, enabled: bool) -> None:
        s = load_scene(scene)
        self.world = World(s, arm=ARM, visual=False)
        q0 = home_configuration(self.world, s.home.position, s.home.rotation).q
        self.arm = SimArm(q0)
        self.arm.enabled = enabled
        self._io_commands: list[Any] = []
        self.joints = rospy.Publisher("/robot/joint_states", JointState, queue_size=10)
        self.endpoint = rospy.Publisher(
            "/robot/limb/right/endpoint_state", EndpointState, queue_size=10
        )
        self.state = rospy.Publisher("/robot/state", RobotAssemblyState, queue_size=10, latch=True)
        self.io_node = rospy.Publisher("/io/end_effector/state", IONodeStatus, queue_size=10)
        self.io_device = rospy.Publisher(
            f"/io/end_effector/{GRIPPER}/state", IODeviceStatus, queue_size=10
        )
        arm = self.arm
        self.subscribers = [
            rospy.Subscriber(
                "/robot/limb/right/joint_command",
                JointCommand,
                lambda m: arm.command(m, time.monotonic()),
                queue_size=1,
                tcp_nodelay=True,
            ),
            rospy.Subscriber(
                "/robot/limb/right/joint_command_timeout",
                Float64,
                lambda m: arm.set_timeout(m.data),
            ),
            rospy.Subscriber("/robot/set_super_enable", Bool, lambda m: arm.enable(m.data)),
            rospy.Subscriber("/robot/set_super_stop", Empty, lambda m: arm.estop()),
            rospy.Subscriber("/robot/set_super_reset", Empty, lambda m: arm.reset()),
            rospy.Subscriber(
                f"/io/end_effector/{GRIPPER}/command", IOComponentCommand, self._on_io_command
            ),
        ]

    def _on_io_command(self, msg: Any) -> None:
        try:
            args = json.loads(msg.args)
            opening = float(args["signals"]["position_m"]["data"][0])
        except (ValueError, KeyError, TypeError, IndexError):
            return
        if msg.op == "set":
            self.arm.set_gripper(opening)
            self._io_commands = [*self._io_commands[-9:], msg.time]

    def publish(self, tick: int) -> None:
        q, v, opening, moving = self.arm.snapshot()
        stamp = rospy.Time.now()
        joints = JointState()
        joints.header.stamp = stamp
        joints.name = ["head_pan", *JOINT_NAMES]
        joints.position = [0.0, *q.tolist()]
        joints.velocity = [0.0, *v.tolist()]
        joints.effort = [0.0] * 8
        self.joints.publish(joints)
        self.world.set_q(q)
        p = self.world.ee_position()
        w, x, y, z = self.world.ee_pose().quaternion
        twist = self.world.jacobian() @ v
        end = EndpointState(valid=True)
        end.header.stamp = stamp
        end.header.frame_id = "base"
        end.pose = Pose()
        end.pose.position.x, end.pose.position.y, end.pose.position.z = p.tolist()
        o = end.pose.orientation
        o.w, o.x, o.y, o.z = float(w), float(x), float(y), float(z)
        end.twist = Twist()
        end.twist.linear.x, end.twist.linear.y, end.twist.linear.z = twist[:3].tolist()
        end.twist.angular.x, end.twist.angular.y, end.twist.angular.z = twist[3:].tolist()
        self.endpoint.publish(end)
        if tick % int(RATE_HZ / STATE_RATE_HZ) == 0:
            self.publish_state(stamp, opening, moving)

    def publish_state(self, stamp: Any, opening: float, moving: bool) -> None:
        with self.arm.lock:
            enabled, stopped, source = self.arm.enabled, self.arm.stopped, self.arm.estop_source
        button = (
            RobotAssemblyState.ESTOP_BUTTON_UNKNOWN
            if stopped
            else RobotAssemblyState.ESTOP_BUTTON_UNPRESSED
        )
        self.state.publish(
            RobotAssemblyState(
                homed=True,
                ready=enabled,
                enabled=enabled,
                stopped=stopped,
                error=False,
                lowVoltage=False,
                estop_button=button,
                estop_source=source,
            )
        )
        ready = IOStatus(tag=IOStatus.READY)
        self.io_node.publish(
            IONodeStatus(
                time=stamp,
                node=IOComponentStatus(name="end_effector", status=ready),
                devices=[IOComponentStatus(name=GRIPPER, status=ready)],
            )
        )

        def signal(name: str, kind: str, value: Any) -> IODataStatus:
            fmt = json.dumps({"type": kind, "role": "output"})
            return IODataStatus(name=name, format=fmt, data=json.dumps([value]), status=ready)

        self.io_device.publish(
            IODeviceStatus(
                time=stamp,
                device=IOComponentStatus(name=GRIPPER, status=ready),
                signals=[
                    signal("position_m", "float", opening),
                    signal("position_response_m", "float", opening),
                    signal("is_moving", "bool", moving),
                    signal("is_calibrated", "bool", True),
                    signal("has_error", "bool", False),
                ],
                commands=list(self._io_commands),
            )
        )

    def run(self) -> None:
        rate = rospy.Rate(RATE_HZ)
        tick = 0
        last = time.monotonic()
        while not rospy.is_shutdown():
            now = time.monotonic()
            # real time passes (a late tick moves the arm as far as the time it took)
            self.arm.step(min(max(now - last, 1e-4), MAX_STEP), now)
            last = now
            self.publish(tick)
            tick += 1
            try:
                rate.sleep()
            except rospy.ROSInterruptException:
                break


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sim_sawyer.py", description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="desk", help="the scene whose home pose it starts at")
    parser.add_argument(
        "--disabled", action="store_true", help="start disabled (the bridge enables it)"
    )
    args = parser.parse_args(rospy.myargv(argv=list(sys.argv[1:] if argv is None else argv)))
    rospy.init_node("sim_sawyer")
    node = SimSawyerNode(args.scene, enabled=not args.disabled)
    rospy.loginfo(f"sim_sawyer: on the {args.scene} scene, {RATE_HZ:g} Hz")
    node.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
