#!/usr/bin/env python3
"""legws bridge for a Rethink Sawyer: Intera joint states out, joint velocity commands in.

Runs on the robot's PC (ROS Noetic, Intera SDK, Python >= 3.8, ``pip install
eclipse-zenoh``) and implements the bridge contract of ``docs/bridge.md``. It talks to the
robot on Intera's own ROS topics through rospy (joint states, endpoint state, joint
commands with the robot's command timeout, enable and state, e-stop, the end-effector IO;
:class:`RosLimb`, :class:`RosEnable`, :func:`find_gripper`):

* ``legws/<robot>/bridge/state`` (published at 100 Hz, the bridge's heartbeat):
  ``{"schema": 1, "seq", "stamp", "q": [7], "dq": [7], "gripper", "enabled", "estop"}``
  from ``/robot/joint_states`` and ``/robot/state``, joints ``right_j0`` .. ``right_j6``.
* ``legws/<robot>/bridge/command`` (subscribed):
  ``{"schema": 1, "seq", "stamp", "mode": "joint_velocity", "dq": [7], "ttl", "gripper"}``.
  A command is applied as ``JointCommand`` in velocity mode until its ``ttl`` runs out (the
  deadman), then the arm holds its position (position mode at the measured angles). A
  command with a non-finite or over-limit value, or any other invalid field, is rejected
  and stops the arm. Nothing moves while the robot is disabled or e-stopped.
* Its own limits, whatever it is sent (the profile's ``[bridge]`` and ``[workspace]``:
  flags, or ``--profile PATH``): commands beyond a rate are refused and stop the arm;
  joint speeds are scaled down to a cap; a command moves the arm at most ``max_ttl``; the
  endpoint's speed is held to a cap and a step whose endpoint leaves the workspace box
  (+ margin) stops the arm, both judged by the forward kinematics of the commanded step
  (the arm's chain, ``bridge/chains/sawyer.json``; without it, the weaker mode on Intera's
  measured endpoint twist). These rules are legws's one guard of every bridge,
  ``legws_daemon/safety/limits.py``. The state's ``limited`` lists what was enforced.
* ``legws/<robot>/stop/*`` (subscribed): any sample stops the arm and latches; commands
  are ignored until a valid ``legws/<robot>/bridge/resume``. The state's ``stopped_by``
  names the role (the key's last chunk).

Standalone on purpose: it imports only rospy, the ROS messages (``std_msgs``,
``sensor_msgs`` and Intera's ``intera_core_msgs``), zenoh, the standard library and two
standard-library parts of legws found in the folder above this file's (the checkout, with
``legws_daemon/safety/limits.py``, ``legws_daemon/arms`` and ``bridge/chains``). The
message checks and the deadman are plain functions and classes, tested in the legws
repository with fake ROS modules, and the whole file against a real ROS master and a
simulated Sawyer (``bridge/ros/sim_sawyer.py``).

Usage (see bridge/README.md)::

    python3 intera_bridge.py                              # loopback: connect tcp/127.0.0.1:7447
    python3 intera_bridge.py --zenoh-config robot.json5   # the real network
    python3 intera_bridge.py --profile sawyer.toml        # limits from a legws profile
"""

# zip(strict=...) needs Python 3.10; the robot's PC may run ROS Noetic's Python 3.8.
# ruff: noqa: B905
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import rospy
import zenoh
from intera_core_msgs.msg import (
    EndpointState,
    IOComponentCommand,
    IODeviceStatus,
    IONodeStatus,
    JointCommand,
    RobotAssemblyState,
)
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Empty, Float64

# The limits and the joint tables every legws bridge shares (standard library, Python 3.8):
# legws_daemon/safety/limits.py and legws_daemon/arms, found in the folder above this one
# (the checkout this file is in, or the folder `legws bridge bundle` writes).
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)
from legws_daemon.arms import arm  # noqa: E402
from legws_daemon.safety import limits as guard_limits  # noqa: E402

ARM = arm("sawyer")
#: The chain of the arm's forward kinematics (base frame to the daemon's EE point).
CHAIN_FILE = os.path.join(_ROOT, "bridge", "chains", ARM.name + ".json")

SCHEMA = 1
#: Intera's joint names: the order of every joint vector on the wire.
JOINT_NAMES = ARM.hardware_joints
#: Joint speed limits, rad/s (Intera specification).
SPEED_LIMITS = ARM.speed_limits
#: Joint position limits, rad.
LOWER = ARM.lower
UPPER = ARM.upper
#: A commanded speed may exceed its limit by this much (floating-point slack), rad/s.
SPEED_TOLERANCE = 1e-6
#: Longest time-to-live of one command, s.
MAX_TTL = 1.0
#: A joint this close to a position limit is not driven further toward it, rad.
LIMIT_GUARD = 0.01
#: Largest command payload accepted, bytes.
MAX_PAYLOAD = 64 * 1024
#: Largest sequence number (a signed 64-bit integer).
MAX_SEQ = 2**63 - 1
STATE_RATE_HZ = 100.0
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
GRIPPER_REQUESTS = ("open", "closed")
_COMMAND_FIELDS = frozenset({"schema", "seq", "stamp", "mode", "dq", "ttl", "gripper"})
_STOP_FIELDS = frozenset({"schema", "stamp", "source", "reason"})
_RESUME_FIELDS = frozenset({"schema", "seq", "stamp"})
#: The roles that stop the robot on ``legws/<robot>/stop/<role>`` (another key: "unknown").
STOP_ROLES = ("operator", "observer", "safety", "bridge", "daemon")
#: The limits the bridge enforces itself, as the state's ``limited`` names them.
LIMITS = ("joint_speed", "ee_speed", "workspace", "ttl", "rate")

