#!/usr/bin/env python3
"""legws bridge for a Franka arm (Panda / FR3): joint states out, joint velocity commands in.

Runs on the computer wired to the arm's control box (FCI; Python >= 3.9, ``pip install
pylibfranka "eclipse-zenoh>=1.10,<2"``) and implements the bridge contract of
``docs/bridge.md``, the same as ``intera_bridge.py`` does for the Sawyer: the same keys,
messages, stops, resume and transport rule. It drives the arm through ``pylibfranka`` (Franka
Robotics' own Python binding of libfranka) with joint velocity control:

* ``legws/<robot>/bridge/state`` (published at 100 Hz, the bridge's heartbeat):
  ``{"schema": 1, "seq", "stamp", "q": [7], "dq": [7], "gripper", "enabled", "estop",
  "stopped_by", "limited"}``, the joints ``panda_joint1`` .. ``panda_joint7`` in order.
* ``legws/<robot>/bridge/command`` (subscribed): ``{"schema": 1, "seq", "stamp", "mode":
  "joint_velocity", "dq": [7], "ttl", "gripper"}``. A command acts for its ``ttl`` after its
  receipt (at most ``--max-ttl``); then the arm brakes to rest and, still for a while,
  libfranka's motion ends and the arm holds its position. A command with a non-finite or
  over-limit value, or any invalid field, is rejected and stops the arm.
* ``legws/<robot>/stop/*``: any sample stops the arm and latches until a valid
  ``legws/<robot>/bridge/resume``, which also runs libfranka's automatic error recovery
  when the arm is in a reflex.

Two loops. The **control loop** (:class:`FrankaArm`, its own thread, 1 kHz: libfranka's
``readOnce``/``writeOnce``) owns the robot: it tracks the target joint velocities with a
jerk- and acceleration-limited ramp (libfranka refuses discontinuous commands) and brakes
to zero when the target expires, so a stalled bridge stops the arm within a few
milliseconds of the target's life. The **bridge tick** (:class:`FrankaBridge`, 100 Hz) turns
the live command into that target within the bridge's own limits, legws' one guard of
every bridge (``legws_daemon/safety/limits.py``: rate, stop latch, joint speed, command
life, joint position limits, endpoint speed and workspace, here on the arm's own endpoint
and Jacobian), no joint braking into its position limit, and publishes the state.

Standalone on purpose: it imports only pylibfranka (at start-up, in :func:`main`), zenoh,
the standard library and two standard-library parts of legws found in the folder above
this one (the checkout this file is in, or the folder ``legws bridge bundle --arm panda``
writes): legws' one guard of every bridge (``legws_daemon/safety/limits.py``) and the arm
tables (``legws_daemon/arms``: the Panda's joint names, limits and mount). Its logic is
tested in the legws repository with the real zenoh
and, end to end, against franka-sim (a libfranka protocol server on MuJoCo,
``tests/bridge/test_franka_e2e.py``).

Usage (see bridge/README.md)::

    python3 franka_bridge.py --robot-ip 172.16.0.2 --zenoh-config bridge.json5
    python3 franka_bridge.py --robot-ip 127.0.0.1 --realtime ignore --insecure-transport
"""

# zip(strict=...) needs Python 3.10; the robot's PC may run an older Python.
# ruff: noqa: B905
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import signal
import stat
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import zenoh

try:  # Python >= 3.11: --profile reads a legws hardware profile
    import tomllib
except ImportError:  # give the limits as flags
    tomllib = None  # type: ignore[assignment]

# The limits and the joint tables every legws bridge shares (standard library, Python 3.8):
# legws_daemon/safety/limits.py and legws_daemon/arms, found in the folder above this one
# (the checkout this file is in, or the folder `legws bridge bundle --arm panda` writes).
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)
try:
    from legws_daemon.arms import arm
    from legws_daemon.safety import limits as guard_module
except ImportError as _err:
    print(
        f"franka_bridge.py: error: legws' arm tables and bridge limits not found in {_ROOT} "
        f"({_err}): run the bridge from a legws checkout, or from the folder `legws bridge "
        "bundle --arm panda --out DIR` writes (DIR/bridge/franka_bridge.py)",
        file=sys.stderr,
    )
    sys.exit(2)

