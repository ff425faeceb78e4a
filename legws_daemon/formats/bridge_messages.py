"""The robot-side bridge contract: joint state in, joint velocity commands out.

Keys live under ``legws/<robot>/bridge/`` (see ``docs/bridge.md``): the bridge publishes
``state`` (≥ 100 Hz, its heartbeat) and subscribes to ``command`` (one per control tick).
Both messages are JSON with ``"schema": 1``, validated on receipt; a payload that does not
validate is an :class:`~legws_daemon.errors.InputError` naming the field, and is never used.

The joint vectors are the arm's: as many as its joints, in the order of its description's
:attr:`~legws_daemon.arms.spec.ArmSpec.hardware_joints` (the Sawyer's ``right_j0`` ..
``right_j6``, the Panda's ``panda_joint1`` .. ``panda_joint7``, the UR5e's six), each
commanded speed within that joint's limit. :func:`bridge_contract` gives one arm's message
types and parsers, derived from its description (:func:`legws_daemon.arms.arm`), the one
every part reads; the bridges read the same tables.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal

from pydantic import AllowInfNan, Field, Strict, StrictBool, model_validator

from legws_daemon.arms import ArmSpec, arm
from legws_daemon.formats.messages import Seq, _Message, parse
from legws_daemon.formats.validation import Finite, field_error

#: A commanded joint speed may exceed its limit by this much (floating-point slack), rad/s.
SPEED_TOLERANCE = 1e-6
#: Longest time-to-live of one command, s: no single message may keep the arm moving longer.
MAX_TTL = 1.0
#: Most joints of any arm on the wire (a vector longer than this is refused unread).
MAX_JOINTS = 12

#: A measured joint angle, rad: finite, within one turn either way.
Angle = Annotated[float, Strict(), AllowInfNan(False), Field(ge=-6.3, le=6.3)]
#: A joint velocity, rad/s: finite, at most 10 rad/s in magnitude (speed limits checked apart).
JointSpeed = Annotated[float, Strict(), AllowInfNan(False), Field(ge=-10.0, le=10.0)]
Joints = Annotated[tuple[Angle, ...], Field(min_length=1, max_length=MAX_JOINTS)]
JointSpeeds = Annotated[tuple[JointSpeed, ...], Field(min_length=1, max_length=MAX_JOINTS)]
Ttl = Annotated[float, Strict(), AllowInfNan(False), Field(gt=0.0, le=MAX_TTL)]

GripperState = Literal["open", "closed", "moving", "unknown"]
GripperRequest = Literal["open", "closed"]


#: The authenticated roles that may stop the robot (``legws/<robot>/stop/<role>``).
StopRole = Literal["operator", "observer", "safety", "bridge", "daemon"]
STOP_ROLES: tuple[str, ...] = ("operator", "observer", "safety", "bridge", "daemon")
#: A limit the bridge enforced itself (``BridgeState.limited``).
Limit = Literal["joint_speed", "ee_speed", "workspace", "ttl", "rate"]


def _check_joints(arm_spec: ArmSpec | None, field: str, values: tuple[float, ...]) -> None:
    """``values`` has one entry per joint of the arm (an arm is required: a message type
    without one is :class:`BridgeState`/:class:`BridgeCommand` itself, only an annotation)."""
    if arm_spec is None:
        raise field_error(
            (field,), "a bridge message is validated for an arm: use bridge_contract(arm)"
        )
    if len(values) != arm_spec.dof:
        raise field_error(
            (field,),
            f"expected {arm_spec.dof} joints ({arm_spec.title}: "
            f"{', '.join(arm_spec.hardware_joints)}), got {len(values)}",
        )


class BridgeState(_Message):
    """``legws/<robot>/bridge/state``: what the robot measures (bridge -> daemon, ≥ 100 Hz).

    The stream is the bridge's heartbeat: the daemon faults when it stops. Validated as one
    arm's (:attr:`BridgeContract.State`).
    """

    #: the arm whose joints the vectors are (set on :func:`bridge_contract`'s subclasses)
    arm: ClassVar[ArmSpec | None] = None

    seq: Seq
    stamp: Finite  # the bridge's clock, s (logged; staleness uses the receive time)
    q: Joints  # joint angles in the arm's joint order, rad
    dq: JointSpeeds  # joint velocities, rad/s
    gripper: GripperState
    enabled: StrictBool  # the robot is enabled (motors powered)
    estop: StrictBool  # an emergency stop is engaged
    #: a stop from this role is latched: no motion until the daemon's resume (None: none;
    #: ``unknown``: a stop on a key of no known role, which stops all the same)
    stopped_by: StopRole | Literal["unknown"] | None = None
    #: the limits the bridge enforced since its previous state message
    limited: tuple[Limit, ...] = ()

    @model_validator(mode="after")
    def _arms_joints(self) -> BridgeState:
        _check_joints(type(self).arm, "q", self.q)
        _check_joints(type(self).arm, "dq", self.dq)
        return self


class BridgeCommand(_Message):
    """``legws/<robot>/bridge/command``: joint velocities for ``ttl`` seconds (daemon -> bridge).

    ``gripper`` is the requested gripper state (``null``: no request); the bridge acts when
    the request changes. Validated as one arm's (:attr:`BridgeContract.Command`): each speed
    within its joint's limit.
    """

    arm: ClassVar[ArmSpec | None] = None

    seq: Seq
    stamp: Finite  # the daemon's clock, s (logged; the ttl runs from the receive time)
    mode: Literal["joint_velocity"]
    dq: JointSpeeds  # rad/s, each within its joint's speed limit
    ttl: Ttl
    gripper: GripperRequest | None = None

    @model_validator(mode="after")
    def _speed_limits(self) -> BridgeCommand:
        spec = type(self).arm
        _check_joints(spec, "dq", self.dq)
        assert spec is not None
        for i, (v, limit) in enumerate(zip(self.dq, spec.speed_limits, strict=True)):
            if abs(v) > limit + SPEED_TOLERANCE:
                raise field_error(
                    ("dq", i),
                    f"{spec.hardware_joints[i]} speed {v:g} rad/s exceeds its limit "
                    f"{limit:g} rad/s",
                )
        return self


@dataclass(frozen=True)
class BridgeContract:
    """One arm's side of the contract: its message types and parsers.

    Attributes:
        arm: the arm's description (joint names, order, position and speed limits).
        State, Command: :class:`BridgeState` and :class:`BridgeCommand` validated for it.
    """

    arm: ArmSpec
    State: type[BridgeState]
    Command: type[BridgeCommand]

    def parse_state(self, payload: bytes | str, source: str) -> BridgeState:
        """Validate one state payload; any problem is an InputError naming the field."""
        return parse(self.State, payload, source)

    def parse_command(self, payload: bytes | str, source: str) -> BridgeCommand:
        """Validate one command payload; any problem is an InputError naming the field."""
        return parse(self.Command, payload, source)


def bridge_contract(arm_spec: ArmSpec | str) -> BridgeContract:
    """The contract of one arm (a registered name or a description): made once per arm."""
    return _contract(arm(arm_spec) if isinstance(arm_spec, str) else arm_spec)


@functools.cache
def _contract(spec: ArmSpec) -> BridgeContract:
    tag = spec.name.title().replace("_", "")
    state = type(f"{tag}BridgeState", (BridgeState,), {"arm": spec, "__module__": __name__})
    command = type(f"{tag}BridgeCommand", (BridgeCommand,), {"arm": spec, "__module__": __name__})
    return BridgeContract(spec, state, command)


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