# The bridge's own limits: the defaults of a legws profile's [bridge] and [workspace]
# tables (legws_daemon/formats/profile.py); --profile or the flags set others.
JOINT_SPEED_CAP = guard_limits.JOINT_SPEED_CAP
EE_SPEED_CAP = guard_limits.EE_SPEED_CAP
WORKSPACE = guard_limits.WORKSPACE
WORKSPACE_MARGIN = guard_limits.WORKSPACE_MARGIN
TTL_CAP = guard_limits.TTL_CAP
COMMAND_RATE_HZ = guard_limits.COMMAND_RATE_HZ
COMMAND_BURST = guard_limits.COMMAND_BURST


class CommandError(ValueError):
    """A command payload that does not follow the contract; the message names the field."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        super().__init__(f"{field}: {message}")


@dataclass(frozen=True)
class Command:
    """A validated joint velocity command."""

    seq: int
    stamp: float
    dq: tuple[float, ...]  # 7 joint velocities, rad/s, within the speed limits
    ttl: float  # seconds the command stays valid after its receipt
    gripper: str | None  # "open", "closed" or None (no request)


def _number(value: Any, field: str) -> float:
    """A finite JSON number (booleans are not numbers)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CommandError(field, f"expected a number, got {value!r}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the float range
        number = math.inf
    if not math.isfinite(number):
        raise CommandError(field, f"expected a finite number, got {value!r}")
    return number


def parse_command(payload: bytes) -> Command:
    """Validate one command payload (JSON); raises :class:`CommandError` naming the field."""
    if len(payload) > MAX_PAYLOAD:
        raise CommandError("payload", f"{len(payload)} bytes exceed {MAX_PAYLOAD}")
    try:
        data = json.loads(payload)
    except (ValueError, RecursionError) as err:  # JSONDecodeError and UnicodeDecodeError
        raise CommandError("payload", f"not JSON: {type(err).__name__}") from None
    if not isinstance(data, dict):
        raise CommandError("payload", "expected a JSON object")
    unknown = sorted(str(k) for k in data if k not in _COMMAND_FIELDS)
    if unknown:
        raise CommandError(unknown[0], "unknown field")
    for name in ("schema", "seq", "stamp", "mode", "dq", "ttl"):
        if name not in data:
            raise CommandError(name, "missing")
    if data["schema"] != SCHEMA:
        raise CommandError("schema", f"unsupported schema {data['schema']!r}; expected {SCHEMA}")
    seq = data["seq"]
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= MAX_SEQ:
        raise CommandError("seq", f"expected an integer in [0, 2^63 - 1], got {seq!r}")
    stamp = _number(data["stamp"], "stamp")
    if data["mode"] != "joint_velocity":
        raise CommandError("mode", f"expected 'joint_velocity', got {data['mode']!r}")
    raw = data["dq"]
    if not isinstance(raw, list) or len(raw) != len(JOINT_NAMES):
        raise CommandError("dq", f"expected a list of {len(JOINT_NAMES)} joint velocities")
    dq = tuple(_number(v, f"dq[{i}]") for i, v in enumerate(raw))
    for i, (v, limit) in enumerate(zip(dq, SPEED_LIMITS)):
        if abs(v) > limit + SPEED_TOLERANCE:
            raise CommandError(
                f"dq[{i}]", f"{JOINT_NAMES[i]} speed {v:g} rad/s exceeds its limit {limit:g}"
            )
    ttl = _number(data["ttl"], "ttl")
    if not 0.0 < ttl <= MAX_TTL:
        raise CommandError("ttl", f"expected 0 < ttl <= {MAX_TTL:g} s, got {ttl:g}")
    gripper = data.get("gripper")
    if gripper is not None and gripper not in GRIPPER_REQUESTS:
        raise CommandError("gripper", f"expected 'open', 'closed' or null, got {gripper!r}")
    return Command(seq, stamp, dq, ttl, gripper)


#: Characters no text of a message may hold (as legws_daemon.formats.validation): C0/C1
#: controls but tab and line feed, line/paragraph separators, bidirectional controls.
_UNSAFE_TEXT = re.compile(
    "[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028\u2029\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069]"
)


def _text(value: Any, field: str, longest: int) -> None:
    if value is not None and (not isinstance(value, str) or len(value) > longest):
        raise CommandError(field, f"expected a string of at most {longest} characters or null")
    if isinstance(value, str) and _UNSAFE_TEXT.search(value):
        raise CommandError(field, "holds a control or bidirectional character")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key {key!r} appears twice")
        out[key] = value
    return out


def _json_object(payload: bytes, fields: frozenset[str]) -> dict[str, Any]:
    """A JSON object of ``schema`` 1 with no other fields than ``fields``."""
    if len(payload) > MAX_PAYLOAD:
        raise CommandError("payload", f"{len(payload)} bytes exceed {MAX_PAYLOAD}")
    try:
        data = json.loads(payload, object_pairs_hook=_unique_keys)
    except (ValueError, RecursionError) as err:
        raise CommandError("payload", f"not JSON: {type(err).__name__}") from None
    if not isinstance(data, dict):
        raise CommandError("payload", "expected a JSON object")
    unknown = sorted(str(k) for k in data if k not in fields)
    if unknown:
        raise CommandError(unknown[0], "unknown field")
    if "schema" not in data:
        raise CommandError("schema", "missing")
    if data["schema"] != SCHEMA:
        raise CommandError("schema", f"unsupported schema {data['schema']!r}; expected {SCHEMA}")
    return data


def check_stop(payload: bytes) -> None:
    """Validate a stop payload (empty: no detail); raises :class:`CommandError`. A stop
    stops whatever its payload: this only decides whether it is counted as invalid."""
    if not payload:
        return
    data = _json_object(payload, _STOP_FIELDS)
    if data.get("stamp") is not None:
        _number(data["stamp"], "stamp")
    _text(data.get("source"), "source", 64)
    _text(data.get("reason"), "reason", 200)


def check_resume(payload: bytes) -> None:
    """Validate a resume payload ``{"schema": 1, "seq", "stamp"}``; raises CommandError."""
    data = _json_object(payload, _RESUME_FIELDS)
    for name in ("seq", "stamp"):
        if name not in data:
            raise CommandError(name, "missing")
    seq = data["seq"]
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= MAX_SEQ:
        raise CommandError("seq", f"expected an integer in [0, 2^63 - 1], got {seq!r}")
    _number(data["stamp"], "stamp")


def stop_role(key: str) -> str:
    """The role of a stop key (its last chunk), ``unknown`` for any other."""
    role = key.rsplit("/", 1)[-1]
    return role if role in STOP_ROLES else "unknown"


#: The bridge's own limits (a profile's [bridge] and [workspace]): the module's.
Limits = guard_limits.BridgeLimits


#: A legws profile's [bridge] and [workspace] (the module's reader; Python >= 3.11).
profile_limits = guard_limits.profile_limits


def endpoint_state(limb: Any) -> tuple[list[float], list[float]] | None:
    """Intera's endpoint position and linear velocity (base frame), or ``None`` when the
    robot has not reported them (yet) or they are not finite."""
    try:
        p = limb.endpoint_pose()["position"]
        v = limb.endpoint_velocity()["linear"]
        position = [float(p.x), float(p.y), float(p.z)]
        linear = [float(v.x), float(v.y), float(v.z)]
    except (KeyError, AttributeError, TypeError, ValueError):
        return None
    if not all(math.isfinite(x) for x in position + linear):
        return None
    return position, linear


def load_chain(path: str = CHAIN_FILE) -> guard_limits.Chain | None:
    """The arm's forward kinematics (``None``: no chain file, the weaker measured mode)."""
    try:
        with open(path, encoding="utf-8") as f:
            return guard_limits.Chain.from_json(f.read())
    except FileNotFoundError:
        return None


def state_message(
    seq: int,
    stamp: float,
    q: Sequence[float],
    dq: Sequence[float],
    gripper: str,
    enabled: bool,
    estop: bool,
    stopped_by: str | None = None,
    limited: Sequence[str] = (),
) -> bytes:
    """The wire form of one state; raises ValueError for non-finite measurements."""
    doc = {
        "schema": SCHEMA,
        "seq": seq,
        "stamp": stamp,
        "q": [float(v) for v in q],
        "dq": [float(v) for v in dq],
        "gripper": gripper,
        "enabled": bool(enabled),
        "estop": bool(estop),
        "stopped_by": stopped_by,
        "limited": [name for name in LIMITS if name in limited],
    }
    return json.dumps(doc, allow_nan=False).encode()


def robot_status(state: Any) -> tuple[bool, bool]:
    """``(enabled, estop)`` from Intera's ``RobotAssemblyState`` (``RosEnable.state()``)."""
    estop_pressed = getattr(state, "ESTOP_BUTTON_PRESSED", 1)
    estop = bool(getattr(state, "stopped", False)) or (
        getattr(state, "estop_button", 0) == estop_pressed
    )
    return bool(getattr(state, "enabled", False)), estop


class GripperDriver:
    """Open/close and report Intera's gripper (``None``: no gripper attached)."""

    def __init__(self, gripper: Any) -> None:
        self._gripper = gripper
        self.requested: str | None = None

    def command(self, request: str) -> None:
        """Open or close; ClickSmart grippers take the ``grip`` signal instead."""
        self.requested = request
        if self._gripper is None:
            return
        closed = request == "closed"
        if hasattr(type(self._gripper), "set_ee_signal_value"):
            self._gripper.set_ee_signal_value("grip", closed)
        elif closed:
            self._gripper.close()
        else:
            self._gripper.open()

    def status(self) -> str:
        """``open``, ``closed``, ``moving`` or ``unknown`` (no gripper, or never commanded)."""
        if self._gripper is None or self.requested is None:
            return "unknown"
        is_moving = getattr(type(self._gripper), "is_moving", None)
        if is_moving is not None and self._gripper.is_moving():
            return "moving"
        return self.requested


# --- the robot: Intera's own topics, straight through rospy -----------------------------
# What the bridge used of intera_interface (Limb, RobotEnable, the gripper), on the topics
# and message types the Sawyer itself publishes and subscribes (intera_core_msgs).
#: The arm's joint states (sensor_msgs/JointState, all the robot's joints, ~100 Hz).
JOINT_STATES_TOPIC = "/robot/joint_states"
#: The endpoint's pose and twist in the base frame (intera_core_msgs/EndpointState).
ENDPOINT_TOPIC = "/robot/limb/right/endpoint_state"
#: Joint commands (intera_core_msgs/JointCommand).
JOINT_COMMAND_TOPIC = "/robot/limb/right/joint_command"
#: The joint controller's command timeout (std_msgs/Float64, latched): a mode other than
#: position mode without a command for this long falls back to holding its position.
COMMAND_TIMEOUT_TOPIC = "/robot/limb/right/joint_command_timeout"
#: Enabled, stopped (e-stop), error (intera_core_msgs/RobotAssemblyState).
ROBOT_STATE_TOPIC = "/robot/state"
#: Enable (True) or disable (std_msgs/Bool); reset a stopped robot (std_msgs/Empty).
ENABLE_TOPIC = "/robot/set_super_enable"
RESET_TOPIC = "/robot/set_super_reset"
#: The end-effector IO node: its devices (intera_core_msgs/IONodeStatus); a device's state
#: (IODeviceStatus) and commands (IOComponentCommand) under /io/end_effector/<device>/.
EE_NODE_TOPIC = "/io/end_effector/state"
EE_DEVICE_TOPIC = "/io/end_effector/{}/{}"
#: The command timeout the bridge sets, s (Intera's default): the robot itself stops a
#: velocity command after this, whatever the bridge does.
COMMAND_TIMEOUT = 0.2
#: Joint or endpoint states older than this are no state (the robot or ROS is gone), s.
STATE_STALE = 0.1
#: Start-up waits this long for the robot's state, joint states and endpoint state, and
#: for the robot to enable, s (as intera_interface does).
ROBOT_WAIT = 5.0
#: ... and this long for the end-effector IO (no gripper: the state reports "unknown").
GRIPPER_WAIT = 2.0
#: The electric parallel gripper's opening, m (intera_interface.Gripper).
GRIPPER_OPEN = 0.041667
GRIPPER_CLOSED = 0.0


def wait_for(condition: Callable[[], bool], timeout: float, message: str) -> None:
    """Poll ``condition`` every 10 ms until true; OSError(``message``) after ``timeout``."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() >= deadline or rospy.is_shutdown():
            raise OSError(message)
        time.sleep(0.01)


class Vector:
    """A point or vector of the endpoint state (``x``, ``y``, ``z``)."""

    __slots__ = ("x", "y", "z")

    def __init__(self, v: Any) -> None:
        self.x, self.y, self.z = float(v.x), float(v.y), float(v.z)


class RosLimb:
    """The right arm on Intera's topics (what the bridge used of ``intera_interface.Limb``).

    Joint and endpoint states come from the robot's own topics (stale after
    :data:`STATE_STALE`: then none, so the bridge's heartbeat stops); velocities go out as
    ``JointCommand`` in ``VELOCITY_MODE``, the hold as ``POSITION_MODE`` at the measured
    angles. The command timeout is set (latched) to :data:`COMMAND_TIMEOUT` at start.
    """

    def __init__(self, timeout: float = COMMAND_TIMEOUT, wait: float = ROBOT_WAIT) -> None:
        self._lock = threading.Lock()
        self._angles: dict[str, float] = {}
        self._velocities: dict[str, float] = {}
        self._joints_at = -math.inf
        self._endpoint: tuple[dict[str, Vector], dict[str, Vector]] | None = None
        self._endpoint_at = -math.inf
        self._command = JointCommand()
        self._command_pub = rospy.Publisher(
            JOINT_COMMAND_TOPIC, JointCommand, tcp_nodelay=True, queue_size=1
        )
        self._timeout_pub = rospy.Publisher(
            COMMAND_TIMEOUT_TOPIC, Float64, latch=True, queue_size=10
        )
        self._subscribers = [
            rospy.Subscriber(
                JOINT_STATES_TOPIC, JointState, self._on_joints, queue_size=1, tcp_nodelay=True
            ),
            rospy.Subscriber(
                ENDPOINT_TOPIC, EndpointState, self._on_endpoint, queue_size=1, tcp_nodelay=True
            ),
        ]
        self.set_command_timeout(timeout)
        wait_for(self._fresh_joints, wait, f"no joint states of the arm on {JOINT_STATES_TOPIC}")
        wait_for(lambda: self._endpoint is not None, wait, f"no endpoint state on {ENDPOINT_TOPIC}")

    def _on_joints(self, msg: Any) -> None:
        names = list(msg.name)
        if not set(JOINT_NAMES) <= set(names):
            return  # the head's or the gripper's joints alone
        position, velocity = list(msg.position), list(msg.velocity)
        if len(position) != len(names) or len(velocity) != len(names):
            return
        index = {name: i for i, name in enumerate(names)}
        with self._lock:
            self._angles = {n: float(position[index[n]]) for n in JOINT_NAMES}
            self._velocities = {n: float(velocity[index[n]]) for n in JOINT_NAMES}
            self._joints_at = time.monotonic()

    def _on_endpoint(self, msg: Any) -> None:
        if not msg.valid:
            with self._lock:
                self._endpoint = None
            return
        pose = {"position": Vector(msg.pose.position)}
        twist = {"linear": Vector(msg.twist.linear), "angular": Vector(msg.twist.angular)}
        with self._lock:
            self._endpoint = (pose, twist)
            self._endpoint_at = time.monotonic()

    def _fresh_joints(self) -> bool:
        with self._lock:
            return time.monotonic() - self._joints_at <= STATE_STALE

    def joint_angles(self) -> dict[str, float]:
        """The measured angles by joint name; ``{}`` when stale."""
        with self._lock:
            fresh = time.monotonic() - self._joints_at <= STATE_STALE
            return dict(self._angles) if fresh else {}

    def joint_velocities(self) -> dict[str, float]:
        """The measured velocities by joint name; ``{}`` when stale."""
        with self._lock:
            fresh = time.monotonic() - self._joints_at <= STATE_STALE
            return dict(self._velocities) if fresh else {}

    def _endpoint_now(self) -> tuple[dict[str, Vector], dict[str, Vector]] | None:
        with self._lock:
            if time.monotonic() - self._endpoint_at > STATE_STALE:
                return None
            return self._endpoint

    def endpoint_pose(self) -> dict[str, Vector]:
        """``{"position": ...}`` in the base frame; ``{}`` when stale or invalid."""
        endpoint = self._endpoint_now()
        return dict(endpoint[0]) if endpoint is not None else {}

    def endpoint_velocity(self) -> dict[str, Vector]:
        """``{"linear": ..., "angular": ...}``; ``{}`` when stale or invalid."""
        endpoint = self._endpoint_now()
        return dict(endpoint[1]) if endpoint is not None else {}

    def set_command_timeout(self, timeout: float) -> None:
        self._timeout_pub.publish(Float64(timeout))

    def _send(self, mode: int, names: list[str], values: list[float]) -> None:
        command = self._command
        command.header.stamp = rospy.Time.now()
        command.mode = mode
        command.names = names
        if mode == JointCommand.VELOCITY_MODE:
            command.position, command.velocity = [], values
        else:
            command.position, command.velocity = values, []
        self._command_pub.publish(command)

    def set_joint_velocities(self, velocities: dict[str, float]) -> None:
        """One velocity command (the robot applies it for the command timeout)."""
        names = list(velocities)
        self._send(JointCommand.VELOCITY_MODE, names, [float(velocities[n]) for n in names])

    def exit_control_mode(self, timeout: float = COMMAND_TIMEOUT) -> None:
        """Back to position mode at the measured angles (Intera's hold)."""
        self.set_command_timeout(timeout)
        angles = self.joint_angles()
        if angles:
            names = list(angles)
            self._send(JointCommand.POSITION_MODE, names, [angles[n] for n in names])


class RosEnable:
    """The robot's state and enable (what the bridge used of ``RobotEnable``)."""

    def __init__(self, wait: float = ROBOT_WAIT) -> None:
        self._state: Any = None
        self._enable_pub = rospy.Publisher(ENABLE_TOPIC, Bool, queue_size=10)
        self._reset_pub = rospy.Publisher(RESET_TOPIC, Empty, queue_size=10)
        self._subscriber = rospy.Subscriber(ROBOT_STATE_TOPIC, RobotAssemblyState, self._on_state)
        wait_for(lambda: self._state is not None, wait, f"no robot state on {ROBOT_STATE_TOPIC}")

    def _on_state(self, msg: Any) -> None:
        self._state = msg

    def state(self) -> Any:
        """The latest ``RobotAssemblyState``."""
        return self._state

    def enable(self, wait: float = ROBOT_WAIT) -> None:
        """Enable (a stopped robot is reset first, unless its e-stop button is pressed);
        OSError when it does not."""
        state = self._state
        if state.stopped:
            if state.estop_button == RobotAssemblyState.ESTOP_BUTTON_PRESSED:
                raise OSError("Robot is E-Stopped: release the e-stop button")

            def reset() -> bool:
                self._reset_pub.publish(Empty())
                return not self._state.stopped

            wait_for(reset, wait, "failed to reset the stopped robot")

        def enabled() -> bool:
            self._enable_pub.publish(Bool(True))
            return bool(self._state.enabled)

        wait_for(enabled, wait, "failed to enable the robot")
        rospy.loginfo("legws bridge: robot enabled")


class RosGripper:
    """An end-effector IO device's signals: Intera's electric parallel gripper
    (``position_m``; :meth:`open`, :meth:`close`, :meth:`is_moving`)."""

    def __init__(self, device: str) -> None:
        self.device = device
        self.signals: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._pub = rospy.Publisher(
            EE_DEVICE_TOPIC.format(device, "command"), IOComponentCommand, queue_size=10
        )
        self._sub = rospy.Subscriber(
            EE_DEVICE_TOPIC.format(device, "state"), IODeviceStatus, self._on_state
        )

    def _on_state(self, msg: Any) -> None:
        values = {}
        for signal in msg.signals:
            try:
                data = json.loads(signal.data)
            except ValueError:
                continue
            values[signal.name] = data[0] if isinstance(data, list) and data else None
        with self._lock:
            self.signals = values

    def signal(self, name: str) -> Any:
        with self._lock:
            return self.signals.get(name)

    def set_signal(self, name: str, kind: str, value: Any) -> None:
        """One ``set`` command (as ``intera_io.SetCommand``)."""
        args = {"signals": {name: {"format": {"type": kind}, "data": [value]}}}
        self._pub.publish(IOComponentCommand(rospy.Time.now(), "set", json.dumps(args)))

    def open(self) -> None:
        self.set_signal("position_m", "float", GRIPPER_OPEN)

    def close(self) -> None:
        self.set_signal("position_m", "float", GRIPPER_CLOSED)

    def is_moving(self) -> bool:
        return bool(self.signal("is_moving"))


class RosClickSmart(RosGripper):
    """A ClickSmart plate: its ``grip`` signal."""

    def set_ee_signal_value(self, name: str, value: bool) -> None:
        self.set_signal(name, "bool", bool(value))


def find_gripper(wait: float = GRIPPER_WAIT) -> RosGripper | None:
    """The first end-effector device, as a gripper (``None``: none attached, or none this
    bridge knows: neither ``position_m`` nor ``grip``). An electric gripper not calibrated
    yet is calibrated."""
    devices: list[str] = []

    def on_node(msg: Any) -> None:
        devices[:] = [str(d.name) for d in msg.devices]

    node = rospy.Subscriber(EE_NODE_TOPIC, IONodeStatus, on_node)
    try:
        wait_for(lambda: bool(devices), wait, f"no end-effector device on {EE_NODE_TOPIC}")
    finally:
        node.unregister()
    probe = RosGripper(devices[0])
    wait_for(lambda: bool(probe.signals), wait, f"no state of the end effector {devices[0]}")
    if "grip" in probe.signals:
        probe._sub.unregister()
        return RosClickSmart(devices[0])
    if "position_m" not in probe.signals:
        raise OSError(f"the end effector {devices[0]} is not a gripper this bridge drives")
    if probe.signal("is_calibrated") is False:
        probe.set_signal("calibrate", "bool", True)
    return probe


class SawyerBridge:
    """The bridge's work: commands, stops and resumes in (zenoh threads), state out and
    velocities applied (:meth:`tick`, the ROS loop at 100 Hz).

    The rules, in order. On a command: the contract's validation (rejected: the arm stops),
    the rate (refused: the arm stops), the stop latch and shutdown (ignored), the joint
    speed cap (scaled), the ttl cap. Every tick: the deadman, the joint position limits,
    the endpoint speed (scaled), the workspace (the arm stops).

    Args:
        session: an open zenoh session (closed by the caller).
        robot: the robot name: keys under ``legws/<robot>/``.
        limb: the arm (:class:`RosLimb`).
        gripper: the gripper driver.
        enabler: the robot's state (:class:`RosEnable`: ``state()`` says enabled / e-stop).
        clock: monotonic seconds, for the deadman and the rate.
        wall: the clock of the ``stamp`` fields.
        limits: the bridge's own limits (default: the profile defaults).
        period: the tick period, s (the workspace rule predicts one period ahead).
    """

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        limb: Any,
        gripper: GripperDriver,
        enabler: Any,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        limits: Limits | None = None,
        period: float = 1.0 / STATE_RATE_HZ,
        chain: guard_limits.Chain | None = None,
    ) -> None:
        self.state_key = f"legws/{robot}/bridge/state"
        self.command_key = f"legws/{robot}/bridge/command"
        self.resume_key = f"legws/{robot}/bridge/resume"
        self.stop_key = f"legws/{robot}/stop/*"
        self.limb = limb
        self.gripper = gripper
        self.enabler = enabler
        self.clock = clock
        self.wall = wall
        self.limits = limits if limits is not None else Limits()
        self.chain = chain
        # the one guard of every legws bridge: forward kinematics of the commanded step
        # with a chain; without one, the weaker mode on Intera's measured endpoint twist
        self.guard = guard_limits.Guard.for_arm(
            ARM,
            self.limits,
            clock=clock,
            ee_position=chain.position if chain is not None else None,
            period=period,
            limit_margin=LIMIT_GUARD,
        )
        self.joint_caps = list(self.guard.joint_caps)
        self.rejected = 0
        self.accepted = 0  # valid commands (also those refused or ignored)
        self.stops = 0
        self.invalid_stops = 0
        self.resumes = 0
        self.rejected_resumes = 0
        self.counts = self.guard.counts  # per limit, times enforced
        self._lock = threading.Lock()  # the deadman, the latch, the limits, the gripper request
        self._motion = threading.Lock()  # the limb's commands (tick vs. halt at shutdown)
        self._gripper_request: str | None = None
        self._moving = False
        self._halted = False
        self._seq = 0
        self._publisher = session.declare_publisher(self.state_key)
        self._subscribers = [
            session.declare_subscriber(self.command_key, self._on_command),
            session.declare_subscriber(self.stop_key, self._on_stop),
            session.declare_subscriber(self.resume_key, self._on_resume),
        ]

    @property
    def stopped_by(self) -> str | None:
        """The role of the first latched stop (``None``: none)."""
        return self.guard.stopped_by

    def _on_command(self, sample: zenoh.Sample) -> None:
        self.handle_command(sample.payload.to_bytes(), self.clock())

    def _on_stop(self, sample: zenoh.Sample) -> None:
        self.handle_stop(str(sample.key_expr), sample.payload.to_bytes())

    def _on_resume(self, sample: zenoh.Sample) -> None:
        self.handle_resume(sample.payload.to_bytes())

    def handle_command(self, payload: bytes, now: float) -> None:
        """Accept a valid command within the limits; a rejected or refused one stops the arm."""
        try:
            command = parse_command(payload)
        except CommandError as err:
            with self._lock:
                self.rejected += 1
                self.guard.clear()
            rospy.logwarn_throttle(1.0, f"legws bridge: command rejected: {err}")
            return
        with self._lock:
            self.accepted += 1
            if not self.guard.admit(now):
                return  # over the rate: refused, the arm stopped
            if self._halted:
                return
            if self.guard.accept(command.dq, command.ttl, now) != "accepted":
                return  # a latched stop: ignored, its gripper request too
            if command.gripper is not None:
                self._gripper_request = command.gripper

    def handle_stop(self, key: str, payload: bytes) -> None:
        """Any sample on a stop key stops the arm and latches (its payload is only checked
        to count the invalid ones)."""
        try:
            check_stop(payload)
            valid = True
        except CommandError:
            valid = False
        role = stop_role(key)
        with self._lock:
            self.stops += 1
            if not valid:
                self.invalid_stops += 1
            self.guard.stop(role)
        rospy.logwarn_throttle(1.0, f"legws bridge: stopped by {role} ({key})")

    def handle_resume(self, payload: bytes) -> None:
        """A valid resume clears the latched stop (no command comes back)."""
        try:
            check_resume(payload)
        except CommandError as err:
            with self._lock:
                self.rejected_resumes += 1
            rospy.logwarn_throttle(1.0, f"legws bridge: resume rejected: {err}")
            return
        with self._lock:
            self.resumes += 1
            self.guard.resume()  # the daemon's resume (bridge/resume) clears every stop

    def tick(self) -> None:
        """Apply the live command within the limits (or hold still), drive the gripper,
        publish the state."""
        now = self.clock()
        angles = self.limb.joint_angles()
        speeds = self.limb.joint_velocities()
        if any(name not in angles or name not in speeds for name in JOINT_NAMES):
            return  # no joint state from the robot yet: no heartbeat either
        q = [float(angles[name]) for name in JOINT_NAMES]
        dq = [float(speeds[name]) for name in JOINT_NAMES]
        enabled, estop = robot_status(self.enabler.state())
        endpoint = endpoint_state(self.limb)
        with self._motion:
            with self._lock:
                velocities = None
                if self._halted or not enabled or estop:
                    self.guard.clear()  # never moves while disabled or e-stopped
                elif endpoint is None and self.guard.live is not None:
                    # no endpoint state from Intera (the robot not reporting): hold
                    rospy.logwarn_throttle(1.0, "legws bridge: no endpoint state; holding")
                else:
                    step = self.guard.step(q, now, horizon=self.guard.period, measured=endpoint)
                    if step.moving:
                        velocities = list(step.velocity)
                request, self._gripper_request = self._gripper_request, None
                stopped_by = self.guard.stopped_by
                limited = self.guard.take_limited()
            if velocities is not None:
                self.limb.set_joint_velocities(dict(zip(JOINT_NAMES, velocities)))
                self._moving = True
            elif self._moving:
                self._hold()
        if request is not None and request != self.gripper.requested and enabled and not estop:
            self.gripper.command(request)
        try:
            payload = state_message(
                self._seq,
                self.wall(),
                q,
                dq,
                self.gripper.status(),
                enabled,
                estop,
                stopped_by,
                limited,
            )
        except ValueError as err:
            rospy.logerr_throttle(1.0, f"legws bridge: state not published: {err}")
            return
        if limited:
            rospy.logwarn_throttle(1.0, f"legws bridge: limits enforced: {', '.join(limited)}")
        self._seq += 1
        self._publisher.put(payload)

    def _hold(self) -> None:
        """Zero velocities, then Intera's position hold at the current angles."""
        self.limb.set_joint_velocities(dict.fromkeys(JOINT_NAMES, 0.0))
        self.limb.exit_control_mode()
        self._moving = False

    def halt(self) -> None:
        """Stop for good (shutdown): zero velocities, no further command is applied."""
        with self._motion:
            with self._lock:
                self._halted = True
                self.guard.clear()
            if self._moving:
                self._hold()

    def close(self) -> None:
        """Halt and undeclare; the session is closed by its owner."""
        self.halt()
        entities: list[Any] = [*self._subscribers, self._publisher]
        for entity in entities:
            with contextlib.suppress(zenoh.ZError):  # a closed session: nothing left
                entity.undeclare()


def zenoh_config(path: str | None, connect: Sequence[str], listen: Sequence[str]) -> zenoh.Config:
    """A JSON5 file for the real network, else a loopback peer without multicast scouting
    or gossip, dialling again every 0.1-0.5 s (the daemon waits 3 s for it at start-up)."""
    if path is not None:
        return zenoh.Config.from_file(path)
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    retry = {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}
    config.insert_json5("connect/retry", json.dumps(retry))
    return config


def _config_value(config: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(config.get_json(key))
    except Exception:  # a key this zenoh does not know: unset
        return None


def _config_endpoints(config: zenoh.Config, which: str) -> list[str]:
    value = _config_value(config, which + "/endpoints")
    if isinstance(value, dict):  # zenoh's per-mode form
        value = value.get(_config_value(config, "mode") or "peer", [])
    return [str(e) for e in value] if isinstance(value, list) else []


def authentication_problem(config: zenoh.Config) -> str | None:
    """What makes ``config`` unauthenticated, or ``None`` (the same rule as the daemon's
    ``legws_daemon/transport/security.py``): TLS endpoints only, mutual TLS or
    user/password, and an access control denying by default."""
    endpoints = _config_endpoints(config, "listen") + _config_endpoints(config, "connect")
    if not endpoints:
        return "it has no listen or connect endpoint"
    plain = [e for e in endpoints if e.split("/", 1)[0] not in ("tls", "quic")]
    if plain:
        return f"endpoint {plain[0]} is not TLS (use tls/HOST:PORT)"
    protocols = _config_value(config, "transport/link/protocols")
    if isinstance(protocols, list) and set(protocols) - {"tls", "quic"}:
        return f"transport/link/protocols allows {sorted(set(protocols) - {'tls', 'quic'})}"
    mtls = _config_value(config, "transport/link/tls/enable_mtls") is True
    usrpwd = bool(
        _config_value(config, "transport/auth/usrpwd/dictionary_file")
        or _config_value(config, "transport/auth/usrpwd/user")
    )
    if not (mtls or usrpwd):
        return "no authentication (transport/link/tls/enable_mtls or transport/auth/usrpwd)"
    if _config_value(config, "mode") == "client":
        return None
    if _config_value(config, "access_control/enabled") is not True:
        return "access_control is not enabled"
    if _config_value(config, "access_control/default_permission") != "deny":
        return 'access_control/default_permission is not "deny"'
    return None


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="intera_bridge.py", description="legws bridge for a Rethink Sawyer (Intera)."
    )
    parser.add_argument("--robot", default="sawyer", help="robot name of the zenoh keys")
    parser.add_argument("--zenoh-config", help="JSON5 zenoh configuration (the real network)")
    parser.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to connect to (repeatable; default {DEFAULT_CONNECT})",
    )
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT")
    parser.add_argument("--rate", type=float, default=STATE_RATE_HZ, help="state rate, Hz")
    parser.add_argument(
        "--insecure-transport",
        action="store_true",
        help="run on a transport without authentication and access control (a bench test): "
        "anyone who reaches it can command the arm within the bridge's limits",
    )
    parser.add_argument(
        "--no-enable", action="store_true", help="do not enable the robot at start-up"
    )
    limits = parser.add_argument_group(
        "limits", "the bridge's own limits (default: a legws profile's defaults)"
    )
    limits.add_argument(
        "--profile",
        metavar="PATH",
        help="a legws hardware profile (.toml): its [bridge] and [workspace] (Python >= 3.11)",
    )
    limits.add_argument(
        "--joint-speed-cap", type=float, help=f"rad/s per joint (default {JOINT_SPEED_CAP:g})"
    )
    limits.add_argument(
        "--ee-speed-cap", type=float, help=f"endpoint speed, m/s (default {EE_SPEED_CAP:g})"
    )
    limits.add_argument(
        "--workspace",
        type=float,
        nargs=6,
        metavar=("X0", "X1", "Y0", "Y1", "Z0", "Z1"),
        help="the endpoint's box, base frame, m (default "
        + " ".join(f"{v:g}" for pair in WORKSPACE for v in pair)
        + ")",
    )
    limits.add_argument("--workspace-margin", type=float, help=f"m (default {WORKSPACE_MARGIN:g})")
    limits.add_argument(
        "--max-ttl",
        type=float,
        help=f"a command moves the arm at most this long, s (default {TTL_CAP:g})",
    )
    limits.add_argument(
        "--command-rate",
        type=float,
        help=f"commands/s at most, {COMMAND_BURST} more in a burst (default {COMMAND_RATE_HZ:g})",
    )
    args = parser.parse_args(list(argv))
    if args.zenoh_config and (args.connect or args.listen):
        parser.error("--zenoh-config replaces --connect/--listen")
    if not 1.0 <= args.rate <= 1000.0:
        parser.error(f"--rate must be in [1, 1000] Hz, got {args.rate:g}")
    if args.connect is None:
        args.connect = [] if args.listen else [DEFAULT_CONNECT]
    for flag, endpoints in (("--connect", args.connect), ("--listen", args.listen)):
        for endpoint in endpoints:
            problem = endpoint_problem(endpoint)
            if problem:
                parser.error(f"{flag}: {problem}")
    try:
        args.limits = limits_from_args(args)
    except (OSError, ValueError) as err:
        parser.error(_first_line(err))
    return args


