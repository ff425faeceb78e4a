"""The robot-side bridge contract: joint state in, joint velocity commands out.

Keys live under ``legws/<robot>/bridge/`` (see ``docs/bridge.md``): the bridge publishes
``state`` (≥ 100 Hz, its heartbeat) and subscribes to ``command`` (one per control tick).
Joint order and the base frame are Intera's (``right_j0`` .. ``right_j6``). Both messages
are JSON with ``"schema": 1``, validated on receipt; a payload that does not validate is an
:class:`~legws_daemon.errors.InputError` naming the field, and is never used.

The joint tables below are the Sawyer's description (:func:`legws_daemon.arms.arm`), the
one every part reads; the bridges read them there too.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AllowInfNan, Field, Strict, StrictBool, model_validator

from legws_daemon.arms import arm
from legws_daemon.formats.messages import Seq, _Message, parse
from legws_daemon.formats.validation import Finite, field_error

_SAWYER = arm("sawyer")
#: Intera's joint names, in the order of every joint vector on the wire.
JOINT_NAMES: tuple[str, ...] = _SAWYER.hardware_joints
#: Joint speed limits, rad/s (the Sawyer's description: Intera's specification).
JOINT_SPEED_LIMITS: tuple[float, ...] = _SAWYER.speed_limits
#: Joint position limits, rad (the Sawyer's description).
JOINT_LOWER: tuple[float, ...] = _SAWYER.lower
JOINT_UPPER: tuple[float, ...] = _SAWYER.upper
#: A commanded joint speed may exceed its limit by this much (floating-point slack), rad/s.
SPEED_TOLERANCE = 1e-6
#: Longest time-to-live of one command, s: no single message may keep the arm moving longer.
MAX_TTL = 1.0

#: A measured joint angle, rad: finite, within one turn either way.
Angle = Annotated[float, Strict(), AllowInfNan(False), Field(ge=-6.3, le=6.3)]
#: A joint velocity, rad/s: finite, at most 10 rad/s in magnitude (speed limits checked apart).
JointSpeed = Annotated[float, Strict(), AllowInfNan(False), Field(ge=-10.0, le=10.0)]
Joints = tuple[Angle, Angle, Angle, Angle, Angle, Angle, Angle]
JointSpeeds = tuple[
    JointSpeed, JointSpeed, JointSpeed, JointSpeed, JointSpeed, JointSpeed, JointSpeed
]
Ttl = Annotated[float, Strict(), AllowInfNan(False), Field(gt=0.0, le=MAX_TTL)]

GripperState = Literal["open", "closed", "moving", "unknown"]
GripperRequest = Literal["open", "closed"]


#: The authenticated roles that may stop the robot (``legws/<robot>/stop/<role>``).
StopRole = Literal["operator", "observer", "safety", "bridge", "daemon"]
STOP_ROLES: tuple[str, ...] = ("operator", "observer", "safety", "bridge", "daemon")
#: A limit the bridge enforced itself (``BridgeState.limited``).
Limit = Literal["joint_speed", "ee_speed", "workspace", "ttl", "rate"]


class BridgeState(_Message):
    """``legws/<robot>/bridge/state``: what the robot measures (bridge -> daemon, ≥ 100 Hz).

    The stream is the bridge's heartbeat: the daemon faults when it stops.
    """

    seq: Seq
    stamp: Finite  # the bridge's clock, s (logged; staleness uses the receive time)
    q: Joints  # joint angles right_j0..right_j6, rad
    dq: JointSpeeds  # joint velocities, rad/s
    gripper: GripperState
    enabled: StrictBool  # the robot is enabled (motors powered)
    estop: StrictBool  # an emergency stop is engaged
    #: a stop from this role is latched: no motion until the daemon's resume (None: none;
    #: ``unknown``: a stop on a key of no known role, which stops all the same)
    stopped_by: StopRole | Literal["unknown"] | None = None
    #: the limits the bridge enforced since its previous state message
    limited: tuple[Limit, ...] = ()


class BridgeCommand(_Message):
    """``legws/<robot>/bridge/command``: joint velocities for ``ttl`` seconds (daemon -> bridge).

    ``gripper`` is the requested gripper state (``null``: no request); the bridge acts when
    the request changes.
    """

    seq: Seq
    stamp: Finite  # the daemon's clock, s (logged; the ttl runs from the receive time)
    mode: Literal["joint_velocity"]
    dq: JointSpeeds  # rad/s, each within its joint's speed limit
    ttl: Ttl
    gripper: GripperRequest | None = None

    @model_validator(mode="after")
    def _speed_limits(self) -> BridgeCommand:
        for i, (v, limit) in enumerate(zip(self.dq, JOINT_SPEED_LIMITS, strict=True)):
            if abs(v) > limit + SPEED_TOLERANCE:
                raise field_error(
                    ("dq", i),
                    f"{JOINT_NAMES[i]} speed {v:g} rad/s exceeds its limit {limit:g} rad/s",
                )
        return self


class StopMessage(_Message):
    """``legws/<robot>/stop/<role>``: stop the robot (anyone authenticated -> daemon, bridge).

    The key names the role (the access control lets each role publish on its own key only);
    the payload only says more. Any sample on a stop key stops, even one whose payload does
    not validate.
    """

    stamp: Finite | None = None  # the sender's clock, s
    source: Annotated[str, Field(max_length=64)] | None = None  # who, in the sender's words
    reason: Annotated[str, Field(max_length=200)] | None = None


class ResumeMessage(_Message):
    """``legws/<robot>/bridge/resume``: clear a latched stop (the daemon only -> bridge)."""

    seq: Seq
    stamp: Finite


def bridge_keys(robot: str) -> dict[str, str]:
    """The bridge's key expressions of one robot (``legws/<robot>/bridge/...`` and the
    stop keys ``legws/<robot>/stop/*``)."""
    base = f"legws/{robot}/bridge"
    return {
        "state": f"{base}/state",
        "command": f"{base}/command",
        "resume": f"{base}/resume",
        "stop": f"legws/{robot}/stop/*",
    }


def stop_key(robot: str, role: str) -> str:
    """The key on which ``role`` stops ``robot``."""
    return f"legws/{robot}/stop/{role}"


def stop_role(key: str) -> str:
    """The role of a stop key (its last chunk); ``unknown`` when not a known role."""
    role = key.rsplit("/", 1)[-1]
    return role if role in STOP_ROLES else "unknown"


def parse_stop(payload: bytes | str, source: str) -> StopMessage:
    """Validate a stop payload (empty: no detail)."""
    if not payload:
        return StopMessage.model_validate({"schema": 1})
    return parse(StopMessage, payload, source)


def parse_resume(payload: bytes | str, source: str) -> ResumeMessage:
    return parse(ResumeMessage, payload, source)


def parse_state(payload: bytes | str, source: str) -> BridgeState:
    """Validate one state payload; any problem is an InputError naming the field."""
    return parse(BridgeState, payload, source)


def parse_command(payload: bytes | str, source: str) -> BridgeCommand:
    """Validate one command payload; any problem is an InputError naming the field."""
    return parse(BridgeCommand, payload, source)
