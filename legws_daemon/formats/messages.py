"""Messages on the wire (zenoh payloads): JSON with a schema version, validated on receipt.

Keys live under ``legws/<robot>/``: ``joystick`` (in), ``status`` and ``events`` (out),
``command`` (a queryable). A payload that does not validate is rejected with an
:class:`~legws_daemon.errors.InputError` naming the field; for the joystick a rejected
message counts as no input (the deadman then stops the robot), never as a guess.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import math
from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, Strict, StrictBool, model_validator

from legws_daemon.errors import InputError
from legws_daemon.formats.nesting import check_json_nesting
from legws_daemon.formats.validation import (
    Angle,
    Coordinate,
    DuplicateKeyError,
    Finite,
    Quat,
    Vec3,
    check_json_text,
    field_error,
    printable,
    unique_keys,
    validate,
)

SCHEMA_VERSION = 1
#: Largest payload accepted, bytes: a joystick or command message is a few hundred.
MAX_PAYLOAD = 64 * 1024

Axis = Annotated[float, Strict(), Field(ge=-1.0, le=1.0, allow_inf_nan=False)]
Seq = Annotated[int, Strict(), Field(ge=0, le=2**63 - 1)]
Label = Annotated[str, Field(min_length=1, max_length=64)]
#: A publisher session: 1 to 64 characters of letters, digits, ``-``, ``_``, ``.``, ``:``.
SessionId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:-]+$")]
#: A session key the daemon gives a publisher (``hello``): this many random bytes.
SESSION_KEY_BYTES = 32
#: The ``auth`` tag of a joystick message: HMAC-SHA256 truncated to this many hex digits.
AUTH_DIGITS = 32
#: How many hex digits of a session's public id status and events show.
PUBLIC_ID_DIGITS = 12
AuthTag = Annotated[str, Field(pattern=rf"^[0-9a-f]{{{AUTH_DIGITS}}}$")]


class _Message(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    schema_: Literal[1] = Field(alias="schema")


class Buttons(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    cancel: StrictBool = False  # give control back to the user during assistance
    confirm: StrictBool = False  # commit now: the object the hand is at, else the most likely
    #: the hold-to-run (enable) button: ``true`` held, ``false`` released — the message is
    #: then no input (zero velocity, assistance paused), however the stick stands. ``null``
    #: (or left out): the publisher has no such button; every message is enabled and the
    #: stream itself is the dead-man signal.
    enable: StrictBool | None = None
    #: the gripper the operator asks for: ``true`` closed, ``false`` open; ``null`` (or left
    #: out): no request (a publisher without a gripper button). Acted on in teleoperation.
    gripper: StrictBool | None = None

    @property
    def enabled(self) -> bool:
        """Whether the message is input (enable held, or no enable button)."""
        return self.enable is not False


class JoystickMessage(_Message):
    """A joystick sample: deflection ``axes`` (x, y, z in the robot base frame), |axes| <= 1."""

    seq: Seq
    stamp: Finite  # sender's clock, s (for logs; staleness uses the receive time)
    axes: tuple[Axis, Axis, Axis]
    buttons: Buttons = Buttons()
    source: Label = "unknown"
    #: chosen at random at each publisher start; ``seq`` counts within it. Without it the
    #: daemon takes ``source`` as the session (schema-1 publishers before sessions).
    session: SessionId | None = None
    #: the publisher's last message (it stops): no input, and its operator lease ends now
    bye: StrictBool = False
    #: a keyed session's tag (:func:`auth_tag`): HMAC-SHA256 with the key of its ``hello``
    #: over :func:`canonical_bytes`; the daemon refuses a keyed session's message without it
    auth: AuthTag | None = None
    #: the rotation axes: turn the EE about the base frame's x, y, z, |rotation| <= 1 (the
    #: EE turns at the profile's ``w_teleop`` times it); left out: no turning (schema-1
    #: senders before rotation)
    rotation: tuple[Axis, Axis, Axis] | None = None

    @model_validator(mode="after")
    def _norm(self) -> JoystickMessage:
        for name in ("axes", "rotation"):
            values = getattr(self, name)
            if values is None:
                continue
            norm = math.sqrt(sum(a * a for a in values))
            if norm > 1.0 + 1e-6:
                what = "deflection" if name == "axes" else "rotation"
                raise field_error((name,), f"{what} must have norm <= 1, got {norm:.4f}")
        return self


#: Fields the canonical bytes leave out while they are ``null``: added after keyed sessions
#: were specified, so a schema-1 sender that knows nothing of them keeps its tags.
_LATER_FIELDS = ("rotation",)
_LATER_BUTTONS = ("gripper",)


def _drop_later(data: dict[str, Any]) -> None:
    """A joystick message's JSON form without those of :data:`_LATER_FIELDS` and
    :data:`_LATER_BUTTONS` that are ``null``."""
    for name in _LATER_FIELDS:
        if data.get(name) is None:
            data.pop(name, None)
    for name in _LATER_BUTTONS:
        if data["buttons"].get(name) is None:
            data["buttons"].pop(name, None)


def canonical_bytes(message: JoystickMessage) -> bytes:
    """What a joystick message's ``auth`` tag covers: every field but ``auth`` as the
    daemon reads the message (defaults filled in), JSON with sorted keys, no spaces,
    ASCII only — the same bytes on both sides whatever the sender's JSON looked like."""
    data = message.model_dump(mode="json", by_alias=True, exclude={"auth"})
    _drop_later(data)
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return text.encode("ascii")