ARM = arm("panda")
SCHEMA = 1
#: Franka's joint names (as franka_ros calls them): the order of every joint vector on the
#: wire (the arm's description, ``legws_daemon/arms/panda.py``).
JOINT_NAMES = ARM.hardware_joints
#: Joint speed limits, rad/s (Franka's datasheet).
SPEED_LIMITS = ARM.speed_limits
#: Joint position limits, rad.
LOWER = ARM.lower
UPPER = ARM.upper
#: The joint acceleration and jerk limits of the FCI's motion generator (rad/s², rad/s³):
#: the robot aborts a motion whose commands exceed them. The lower of the Panda's
#: (libfranka 0.9: 15, 7.5, 10, 12.5, 15, 20, 20 and 7500, 3750, 5000, 6250, 7500, 10000,
#: 10000) and the FR3's (libfranka >= 0.10: 10 and 5000 for every joint).
ACCEL_LIMITS = (10.0, 7.5, 10.0, 10.0, 10.0, 10.0, 10.0)
JERK_LIMITS = (5000.0, 3750.0, 5000.0, 5000.0, 5000.0, 5000.0, 5000.0)
#: The ramp uses this fraction of them: braking from 0.8 rad/s takes about 0.2 s.
ACCEL_FRACTION = 0.5
JERK_FRACTION = 0.1
#: The ramp's gain toward the target velocity, 1/s (its own jerk is then about
#: RAMP_GAIN x acceleration, far below the limits).
RAMP_GAIN = 25.0
#: Below this (rad/s, rad/s²) a joint at a zero target is at rest.
REST_SPEED = 1e-4
REST_ACCEL = 1e-2
#: A motion at rest with no live target this long is ended (libfranka's hold), s.
IDLE_FINISH = 0.5
#: A target handed to the control loop lives at most this long (the bridge tick renews it
#: every period): a stalled tick stops the arm, s.
HANDOFF = 0.03
#: The control loop's nominal period (the FCI's), s.
CONTROL_PERIOD = 0.001
#: A commanded speed may exceed its limit by this much (floating-point slack), rad/s.
SPEED_TOLERANCE = 1e-6
#: Longest time-to-live of one command, s.
MAX_TTL = 1.0
#: A joint this close to a position limit (after braking) is not driven further, rad.
LIMIT_GUARD = 0.02
#: Largest command payload accepted, bytes.
MAX_PAYLOAD = 64 * 1024
#: Largest sequence number (a signed 64-bit integer).
MAX_SEQ = 2**63 - 1
STATE_RATE_HZ = 100.0
#: A robot state older than this is no state (the robot or the network is gone), s.
STATE_STALE = 0.1
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
GRIPPER_REQUESTS = ("open", "closed")
#: The Franka Hand's speed (m/s) and grasp force (N) for the bridge's open and close.
GRIPPER_SPEED = 0.1
GRIPPER_FORCE = 20.0
#: The hand's opening when it does not report one, m.
GRIPPER_MAX_WIDTH = 0.08
_COMMAND_FIELDS = frozenset({"schema", "seq", "stamp", "mode", "dq", "ttl", "gripper"})
_STOP_FIELDS = frozenset({"schema", "stamp", "source", "reason"})
_RESUME_FIELDS = frozenset({"schema", "seq", "stamp"})
#: The roles that stop the robot on ``legws/<robot>/stop/<role>`` (another key: "unknown").
STOP_ROLES = ("operator", "observer", "safety", "bridge", "daemon")
#: The limits the bridge enforces itself, as the state's ``limited`` names them.
LIMITS = ("joint_speed", "ee_speed", "workspace", "ttl", "rate")

# The bridge's own limits: the defaults of a legws profile's [bridge] and [workspace]
# tables (legws_daemon/formats/profile.py); --profile or the flags set others.
JOINT_SPEED_CAP = 0.8  # rad/s, each joint (and at most its specification)
EE_SPEED_CAP = 0.2  # m/s, the endpoint's speed (J(q) dq)
#: The box the endpoint stays in (table coordinates, m): x, y, z ranges ...
WORKSPACE = ((0.20, 0.95), (-0.55, 0.55), (0.0, 0.60))
WORKSPACE_MARGIN = 0.02  # ... grown by this, m
TTL_CAP = 0.2  # a command moves the arm at most this long after its receipt, s
COMMAND_RATE_HZ = 60.0  # commands per second at most ...
COMMAND_BURST = 5  # ... and this many more in a burst (the token bucket's depth)
#: Where the arm's base stands in table coordinates (x, y, z m, yaw rad): legws' Panda
#: mount (``legws_daemon/arms/panda.py``). The workspace box is in table coordinates.
MOUNT = (ARM.mount.x, ARM.mount.y, ARM.mount.z, ARM.mount.yaw)


def log(message: str) -> None:
    """One line on stderr, terminal-safe."""
    safe = "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)
    print(f"franka_bridge: {safe}", file=sys.stderr, flush=True)


class Throttled:
    """Log a kind of line at most once per ``interval`` seconds."""

    def __init__(self, interval: float = 1.0) -> None:
        self.interval = interval
        self._last: dict[str, float] = {}

    def __call__(self, kind: str, message: str) -> None:
        now = time.monotonic()
        if now - self._last.get(kind, -math.inf) >= self.interval:
            self._last[kind] = now
            log(message)


class CommandError(ValueError):
    """A payload that does not follow the contract; the message names the field."""

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
    except (ValueError, RecursionError) as err:  # JSONDecodeError and UnicodeDecodeError
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


