#!/usr/bin/env python3
"""legws bridge for a Rethink Sawyer: Intera joint states out, joint velocity commands in.

Runs on the robot's PC (ROS Noetic, Intera SDK, Python >= 3.8, ``pip install
eclipse-zenoh``) and implements the bridge contract of ``docs/bridge.md``:

* ``legws/<robot>/bridge/state`` (published at 100 Hz, the bridge's heartbeat):
  ``{"schema": 1, "seq", "stamp", "q": [7], "dq": [7], "gripper", "enabled", "estop"}``
  from ``intera_interface.Limb('right')``, joints ``right_j0`` .. ``right_j6``.
* ``legws/<robot>/bridge/command`` (subscribed):
  ``{"schema": 1, "seq", "stamp", "mode": "joint_velocity", "dq": [7], "ttl", "gripper"}``.
  A command is applied with ``Limb.set_joint_velocities`` until its ``ttl`` runs out (the
  deadman), then the arm holds its position. A command with a non-finite or over-limit
  value, or any other invalid field, is rejected and stops the arm. Nothing moves while
  the robot is disabled or e-stopped.

Standalone on purpose: it imports only rospy, intera_interface, zenoh and the standard
library. The message checks and the deadman are plain functions and classes, tested in
the legws repository with fake ``rospy``/``intera_interface`` modules.

Usage (see bridge/README.md)::

    python3 intera_bridge.py                              # loopback: connect tcp/127.0.0.1:7447
    python3 intera_bridge.py --zenoh-config robot.json5   # the real network
"""

# zip(strict=...) needs Python 3.10; the robot's PC may run ROS Noetic's Python 3.8.
# ruff: noqa: B905
from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import intera_interface
import rospy
import zenoh

SCHEMA = 1
#: Intera's joint names: the order of every joint vector on the wire.
JOINT_NAMES = ("right_j0", "right_j1", "right_j2", "right_j3", "right_j4", "right_j5", "right_j6")
#: Joint speed limits, rad/s (Intera specification).
SPEED_LIMITS = (1.74, 1.328, 1.957, 1.957, 3.485, 3.485, 4.545)
#: Joint position limits, rad.
LOWER = (-3.0503, -3.8095, -3.0426, -3.0439, -2.9761, -2.9761, -4.7124)
UPPER = (3.0503, 2.2736, 3.0426, 3.0439, 2.9761, 2.9761, 4.7124)
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


def guard_limits(q: Sequence[float], dq: Sequence[float]) -> list[float]:
    """``dq`` with the joints at (or past) a position limit not driven further out."""
    out = []
    for qi, vi, lo, hi in zip(q, dq, LOWER, UPPER):
        outward = (vi > 0.0 and qi >= hi - LIMIT_GUARD) or (vi < 0.0 and qi <= lo + LIMIT_GUARD)
        out.append(0.0 if outward else float(vi))
    return out


class Deadman:
    """The current command and its expiry: velocities only while a fresh command lives."""

    def __init__(self) -> None:
        self._command: Command | None = None
        self._expires = 0.0

    def accept(self, command: Command, now: float) -> None:
        """A valid command replaces the current one; it lives ``ttl`` seconds from ``now``."""
        self._command = command
        self._expires = now + command.ttl

    def clear(self) -> None:
        """Stop: a rejected command, a disabled robot or a shutdown."""
        self._command = None

    def velocities(self, now: float, q: Sequence[float], can_move: bool) -> list[float] | None:
        """The joint velocities to apply now, or ``None`` when the arm must hold still."""
        if self._command is None or not can_move:
            self._command = None
            return None
        if now >= self._expires:
            self._command = None
            return None
        return guard_limits(q, self._command.dq)


def state_message(
    seq: int,
    stamp: float,
    q: Sequence[float],
    dq: Sequence[float],
    gripper: str,
    enabled: bool,
    estop: bool,
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
    }
    return json.dumps(doc, allow_nan=False).encode()


def robot_status(state: Any) -> tuple[bool, bool]:
    """``(enabled, estop)`` from Intera's ``AssemblyState`` (``RobotEnable.state()``)."""
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