_ENDPOINT = re.compile(
    r"(tcp|udp|tls|quic)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9.-]*):([0-9]{1,5})"
)


def endpoint_problem(text: str) -> str | None:
    """What is wrong with a zenoh endpoint PROTOCOL/HOST:PORT (as legws' profiles check it)."""
    m = _ENDPOINT.fullmatch(text)
    if m is None:
        return f"expected PROTOCOL/HOST:PORT (tcp, udp, tls or quic), got {text[:80]!r}"
    if not 1 <= int(m.group(3)) <= 65535:
        return f"port {m.group(3)} is not in 1..65535"
    return None


def limits_from_args(args: argparse.Namespace) -> Limits:
    """The profile's limits (or the defaults), with the flags given on top."""
    limits = profile_limits(args.profile) if args.profile else Limits()
    flags = {
        "joint_speed_cap": args.joint_speed_cap,
        "ee_speed_cap": args.ee_speed_cap,
        "workspace_margin": args.workspace_margin,
        "max_ttl": args.max_ttl,
        "command_rate_hz": args.command_rate,
    }
    changes: dict[str, Any] = {k: v for k, v in flags.items() if v is not None}
    if args.workspace is not None:
        w = args.workspace
        changes["workspace"] = ((w[0], w[1]), (w[2], w[3]), (w[4], w[5]))
    return replace(limits, **changes)