def _seq(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEQ:
        raise CommandError("seq", f"expected an integer in [0, 2^63 - 1], got {value!r}")
    return value


def parse_command(payload: bytes) -> Command:
    """Validate one command payload (JSON); raises :class:`CommandError` naming the field."""
    data = _json_object(payload, _COMMAND_FIELDS)
    for name in ("seq", "stamp", "mode", "dq", "ttl"):
        if name not in data:
            raise CommandError(name, "missing")
    seq = _seq(data["seq"])
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


def check_stop(payload: bytes) -> None:
    """Validate a stop payload (empty: no detail). A stop stops whatever its payload: this
    only decides whether it is counted as invalid."""
    if not payload:
        return
    data = _json_object(payload, _STOP_FIELDS)
    if data.get("stamp") is not None:
        _number(data["stamp"], "stamp")
    _text(data.get("source"), "source", 64)
    _text(data.get("reason"), "reason", 200)


def check_resume(payload: bytes) -> None:
    """Validate a resume payload ``{"schema": 1, "seq", "stamp"}``."""
    data = _json_object(payload, _RESUME_FIELDS)
    for name in ("seq", "stamp"):
        if name not in data:
            raise CommandError(name, "missing")
    _seq(data["seq"])
    _number(data["stamp"], "stamp")


def stop_role(key: str) -> str:
    """The role of a stop key (its last chunk), ``unknown`` for any other."""
    role = key.rsplit("/", 1)[-1]
    return role if role in STOP_ROLES else "unknown"


@dataclass(frozen=True)
class Limits:
    """The limits the bridge enforces itself (a legws profile's ``[bridge]`` and
    ``[workspace]``; the defaults are the profile's) and where the arm stands."""

    joint_speed_cap: float = JOINT_SPEED_CAP
    ee_speed_cap: float = EE_SPEED_CAP
    workspace: tuple[tuple[float, float], ...] = WORKSPACE  # table coordinates, m
    workspace_margin: float = WORKSPACE_MARGIN
    max_ttl: float = TTL_CAP
    command_rate_hz: float = COMMAND_RATE_HZ
    burst: int = COMMAND_BURST
    mount: tuple[float, float, float, float] = MOUNT  # x, y, z (m), yaw (rad)

    def __post_init__(self) -> None:
        """The profile's ranges; a ValueError names the field."""
        ranges = (
            ("joint_speed_cap", self.joint_speed_cap, 0.0, max(SPEED_LIMITS), False),
            ("ee_speed_cap", self.ee_speed_cap, 0.0, 2.0, False),
            ("workspace_margin", self.workspace_margin, 0.0, 0.2, True),
            ("max_ttl", self.max_ttl, 0.0, MAX_TTL, False),
            ("command_rate_hz", self.command_rate_hz, 0.0, 1000.0, False),
        )
        for name, value, lo, hi, closed in ranges:
            number = float(value)
            above = number >= lo if closed else number > lo
            if not (math.isfinite(number) and above and number <= hi):
                opening = "[" if closed else "("
                raise ValueError(f"{name} must be in {opening}{lo:g}, {hi:g}], got {value!r}")
        if isinstance(self.burst, bool) or not isinstance(self.burst, int) or self.burst < 1:
            raise ValueError(f"burst must be an integer >= 1, got {self.burst!r}")
        if len(self.workspace) != 3:
            raise ValueError("workspace must have x, y and z ranges")
        for axis, (lo, hi) in zip("xyz", self.workspace):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"workspace {axis} must be [low, high] with low < high")
        if len(self.mount) != 4 or not all(math.isfinite(v) for v in self.mount):
            raise ValueError("mount must be four finite numbers: x y z yaw")

    def describe(self) -> str:
        box = " ".join(f"{axis} [{lo:g}, {hi:g}]" for axis, (lo, hi) in zip("xyz", self.workspace))
        mount = " ".join(f"{v:g}" for v in self.mount)
        return (
            f"joint speed <= {self.joint_speed_cap:g} rad/s, EE speed <= {self.ee_speed_cap:g} "
            f"m/s, EE in {box} m + {self.workspace_margin:g} m (table coordinates, base at "
            f"{mount}), ttl <= {self.max_ttl:g} s, <= {self.command_rate_hz:g} commands/s "
            f"(burst {self.burst})"
        )


_PROFILE_BRIDGE_KEYS = (
    "joint_speed_cap",
    "ee_speed_cap",
    "workspace_margin",
    "max_ttl",
    "command_rate_hz",
)
#: Largest hardware profile read (as legws_daemon.formats.files.LIMITS).
MAX_PROFILE_BYTES = 256 * 1024


def _profile_number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    return float(value)


def profile_limits(path: str) -> Limits:
    """The limits of a legws hardware profile (``[bridge]``, ``[workspace]``; what it
    leaves out keeps the default). Raises ValueError (or OSError) naming the problem."""
    if tomllib is None:
        raise ValueError("--profile needs Python >= 3.11 (tomllib); give the limits as flags")
    st = os.stat(path)  # a device, FIFO or huge file is refused before it is opened
    if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_PROFILE_BYTES:
        raise ValueError(f"{path}: expected a regular file of at most {MAX_PROFILE_BYTES} bytes")
    with open(path, "rb") as f:
        try:
            doc = tomllib.load(f)
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"{path}: not TOML: {err}") from None
    values: dict[str, Any] = {}
    bridge = doc.get("bridge", {})
    if not isinstance(bridge, dict):
        raise ValueError(f"{path}: [bridge] must be a table")
    for key, value in bridge.items():
        if key not in _PROFILE_BRIDGE_KEYS:
            raise ValueError(f"{path}: bridge.{key}: unknown field")
        values[key] = _profile_number(value, f"{path}: bridge.{key}")
    workspace = doc.get("workspace", {})
    if not isinstance(workspace, dict):
        raise ValueError(f"{path}: [workspace] must be a table")
    ranges = []
    for i, axis in enumerate("xyz"):
        pair = workspace.get(axis, WORKSPACE[i])
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise ValueError(f"{path}: workspace.{axis}: expected [low, high]")
        ranges.append(tuple(_profile_number(v, f"{path}: workspace.{axis}") for v in pair))
    values["workspace"] = tuple(ranges)
    try:
        return Limits(**values)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None