def auth_tag(key: bytes, message: JoystickMessage) -> str:
    """The ``auth`` tag of ``message`` under a session key: HMAC-SHA256 of
    :func:`canonical_bytes`, its first 128 bits in lowercase hex."""
    digest = hmac.new(key, canonical_bytes(message), hashlib.sha256).hexdigest()
    return digest[:AUTH_DIGITS]


def tag_matches(key: bytes, message: JoystickMessage) -> bool:
    """Whether ``message`` carries the right tag for ``key`` (compared in constant time)."""
    return message.auth is not None and hmac.compare_digest(auth_tag(key, message), message.auth)


def public_session_id(session: str) -> str:
    """How status and events name a session: the first 12 hex digits of SHA-256 of its id
    (the id cannot be read back from it; a session's key has no part in it)."""
    return hashlib.sha256(session.encode()).hexdigest()[:PUBLIC_ID_DIGITS]


class Pose(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    position: Vec3
    quaternion: Quat


class OperatorInfo(BaseModel):
    """The session holding the operator lease."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    source: Label
    session: SessionId | None = None


class PlanarPose(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    x: Coordinate
    y: Coordinate
    yaw: Angle = 0.0


class ObjectPlacementStatus(BaseModel):
    """One tracked object: placed, misplaced (with the move that corrects it) or unseen."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    state: Literal["placed", "misplaced", "unseen"]
    text: str
    move: PlanarPose | None = None
    age: Finite | None = None


class PlacementStatus(BaseModel):
    """The placed layout of the current decision as a tracker reports it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stage: Label
    certified: StrictBool | None
    certificate: Finite | None
    planned_certificate: Finite | None
    commit_certificate: Finite | None
    commit_certified: Seq | None
    objects: Annotated[dict[Label, ObjectPlacementStatus], Field(max_length=64)]
    #: the tracked objects off their planned poses (beyond the tolerance), in scene order,
    #: whatever J says
    misplaced: Annotated[list[Label], Field(max_length=64)] = []


class LayoutStatus(BaseModel):
    """Where every object of the daemon's scene should stand in the current decision: the
    plan's layout of it, else the daemon's ``--layout`` or the scene file's poses."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    scene: Label
    objects: Annotated[dict[Label, PlanarPose], Field(max_length=64)]


class CalibrationStatus(BaseModel):
    """The calibration target shown (``legws operator calibrate``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    reach: Annotated[int, Strict(), Field(ge=1)]  # 1-based
    of: Annotated[int, Strict(), Field(ge=1)]
    target: Vec3
    distance: Finite | None = None  # from the EE, m


Steering = Literal["free", "axes", "axes+diagonals"]


class OperatorModelNumbers(BaseModel):
    """An operator model (method.md §10): the numbers and the steering."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    speed: Finite
    sigma: Finite
    rho: Finite
    bias_deg: Finite
    steering: Steering


class WatchEstimate(OperatorModelNumbers):
    """The live watch's fit over its window of completed picks."""

    picks: Seq
    ticks: Seq


class WatchStatus(BaseModel):
    """The live watch of ``legws daemon --operator``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    window: Seq
    minimum: Seq
    picks: Seq  # completed picks seen since start
    estimate: WatchEstimate | None = None
    outside: list[Literal["speed", "sigma", "rho", "bias_deg", "steering"]] = []
    warning: str | None = None
    error: str | None = None


class OperatorModelStatus(BaseModel):
    """The person every certificate is for (``legws daemon --operator``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Label
    model: OperatorModelNumbers  # certify_with: what the certificates use
    intervals: dict[Literal["speed", "sigma", "rho", "bias_deg"], tuple[Finite, Finite]]
    file: str | None = None
    watch: WatchStatus | None = None


class StatusMessage(_Message):
    robot: Label
    seq: Seq
    stamp: Finite
    started: Finite | None = None  # the daemon's wall clock when it started, s
    mode: Literal["idle", "teleop", "assist", "stopped", "fault", "calibrate"]
    stage: Label | None = None
    posterior: dict[Label, Annotated[float, Field(ge=0.0, le=1.0)]] = {}
    committed: Label | None = None
    ee: Pose | None = None
    certificate: Finite | None = None
    adapter: Label
    fallback: StrictBool = False
    fault: str | None = None
    phase: Label | None = None  # step of the assisted action
    gripper_closed: StrictBool = False
    deadman: StrictBool = False  # no valid joystick input within the timeout: zero velocity
    tick: Seq = 0
    overruns: Seq = 0  # control ticks that ran past their period
    rejected: Seq = 0  # joystick messages not used, all reasons (the sum of ``rejections``)
    #: joystick messages not used, by reason: invalid, auth, stale_seq, not_operator
    rejections: dict[Literal["invalid", "auth", "stale_seq", "not_operator"], Seq] = {}
    #: the session holding the operator lease (its public id: :func:`public_session_id`)
    operator: OperatorInfo | None = None
    slack: Finite | None = None  # certificate seen from the current EE pose
    decision: Seq = 0  # counts the decisions of the run (a new stage, or a restart)
    targets: dict[Label, Vec3] = {}  # goal positions of the current decision (base frame, m)
    #: the zenoh transport: authenticated (TLS, mutual TLS or user/password, access control)
    transport: Literal["authenticated", "unauthenticated"] = "unauthenticated"
    #: a real arm runs on an unauthenticated transport (``--insecure-transport``)
    insecure_transport: StrictBool = False
    #: the control loop's SCHED_FIFO priority; 0: normal scheduling
    realtime_priority: Annotated[int, Strict(), Field(ge=0, le=99)] = 0
    #: the placed layout as a tracker reports it (``legws track``); None until one does
    placement: PlacementStatus | None = None
    #: the layout the daemon runs now (what ``legws track --source sim:`` renders)
    layout: LayoutStatus | None = None
    #: the calibration target shown (``legws operator calibrate``); None otherwise
    calibration: CalibrationStatus | None = None
    #: the person the certificates are for (``legws daemon --operator``); None: section 2's
    #: user
    operator_model: OperatorModelStatus | None = None
    #: the help before the commit (profile ``control.assist``, ``--assist``); None: a daemon
    #: from before the policies (it commits, nothing more)
    assist: Literal["commit", "blend", "hindsight", "none"] | None = None


EventKind = Literal[
    "commit",
    "cancel",
    "override",
    "stage_done",
    "task_done",
    "fault",
    "recovered",
    "fallback",
    "warning",
    "reset",
    "stop",
    "loaded",
    "started",
    "shutdown",
    "operator",
    "deadman",
    "input_rejected",
    "placed",
    "reach",
    "reached",
    "operator_inside",
    "stall",
]


class EventMessage(_Message):
    robot: Label
    seq: Seq
    stamp: Finite
    kind: EventKind
    detail: dict[str, Any] = {}


class CommandRequest(_Message):
    command: Literal[
        "status", "reset", "stop", "load_scene", "load_taskgraph", "release", "take_control"
    ]
    #: ``load_scene``/``load_taskgraph``: a catalog name; ``take_control``: a session (its
    #: id, its public id, or the ``source`` of one without an id)
    argument: Label | None = None
    #: ``load_taskgraph`` only: ``"auto"`` the graph's cached plan (``legws plan``), refused
    #: without one; ``"none"`` the shipped layout; left out: the cached plan when there is
    #: one, else the shipped layout with a warning
    plan: Literal["auto", "none"] | None = None

    @model_validator(mode="after")
    def _argument(self) -> CommandRequest:
        needs = self.command in ("load_scene", "load_taskgraph", "take_control")
        if needs and self.argument is None:
            raise field_error(("argument",), f"'{self.command}' needs an argument")
        if not needs and self.argument is not None:
            raise field_error(("argument",), f"'{self.command}' takes no argument")
        if self.plan is not None and self.command != "load_taskgraph":
            raise field_error(("plan",), "only with 'load_taskgraph'")
        return self


class HelloRequest(_Message):
    """``hello`` on the command key: a key for the joystick session ``argument`` (a query:
    the reply goes to the asker alone)."""

    command: Literal["hello"]
    argument: SessionId


class HelloReply(BaseModel):
    """The daemon's answer to ``hello`` (to the asker only): the session's key."""

    model_config = ConfigDict(extra="ignore", frozen=True)

    ok: Literal[True]
    session: Annotated[str, Field(pattern=rf"^[0-9a-f]{{{PUBLIC_ID_DIGITS}}}$")]  # public id
    key: Annotated[str, Field(pattern=rf"^[0-9a-f]{{{2 * SESSION_KEY_BYTES}}}$")]
    started: Finite | None = None  # the daemon's start (status ``started``): which daemon


class ObjectsMessage(_Message):
    """Where objects really are (a tracker, or a person with a tape measure): planar poses
    in the robot base frame. The daemon recomputes the certificate from them."""

    seq: Seq
    stamp: Finite
    objects: Annotated[dict[Label, PlanarPose], Field(max_length=64)]
    #: objects the sender looked for and did not see (they keep their last pose)
    unseen: Annotated[list[Label], Field(max_length=64)] = []
    source: Label = "unknown"


M = TypeVar("M", bound=_Message)


def parse(model: type[M], payload: bytes | str, source: str) -> M:
    """Validate one payload; any problem is an :class:`InputError` naming the field."""
    return validate(model, _load(payload, source), source)


def parse_request(payload: bytes | str, source: str) -> CommandRequest | HelloRequest:
    """A payload on the command key: a ``hello`` or one of the commands (parsed once)."""
    data = _load(payload, source)
    if isinstance(data, dict) and data.get("command") == "hello":
        return validate(HelloRequest, data, source)
    return validate(CommandRequest, data, source)


def _load(payload: bytes | str, source: str) -> Any:
    """The JSON of one payload, checked for size, duplicate keys, schema and text."""
    if len(payload) > MAX_PAYLOAD:
        raise InputError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}", source=source)
    text = payload.decode("utf-8", errors="replace") if isinstance(payload, bytes) else payload
    check_json_nesting(text, source)
    try:
        data = json.loads(payload, object_pairs_hook=unique_keys)
    except DuplicateKeyError as dup:
        raise InputError(
            f"the key {printable(dup.key)!r} appears twice in one object", source=source
        ) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"not JSON: {err}", source=source) from None
    except RecursionError:
        raise InputError("not JSON: nested too deeply", source=source) from None
    except ValueError as err:  # e.g. an integer of more than 4300 digits
        raise InputError(f"not JSON: {err}", source=source) from None
    if isinstance(data, dict) and data.get("schema") not in (None, SCHEMA_VERSION):
        raise InputError(
            f"unsupported schema {data.get('schema')!r}; this daemon speaks {SCHEMA_VERSION}",
            source=source,
            field="schema",
        )
    check_json_text(data, text, source)  # labels and reasons are printed: no controls
    return data


def dump(message: _Message) -> bytes:
    """The wire form of a message (with its ``schema`` field); a joystick message leaves out
    the fields added since schema 1 began while they are ``null`` (a daemon that predates
    them reads it)."""
    if not isinstance(message, JoystickMessage):
        return message.model_dump_json(by_alias=True).encode()
    data = message.model_dump(mode="json", by_alias=True)
    _drop_later(data)
    return json.dumps(data, separators=(",", ":")).encode()