def open_gripper() -> GripperDriver:
    """The attached gripper, or a driver reporting ``unknown`` when there is none."""
    try:
        gripper = find_gripper()
    except Exception as err:  # OSError: none attached (no IO state in time), or unknown
        rospy.logwarn(f"legws bridge: no gripper ({err}); gripper requests are ignored")
        gripper = None
    return GripperDriver(gripper)


def _first_line(err: BaseException) -> str:
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def _fail(message: str) -> int:
    """One line on stderr, exit code 2; a character a terminal would act on (an escape, a
    line break, a bidirectional control: from a path or a library's message) is written as
    Python escapes it (the script stands alone: legws's own helper is not here)."""
    safe = "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)
    print(f"intera_bridge.py: error: {safe}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bridge until SIGINT/SIGTERM or ROS shutdown; returns the exit code.

    Args:
        argv: the arguments without the program name (default: ``sys.argv[1:]``); ROS
            remappings (``name:=value``) are dropped.
    """
    args = parse_args(rospy.myargv(argv=list(sys.argv[1:] if argv is None else argv)))
    try:
        config = zenoh_config(args.zenoh_config, args.connect, args.listen)
    except Exception as err:  # zenoh raises its own error types for bad JSON5 or keys
        return _fail(f"invalid zenoh configuration: {_first_line(err)}")
    problem = authentication_problem(config)
    if problem is not None and not args.insecure_transport:
        return _fail(
            f"the transport is not authenticated: {problem}; pass --zenoh-config with the "
            "bridge.json5 of `legws secure init`, or --insecure-transport for a bench test"
        )
    rospy.init_node("legws_bridge")
    if problem is not None:
        rospy.logwarn(f"legws bridge: INSECURE TRANSPORT: {problem}")
    try:
        enabler = RosEnable()
        if not args.no_enable:
            enabler.enable()
        limb = RosLimb()
    except Exception as err:  # OSError: no state in time, e-stop, not enabled
        return _fail(f"cannot reach the robot: {_first_line(err)}")
    gripper = open_gripper()
    try:
        session = zenoh.open(config)
    except Exception as err:
        return _fail(f"cannot open a zenoh session: {_first_line(err)}")
    try:
        chain = load_chain()
        if chain is None:
            rospy.logwarn(
                f"legws bridge: no {CHAIN_FILE}: the endpoint is judged by Intera's measured "
                "twist, a tick behind (the weaker mode)"
            )
        bridge = SawyerBridge(
            session,
            args.robot,
            limb,
            gripper,
            enabler,
            limits=args.limits,
            period=1.0 / args.rate,
            chain=chain,
        )
        try:
            rospy.on_shutdown(bridge.halt)  # zero velocities while ROS can still send them
            rospy.loginfo(f"legws bridge: {bridge.state_key} at {args.rate:g} Hz")
            rospy.loginfo(f"legws bridge: limits: {args.limits.describe()}")
            rate = rospy.Rate(args.rate)
            while not rospy.is_shutdown():
                bridge.tick()
                try:
                    rate.sleep()
                except rospy.ROSInterruptException:
                    break
        finally:
            bridge.close()
    finally:
        session.close()  # type: ignore[no-untyped-call]
    return 0


if __name__ == "__main__":
    sys.exit(main())