class Ramp:
    """Joint velocities that follow a target with bounded acceleration and jerk.

    libfranka's motion generator refuses a velocity command whose acceleration or jerk
    breaks the arm's limits, so a step in the target (a new command, a stop) becomes a
    smooth change: the acceleration goes toward ``gain`` x the velocity error, at most
    ``accel`` (rad/s²), changing by at most ``jerk`` x one control cycle per command.

    A command that comes late (``dt`` several cycles: a loaded bridge PC) continues what
    the robot did meanwhile: the FCI applies one command per 1 ms cycle and extrapolates
    the missed ones at the last acceleration, then differences the late command against
    that extrapolation over one cycle. So the missed cycles are integrated at the
    acceleration held, and only the last one changes it — a change spread over ``dt``
    would reach the robot as the whole of it in one cycle (a 21 rad/s² "acceleration
    discontinuity" from a 5 rad/s² ramp, three cycles late, once in CI).
    """

    def __init__(
        self,
        accel: Sequence[float],
        jerk: Sequence[float],
        gain: float = RAMP_GAIN,
    ) -> None:
        self.accel = [float(a) for a in accel]
        self.jerk = [float(j) for j in jerk]
        self.gain = gain
        self.v = [0.0] * len(self.accel)
        self.a = [0.0] * len(self.accel)

    def reset(self, velocities: Sequence[float] | None = None) -> None:
        self.v = [float(x) for x in velocities] if velocities is not None else [0.0] * len(self.v)
        self.a = [0.0] * len(self.v)

    def step(self, target: Sequence[float], dt: float) -> list[float]:
        """The next velocities, ``dt`` seconds on (one control cycle or more), toward
        ``target``."""
        cycle = min(dt, CONTROL_PERIOD) if dt > 0.0 else CONTROL_PERIOD
        missed = max(0.0, dt - cycle)  # the robot held the acceleration through these
        for i, goal in enumerate(target):
            held = self.v[i] + self.a[i] * missed  # where the robot's reference is now
            wanted = max(-self.accel[i], min(self.accel[i], self.gain * (goal - held)))
            change = self.jerk[i] * cycle
            a = self.a[i] + max(-change, min(change, wanted - self.a[i]))
            v = held + a * cycle
            if goal == 0.0 and abs(v) < REST_SPEED and abs(a) < REST_ACCEL:
                v = 0.0  # at rest (a step of at most REST_SPEED in one cycle)
            # the acceleration the robot measures (and holds through a late cycle): the
            # ramp's own, or the small one of the step to rest
            self.a[i] = (v - held) / cycle
            self.v[i] = v
        return list(self.v)

    def at_rest(self) -> bool:
        return not any(self.v) and not any(self.a)

    def braking_time(self, speeds: Sequence[float]) -> float:
        """About how long the ramp takes from ``speeds`` to rest, s."""
        return max(abs(v) / a for v, a in zip(speeds, self.accel)) + 2.0 / self.gain


def default_ramp() -> Ramp:
    return Ramp(
        [ACCEL_FRACTION * a for a in ACCEL_LIMITS], [JERK_FRACTION * j for j in JERK_LIMITS]
    )


def guard_joint_limits(
    q: Sequence[float], target: Sequence[float], accel: Sequence[float], period: float
) -> list[float]:
    """``target`` with no joint driven to (or past) a position limit: a joint whose braking
    distance from this speed (plus one period) reaches the limit less LIMIT_GUARD gets 0."""
    out = []
    for qi, vi, lo, hi, a in zip(q, target, LOWER, UPPER, accel):
        reach = qi + vi * period + math.copysign(vi * vi / (2.0 * a), vi)
        outward = (vi > 0.0 and reach >= hi - LIMIT_GUARD) or (
            vi < 0.0 and reach <= lo + LIMIT_GUARD
        )
        out.append(0.0 if outward else float(vi))
    return out


def linear_jacobian(jacobian: Sequence[float]) -> list[list[float]]:
    """The 3 x 7 linear rows of libfranka's zero Jacobian (42 values, column-major)."""
    return [[float(jacobian[6 * j + r]) for j in range(len(JOINT_NAMES))] for r in range(3)]


def endpoint_position(o_t_ee: Sequence[float]) -> list[float]:
    """The endpoint's position in the base frame from libfranka's ``O_T_EE`` (column-major)."""
    return [float(o_t_ee[12]), float(o_t_ee[13]), float(o_t_ee[14])]


class TableFrame:
    """The arm's base frame to table coordinates (the base at the mount, turned by its
    yaw): the workspace box is in table coordinates, like the profile's."""

    def __init__(self, mount: Sequence[float]) -> None:
        x, y, z, yaw = mount
        self._origin = (float(x), float(y), float(z))
        self._cos, self._sin = math.cos(yaw), math.sin(yaw)

    def to_table(self, v: Sequence[float], point: bool) -> list[float]:
        """A point (``point``) or a vector of the base frame, in table coordinates."""
        x = self._cos * v[0] - self._sin * v[1]
        y = self._sin * v[0] + self._cos * v[1]
        if not point:
            return [x, y, float(v[2])]
        ox, oy, oz = self._origin
        return [ox + x, oy + y, oz + float(v[2])]