class SawyerBridge:
    """The bridge's work: commands in (a zenoh thread), state out and velocities applied
    (:meth:`tick`, the ROS loop at 100 Hz).

    Args:
        session: an open zenoh session (closed by the caller).
        robot: the robot name: keys under ``legws/<robot>/bridge/``.
        limb: ``intera_interface.Limb('right')``.
        gripper: the gripper driver.
        enabler: ``intera_interface.RobotEnable`` (its ``state()`` says enabled / e-stop).
        clock: monotonic seconds, for the deadman.
        wall: the clock of the ``stamp`` fields.
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
    ) -> None:
        self.state_key = f"legws/{robot}/bridge/state"
        self.command_key = f"legws/{robot}/bridge/command"
        self.limb = limb
        self.gripper = gripper
        self.enabler = enabler
        self.clock = clock
        self.wall = wall
        self.deadman = Deadman()
        self.rejected = 0
        self.accepted = 0
        self._lock = threading.Lock()  # the deadman and the gripper request
        self._motion = threading.Lock()  # the limb's commands (tick vs. halt at shutdown)
        self._gripper_request: str | None = None
        self._moving = False
        self._halted = False
        self._seq = 0
        self._publisher = session.declare_publisher(self.state_key)
        self._subscriber = session.declare_subscriber(self.command_key, self._on_command)

    def _on_command(self, sample: zenoh.Sample) -> None:
        self.handle_command(sample.payload.to_bytes(), self.clock())

    def handle_command(self, payload: bytes, now: float) -> None:
        """Accept a valid command; a rejected one stops the arm."""
        try:
            command = parse_command(payload)
        except CommandError as err:
            with self._lock:
                self.rejected += 1
                self.deadman.clear()
            rospy.logwarn_throttle(1.0, f"legws bridge: command rejected: {err}")
            return
        with self._lock:
            self.accepted += 1
            if self._halted:
                return
            self.deadman.accept(command, now)
            if command.gripper is not None:
                self._gripper_request = command.gripper

    def tick(self) -> None:
        """Apply the live command (or hold still), drive the gripper, publish the state."""
        now = self.clock()
        angles = self.limb.joint_angles()
        speeds = self.limb.joint_velocities()
        if any(name not in angles or name not in speeds for name in JOINT_NAMES):
            return  # no joint state from the robot yet: no heartbeat either
        q = [float(angles[name]) for name in JOINT_NAMES]
        dq = [float(speeds[name]) for name in JOINT_NAMES]
        enabled, estop = robot_status(self.enabler.state())
        with self._motion:
            with self._lock:
                velocities = None
                if not self._halted:
                    velocities = self.deadman.velocities(now, q, enabled and not estop)
                request, self._gripper_request = self._gripper_request, None
            if velocities is not None:
                self.limb.set_joint_velocities(dict(zip(JOINT_NAMES, velocities)))
                self._moving = True
            elif self._moving:
                self._hold()
        if request is not None and request != self.gripper.requested and enabled and not estop:
            self.gripper.command(request)
        try:
            payload = state_message(
                self._seq, self.wall(), q, dq, self.gripper.status(), enabled, estop
            )
        except ValueError as err:
            rospy.logerr_throttle(1.0, f"legws bridge: state not published: {err}")
            return
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
                self.deadman.clear()
            if self._moving:
                self._hold()

    def close(self) -> None:
        """Halt and undeclare; the session is closed by its owner."""
        self.halt()
        for entity in (self._subscriber, self._publisher):
            with contextlib.suppress(zenoh.ZError):  # a closed session: nothing left
                entity.undeclare()  # type: ignore[no-untyped-call]


def zenoh_config(path: str | None, connect: Sequence[str], listen: Sequence[str]) -> zenoh.Config:
    """A JSON5 file for the real network, else a loopback peer without multicast scouting."""
    if path is not None:
        return zenoh.Config.from_file(path)
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return config


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
        "--no-enable", action="store_true", help="do not enable the robot at start-up"
    )
    args = parser.parse_args(list(argv))
    if args.zenoh_config and (args.connect or args.listen):
        parser.error("--zenoh-config replaces --connect/--listen")
    if not 1.0 <= args.rate <= 1000.0:
        parser.error(f"--rate must be in [1, 1000] Hz, got {args.rate:g}")
    if args.connect is None:
        args.connect = [] if args.listen else [DEFAULT_CONNECT]
    return args


def open_gripper() -> GripperDriver:
    """The attached gripper, or a driver reporting ``unknown`` when there is none."""
    try:
        gripper = intera_interface.get_current_gripper_interface()
    except Exception as err:  # Intera raises OSError (timeout) and others without a gripper
        rospy.logwarn(f"legws bridge: no gripper ({err}); gripper requests are ignored")
        gripper = None
    return GripperDriver(gripper)


def _first_line(err: BaseException) -> str:
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def _fail(message: str) -> int:
    """One line on stderr, exit code 2."""
    print(f"intera_bridge.py: error: {message}", file=sys.stderr)
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
    rospy.init_node("legws_bridge")
    try:
        enabler = intera_interface.RobotEnable(intera_interface.CHECK_VERSION)
        if not args.no_enable:
            enabler.enable()
        limb = intera_interface.Limb("right")
    except Exception as err:  # Intera raises OSError and others (e-stop, no robot)
        return _fail(f"cannot reach the robot: {_first_line(err)}")
    gripper = open_gripper()
    try:
        session = zenoh.open(config)
    except Exception as err:
        return _fail(f"cannot open a zenoh session: {_first_line(err)}")
    try:
        bridge = SawyerBridge(session, args.robot, limb, gripper, enabler)
        try:
            rospy.on_shutdown(bridge.halt)  # zero velocities while ROS can still send them
            rospy.loginfo(f"legws bridge: {bridge.state_key} at {args.rate:g} Hz")
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