def robot_status(mode_name: str, fault: str | None) -> tuple[bool, bool]:
    """``(enabled, estop)`` from libfranka's robot mode: enabled in ``Idle`` and ``Move``
    without a fault the control loop caught; the user stop is the e-stop."""
    return mode_name in ("Idle", "Move") and fault is None, mode_name == "UserStopped"


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


@dataclass(frozen=True)
class ArmState:
    """One robot state as the control loop read it."""

    q: tuple[float, ...]
    dq: tuple[float, ...]
    o_t_ee: tuple[float, ...]  # the endpoint's pose, base frame, column-major 4 x 4
    mode: str  # libfranka's RobotMode name
    fault: str | None  # why the control loop's last motion ended in an error, if it did
    received: float  # monotonic time of the read
    raw: Any  # the library's RobotState (for the model)


class FrankaArm:
    """The control loop: the only user of the ``pylibfranka.Robot`` (one thread).

    When a live target comes, it starts joint velocity control (``JointImpedance``) and, at
    every 1 ms cycle, ``readOnce`` / ``writeOnce``: the target's velocities through the
    :class:`Ramp`, zero (braking) once the target has expired. At rest with no live target
    for :data:`IDLE_FINISH` it ends the motion (``motion_finished``) and reads the state
    with ``read_once`` until the next target. An error of the library (a reflex, a network
    fault) ends the motion: the fault is kept (the bridge reports the arm disabled) until
    :meth:`recover`, which runs ``automatic_error_recovery``.
    """

    def __init__(
        self,
        robot: Any,
        library: Any,
        ramp: Ramp | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.robot = robot
        self.lib = library
        self.ramp = ramp if ramp is not None else default_ramp()
        self.clock = clock
        self._lock = threading.Lock()
        self._target = [0.0] * len(JOINT_NAMES)
        self._expires = -math.inf
        self._latest: ArmState | None = None
        self._fault: str | None = None
        self._recover = False
        self._quit = threading.Event()
        self._closing = False  # end the motion as soon as the arm is at rest
        self._control: Any = None
        self._idle_since: float | None = None  # at rest with no live target since (moving)
        self._in_motion = 0  # control cycles of this motion
        self.motions = 0  # motions started
        self.cycles = 0  # control cycles written
        #: the lowest share of the robot's last 100 cycles that got a command in time
        #: (libfranka's ``control_command_success_rate``), during a motion
        self.success_rate = 1.0
        #: the longest the loop took from a state read to its command written, s
        self.longest_cycle = 0.0
        self._log = Throttled()
        self._thread = threading.Thread(target=self._run, name="franka-control", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def set_target(self, velocities: Sequence[float] | None, expires: float) -> None:
        """The velocities to track until ``expires`` (monotonic); ``None``: brake to rest."""
        with self._lock:
            if velocities is None:
                self._target, self._expires = [0.0] * len(JOINT_NAMES), -math.inf
            else:
                self._target, self._expires = [float(v) for v in velocities], expires

    def latest(self) -> ArmState | None:
        with self._lock:
            return self._latest

    def recover(self) -> None:
        """Run the library's automatic error recovery at the next idle read."""
        with self._lock:
            self._recover = True

    def moving(self) -> bool:
        return self._control is not None

    def close(self, timeout: float = 2.0) -> None:
        """Brake to rest, end the motion and stop the loop."""
        self._closing = True
        self.set_target(None, -math.inf)
        deadline = time.monotonic() + timeout
        while self._control is not None and time.monotonic() < deadline and self._thread.is_alive():
            time.sleep(0.005)
        self._quit.set()
        if self._thread.is_alive():
            self._thread.join(timeout=max(0.1, deadline - time.monotonic()))

    def _keep(self, state: Any) -> None:
        mode = getattr(state.robot_mode, "name", str(state.robot_mode))
        with self._lock:
            self._latest = ArmState(
                tuple(float(v) for v in state.q),
                tuple(float(v) for v in state.dq),
                tuple(float(v) for v in state.O_T_EE),
                str(mode),
                self._fault,
                self.clock(),
                state,
            )

    def _live_target(self, now: float) -> list[float] | None:
        with self._lock:
            if now < self._expires and self._fault is None and any(self._target):
                return list(self._target)
        return None

    def _run(self) -> None:
        while not self._quit.is_set():
            self.cycle()

    def cycle(self) -> None:
        """One turn of the control loop (the thread's, over and over): idle, a state read
        (and the recovery or the start of a motion when due); moving, one control cycle —
        ``readOnce``, the ramp toward the live target (or braking), ``writeOnce`` — which
        libfranka paces at 1 kHz. An error of the library ends the motion (the fault kept)."""
        try:
            if self._control is None:
                state = self.robot.read_once()
                self._keep(state)
                with self._lock:
                    recover, self._recover = self._recover, False
                if recover:
                    self.robot.automatic_error_recovery()
                    with self._lock:
                        self._fault = None
                    return
                if self._live_target(self.clock()) is not None and not self._closing:
                    self.ramp.reset()
                    self._control = self.robot.start_joint_velocity_control(
                        self.lib.ControllerMode.JointImpedance
                    )
                    self.motions += 1
                    self._idle_since = None
                    self._in_motion = 0
                return
            state, period = self._control.readOnce()
            read_at = time.perf_counter()
            self._keep(state)
            self._in_motion += 1
            if self._in_motion > 200:  # the rate is over the last 100 cycles
                rate = float(state.control_command_success_rate)
                self.success_rate = min(self.success_rate, rate)
            now = self.clock()
            dt = period.to_sec() or CONTROL_PERIOD
            target = self._live_target(now)
            velocities = self.ramp.step(target or [0.0] * len(JOINT_NAMES), dt)
            finished = False
            if target is None and self.ramp.at_rest():
                self._idle_since = now if self._idle_since is None else self._idle_since
                finished = now - self._idle_since >= IDLE_FINISH or self._closing
            else:
                self._idle_since = None
            command = self.lib.JointVelocities(velocities)
            if finished:
                command.motion_finished = True
            self._control.writeOnce(command)
            self.cycles += 1
            self.longest_cycle = max(self.longest_cycle, time.perf_counter() - read_at)
            if finished:
                self._control = None
        except Exception as err:  # the library's errors: a reflex, the network, a command
            self._control = None
            self.ramp.reset()
            with self._lock:
                self._fault = f"{type(err).__name__}: {err}"
            self._log("fault", f"motion ended: {type(err).__name__}: {str(err)[:300]}")
            time.sleep(0.01)


class GripperDriver:
    """The Franka Hand (``pylibfranka.Gripper``) in a thread of its own: its moves block.

    ``open``: move to the hand's opening; ``closed``: grasp at width 0 with an outer
    tolerance of the whole opening (succeeds on whatever it closes on). ``None``: no hand.
    """

    def __init__(self, gripper: Any) -> None:
        self._gripper = gripper
        self.requested: str | None = None
        self._done: str | None = None
        self._pending: str | None = None
        self._busy = False
        self._failed = False
        self._wake = threading.Condition()
        self._quit = False
        self._thread: threading.Thread | None = None
        if gripper is not None:
            self._thread = threading.Thread(target=self._run, name="franka-gripper", daemon=True)
            self._thread.start()

    def command(self, request: str) -> None:
        self.requested = request
        if self._gripper is None:
            return
        with self._wake:
            self._pending = request
            self._wake.notify()

    def status(self) -> str:
        """``open``, ``closed``, ``moving`` or ``unknown`` (no hand, never commanded, or its
        last move failed)."""
        if self._gripper is None or self.requested is None:
            return "unknown"
        with self._wake:
            if self._busy or self._pending is not None:
                return "moving"
            if self._failed or self._done is None:
                return "unknown"
            return self._done

    def close(self) -> None:
        with self._wake:
            self._quit = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join(timeout=1.0)

    def _run(self) -> None:
        while True:
            with self._wake:
                while self._pending is None and not self._quit:
                    self._wake.wait()
                if self._quit:
                    return
                request, self._pending, self._busy = self._pending, None, True
            failed = False
            try:
                width = float(self._gripper.read_once().max_width) or GRIPPER_MAX_WIDTH
                if request == "open":
                    self._gripper.move(width, GRIPPER_SPEED)
                else:
                    self._gripper.grasp(0.0, GRIPPER_SPEED, GRIPPER_FORCE, 0.005, width)
            except Exception as err:  # the library's errors: the hand stays "unknown"
                failed = True
                log(f"gripper {request} failed: {type(err).__name__}: {str(err)[:200]}")
            with self._wake:
                self._busy, self._failed, self._done = False, failed, request


class FrankaBridge:
    """The bridge's work: commands, stops and resumes in (zenoh threads); every tick the
    live command as the control loop's target within the limits, and the state out.

    The limits are legws' one guard of every bridge (:func:`load_guard`: validity, rate,
    stop latch, joint speed, command life; then every tick the deadman, the joint position
    limits, the endpoint speed and the workspace on the commanded step's kinematics, here
    libfranka's endpoint and zero Jacobian at the measured joints, linearised, in table
    coordinates). The bridge adds the contract's message checks before it and, after it,
    no joint whose braking distance reaches its position limit.

    Args:
        session: an open zenoh session (closed by the caller).
        robot: the robot name: keys under ``legws/<robot>/``.
        arm: the control loop (:class:`FrankaArm`, started).
        model: the library's ``Model`` (``zero_jacobian(state)``).
        gripper: the gripper driver.
        limits: the bridge's own limits.
        period: the tick period, s.
    """

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        arm: FrankaArm,
        model: Any,
        gripper: GripperDriver,
        *,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        limits: Limits | None = None,
        period: float = 1.0 / STATE_RATE_HZ,
    ) -> None:
        self.state_key = f"legws/{robot}/bridge/state"
        self.command_key = f"legws/{robot}/bridge/command"
        self.resume_key = f"legws/{robot}/bridge/resume"
        self.stop_key = f"legws/{robot}/stop/*"
        self.arm = arm
        self.model = model
        self.gripper = gripper
        self.clock = clock
        self.wall = wall
        self.period = period
        self.limits = limits if limits is not None else Limits()
        self.frame = TableFrame(self.limits.mount)
        self._linear: tuple[tuple[float, ...], list[float], list[list[float]]] | None = None
        lim = self.limits
        self.guard = guard_module.Guard(
            LOWER,
            UPPER,
            SPEED_LIMITS,
            guard_module.BridgeLimits(
                joint_speed_cap=lim.joint_speed_cap,
                ee_speed_cap=lim.ee_speed_cap,
                workspace=lim.workspace,
                workspace_margin=lim.workspace_margin,
                max_ttl=lim.max_ttl,
                command_rate_hz=lim.command_rate_hz,
                burst=lim.burst,
            ),
            clock=clock,
            ee_position=self._ee_position,
            period=period,
        )
        self.counts = self.guard.counts
        self.rejected = 0
        self.accepted = 0
        self.stops = 0
        self.invalid_stops = 0
        self.resumes = 0
        self.rejected_resumes = 0
        self._lock = threading.Lock()
        self._gripper_request: str | None = None
        self._halted = False
        self._seq = 0
        self._log = Throttled()
        self._publisher = session.declare_publisher(self.state_key)
        self._subscribers = [
            session.declare_subscriber(self.command_key, self._on_command),
            session.declare_subscriber(self.stop_key, self._on_stop),
            session.declare_subscriber(self.resume_key, self._on_resume),
        ]

    @property
    def stopped_by(self) -> str | None:
        return self.guard.stopped_by  # type: ignore[no-any-return]

    def _ee_position(self, q: Sequence[float]) -> list[float] | None:
        """The endpoint at ``q`` in table coordinates: libfranka's endpoint and Jacobian at
        this tick's measured joints, to first order (the guard's steps are short)."""
        if self._linear is None:
            return None
        q0, p0, rows = self._linear
        dq = [a - b for a, b in zip(q, q0)]
        return [p + sum(r * d for r, d in zip(row, dq)) for p, row in zip(p0, rows)]

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
            self._log("rejected", f"command rejected: {err}")
            return
        with self._lock:
            self.accepted += 1
            if self._halted:
                self.guard.admit(now)  # the rate still measures the sender
                return
            verdict = self.guard.command(command.dq, command.ttl, now)
            if verdict == "accepted" and command.gripper is not None:
                self._gripper_request = command.gripper

    def handle_stop(self, key: str, payload: bytes) -> None:
        """Any sample on a stop key stops the arm and latches."""
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
        self.arm.set_target(None, -math.inf)
        self._log("stop", f"stopped by {role} ({key})")

    def handle_resume(self, payload: bytes) -> None:
        """A valid resume (the daemon's) clears every latched stop (no command comes back)
        and recovers the arm from a reflex."""
        try:
            check_resume(payload)
        except CommandError as err:
            with self._lock:
                self.rejected_resumes += 1
            self._log("resume", f"resume rejected: {err}")
            return
        with self._lock:
            self.resumes += 1
            self.guard.resume()
        state = self.arm.latest()
        if state is not None and (state.fault is not None or state.mode == "Reflex"):
            self.arm.recover()

    def tick(self) -> None:
        """The live command as the control loop's target (or braking), the gripper, the
        state published."""
        now = self.clock()
        state = self.arm.latest()
        if state is None or now - state.received > STATE_STALE:
            with self._lock:
                self.guard.clear()
            self.arm.set_target(None, -math.inf)
            return  # no fresh state of the robot: no heartbeat either
        enabled, estop = robot_status(state.mode, state.fault)
        with self._lock:
            target: list[float] | None = None
            expires = -math.inf
            if self._halted or not enabled or estop:
                self.guard.clear()
            elif self.guard.live is not None:
                live = self.guard.live
                try:
                    jacobian = self.model.zero_jacobian(state.raw)
                except Exception as err:  # no model: no endpoint, the guard stops the arm
                    self._log("model", f"no Jacobian ({type(err).__name__}); holding")
                    self._linear = None
                else:
                    rows = linear_jacobian(jacobian)
                    columns = [self.frame.to_table(c, False) for c in zip(*rows)]
                    self._linear = (
                        state.q,
                        self.frame.to_table(endpoint_position(state.o_t_ee), True),
                        [list(r) for r in zip(*columns)],
                    )
                horizon = self.period + self.arm.ramp.braking_time(live.dq)
                step = self.guard.step(state.q, now, now + self.period, horizon=horizon)
                if step.moving:
                    target = guard_joint_limits(
                        state.q, step.velocity, self.arm.ramp.accel, self.period
                    )
                    after = self.guard.live
                    expires = (
                        min(after.expires, now + HANDOFF)
                        if after is not None
                        else now + step.duration
                    )
            if target is not None and any(target):
                self.arm.set_target(target, expires)
            else:
                self.arm.set_target(None, -math.inf)
            request, self._gripper_request = self._gripper_request, None
            stopped_by = self.guard.stopped_by
            limited = self.guard.take_limited()
        if request is not None and request != self.gripper.requested and enabled and not estop:
            self.gripper.command(request)
        try:
            payload = state_message(
                self._seq,
                self.wall(),
                state.q,
                state.dq,
                self.gripper.status(),
                enabled,
                estop,
                stopped_by if stopped_by in STOP_ROLES or stopped_by is None else "unknown",
                limited,
            )
        except ValueError as err:
            self._log("state", f"state not published: {err}")
            return
        if limited:
            self._log("limits", f"limits enforced: {', '.join(limited)}")
        self._seq += 1
        self._publisher.put(payload)

    def halt(self) -> None:
        """Stop for good (shutdown): brake, no further command is applied."""
        with self._lock:
            self._halted = True
            self.guard.clear()
        self.arm.set_target(None, -math.inf)

    def close(self) -> None:
        """Halt and undeclare; the session is closed by its owner."""
        self.halt()
        for entity in [*self._subscribers, self._publisher]:
            with contextlib.suppress(zenoh.ZError):  # a closed session: nothing left
                entity.undeclare()


# --- the transport: the same rules as intera_bridge.py ----------------------------------


def zenoh_config(path: str | None, connect: Sequence[str], listen: Sequence[str]) -> zenoh.Config:
    """A JSON5 file for the real network, else a loopback peer without multicast scouting
    or gossip, dialling again every 0.1-0.5 s."""
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
    """What makes ``config`` unauthenticated, or ``None`` (the daemon's rule): TLS endpoints
    only, mutual TLS or user/password, and an access control denying by default."""
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


_ENDPOINT = re.compile(
    r"(tcp|udp|tls|quic)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9.-]*):([0-9]{1,5})"
)


def endpoint_problem(text: str) -> str | None:
    """What is wrong with a zenoh endpoint PROTOCOL/HOST:PORT, or ``None``."""
    m = _ENDPOINT.fullmatch(text)
    if m is None:
        return f"expected PROTOCOL/HOST:PORT (tcp, udp, tls or quic), got {text[:80]!r}"
    if not 1 <= int(m.group(3)) <= 65535:
        return f"port {m.group(3)} is not in 1..65535"
    return None


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="franka_bridge.py", description="legws bridge for a Franka arm (pylibfranka)."
    )
    parser.add_argument("--robot-ip", required=True, help="the arm's FCI address (the control box)")
    parser.add_argument(
        "--realtime",
        choices=("enforce", "ignore"),
        default="enforce",
        help="libfranka's realtime rule: enforce (a PREEMPT_RT kernel, the real arm) or "
        "ignore (a simulator, a test)",
    )
    parser.add_argument("--no-gripper", action="store_true", help="no Franka Hand")
    parser.add_argument("--robot", default="panda", help="robot name of the zenoh keys")
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
        help="the endpoint's box, table coordinates, m (default "
        + " ".join(f"{v:g}" for pair in WORKSPACE for v in pair)
        + ")",
    )
    limits.add_argument("--workspace-margin", type=float, help=f"m (default {WORKSPACE_MARGIN:g})")
    limits.add_argument(
        "--mount",
        type=float,
        nargs=4,
        metavar=("X", "Y", "Z", "YAW"),
        help="the arm's base in table coordinates, m and rad (default "
        + " ".join(f"{v:g}" for v in MOUNT)
        + ")",
    )
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
    if args.mount is not None:
        changes["mount"] = tuple(args.mount)
    return replace(limits, **changes)


def _first_line(err: BaseException) -> str:
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def _fail(message: str) -> int:
    """One line on stderr, exit code 2."""
    safe = "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)
    print(f"franka_bridge.py: error: {safe}", file=sys.stderr)
    return 2


def open_gripper(library: Any, address: str) -> GripperDriver:
    """The Franka Hand, or a driver reporting ``unknown`` when there is none."""
    try:
        gripper = library.Gripper(address)
    except Exception as err:  # no hand (the connection is refused) or another fault
        log(f"no gripper ({_first_line(err)}); gripper requests are ignored")
        gripper = None
    return GripperDriver(gripper)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the bridge until SIGINT/SIGTERM; returns the exit code."""
    args = parse_args(list(sys.argv[1:] if argv is None else argv))
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
    if problem is not None:
        log(f"INSECURE TRANSPORT: {problem}")
    try:
        import pylibfranka as library
    except ImportError as err:
        return _fail(f"pylibfranka is not installed ({err}): pip install pylibfranka")
    realtime = {
        "enforce": library.RealtimeConfig.kEnforce,
        "ignore": library.RealtimeConfig.kIgnore,
    }[args.realtime]
    try:
        robot = library.Robot(args.robot_ip, realtime)
        model = robot.load_model()
    except Exception as err:  # the library's network, protocol and realtime errors
        return _fail(f"cannot reach the arm at {args.robot_ip}: {_first_line(err)}")
    gripper = GripperDriver(None) if args.no_gripper else open_gripper(library, args.robot_ip)
    quit_event = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        quit_event.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    arm = FrankaArm(robot, library)
    arm.start()
    try:
        try:
            session = zenoh.open(config)
        except Exception as err:
            return _fail(f"cannot open a zenoh session: {_first_line(err)}")
        try:
            bridge = FrankaBridge(
                session, args.robot, arm, model, gripper, limits=args.limits, period=1.0 / args.rate
            )
            try:
                log(f"{bridge.state_key} at {args.rate:g} Hz, arm at {args.robot_ip}")
                log(f"limits: {args.limits.describe()}")
                period = 1.0 / args.rate
                next_tick = time.monotonic()
                while not quit_event.is_set():
                    bridge.tick()
                    next_tick += period
                    delay = next_tick - time.monotonic()
                    if delay < -period:  # fell behind: start afresh
                        next_tick, delay = time.monotonic(), 0.0
                    quit_event.wait(max(0.0, delay))
            finally:
                bridge.close()
        finally:
            session.close()  # type: ignore[no-untyped-call]
    finally:
        arm.close()
        gripper.close()
    log(
        f"stopped ({arm.motions} motions, {arm.cycles} control cycles, commands in time "
        f">= {100 * arm.success_rate:.0f} %, the longest cycle {1e3 * arm.longest_cycle:.2f} ms)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
