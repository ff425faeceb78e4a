"""Hardware profiles (``hw_profiles/*.toml``): one robot set-up, validated on load.

A profile names the robot (its zenoh keys live under ``legws/<robot>/``), the adapter that
reaches it (a registry key: ``sim`` for the MuJoCo stand-in, ``sawyer`` for the real arm
through its bridge), the control rate and limits, the deadman timeout, the EE workspace
box every command is clamped to, and the transport settings. Defaults are safe: loopback
only, multicast scouting off. ``[control] operator`` names the operator file of the person
who steers this set-up (method.md §10: every certificate the daemon shows is then theirs),
a path relative to the profile's folder, read and validated with the profile.
"""

from __future__ import annotations

import ipaddress
import os
import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    StrictBool,
    model_validator,
)

from legws_daemon.arms import DEFAULT_ARM, arm_names
from legws_daemon.errors import InputError
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.validation import (
    Coordinate,
    Name,
    did_you_mean,
    field_error,
    read_toml_with_lines,
    validate,
    within,
)

Rate = Annotated[float, Strict(), Field(gt=0, le=1000)]
Speed = Annotated[float, Strict(), Field(gt=0, le=2.0)]
Seconds = Annotated[float, Strict(), Field(gt=0, le=60)]
# matched whole (fullmatch: "$" would let a trailing line break through), ASCII digits only
# ("\d" also takes other scripts' digits, which int() reads but zenoh does not)
_ENDPOINT = re.compile(r"(tcp|udp|tls|quic)/(\[[0-9A-Fa-f:.]+\]|[^\s/:\[\]]+):([0-9]{1,5})")
_HOST_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def endpoint_problem(text: str) -> str | None:
    """What is wrong with a zenoh endpoint ``PROTOCOL/HOST:PORT`` (``None``: nothing).

    The protocol is tcp, udp, tls or quic; the host an IPv4 address, an IPv6 address in
    brackets or a host name; the port 1 to 65535 (0, "any free port", is refused: the other
    side could not find it).
    """
    expected = "expected PROTOCOL/HOST:PORT (tcp, udp, tls or quic), e.g. tcp/127.0.0.1:7447"
    quoted = _quote(text)
    m = _ENDPOINT.fullmatch(text)
    if m is None:
        port = re.fullmatch(r".*:([0-9]{6,20})", text)
        if port is not None:
            return f"invalid endpoint {quoted}: port {port.group(1)} is not in 1..65535"
        return f"invalid endpoint {quoted}; {expected}"
    host, port_number = m.group(2), int(m.group(3))
    if not 1 <= port_number <= 65535:
        return f"invalid endpoint {quoted}: port {port_number} is not in 1..65535"
    try:
        ipaddress.ip_address(host[1:-1] if host.startswith("[") else host)
        return None
    except ValueError:
        pass
    if host.startswith("[") or re.fullmatch(r"[0-9.]+", host):
        return f"invalid endpoint {quoted}: {host} is not an IP address"
    if len(host) > 253 or not all(_HOST_LABEL.fullmatch(label) for label in host.split(".")):
        return f"invalid endpoint {quoted}: {_quote(host)} is not a host name"
    return None


def _quote(text: str) -> str:
    """``text`` quoted on one line, at most ~80 characters of it."""
    return repr(text) if len(text) <= 80 else repr(text[:77]) + "..."


def _endpoint(text: str) -> str:
    problem = endpoint_problem(text)
    if problem is not None:
        raise ValueError(problem)
    return text


Endpoint = Annotated[str, Strict(), AfterValidator(_endpoint)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ControlSpec(_Model):
    rate_hz: Rate = 20.0
    v_max: Speed = 0.05  # EE speed at full joystick deflection, m/s
    assist_speed: Speed = 0.10  # autonomous approach, m/s
    deadman_timeout: Seconds = 0.25  # no valid input for this long: zero velocity
    #: a silent operator keeps the lease this much longer than the deadman timeout, s
    lease_grace: Annotated[float, Strict(), Field(ge=0.0, le=60.0, allow_inf_nan=False)] = 0.5
    status_rate_hz: Rate = 10.0
    #: the control loop's thread on SCHED_FIFO at this priority (1-99; needs CAP_SYS_NICE or
    #: an RLIMIT_RTPRIO this high, else it runs at normal priority and says so); 0: normal
    realtime_priority: Annotated[int, Strict(), Field(ge=0, le=99)] = 0
    #: the operator file (``legws operator calibrate``/``fit``) of the person the daemon
    #: certifies for, relative to the profile's folder; made absolute by :func:`load_profile`
    operator: Annotated[str, Strict(), Field(min_length=1, max_length=4096)] | None = None
    #: help before the commit (:mod:`legws_daemon.core.arbitration`): ``commit`` none,
    #: ``blend`` the operator's motion blended with the robot's toward the likely goal,
    #: ``hindsight`` the posterior-weighted assistance of hindsight optimisation, ``none``
    #: teleoperation only (no commit: the operator grasps with the gripper button)
    assist: Literal["commit", "blend", "hindsight", "none"] = "commit"
    #: the EE's turning speed at full deflection of the rotation axes, rad/s (the envelope
    #: caps turning at 0.8 rad/s whatever this says)
    w_teleop: Annotated[float, Strict(), Field(gt=0.0, le=3.0, allow_inf_nan=False)] = 0.5


class WorkspaceBox(_Model):
    """The box the EE may move in (robot base frame, metres); commands are clamped to it."""

    x: tuple[Coordinate, Coordinate] = (0.20, 0.95)
    y: tuple[Coordinate, Coordinate] = (-0.55, 0.55)
    z: tuple[Coordinate, Coordinate] = (0.0, 0.60)

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceBox:
        for axis in ("x", "y", "z"):
            lo, hi = getattr(self, axis)
            if not lo < hi:
                raise field_error((axis,), f"must be [low, high] with low < high, got {[lo, hi]}")
        return self


class SimSpec(_Model):
    realtime: StrictBool = True  # pace the stand-in to the wall clock (False: as fast as possible)


class LinkSpec(_Model):
    """The daemon's link to a robot-side bridge (``[link]``; ``[sawyer]`` in older profiles):
    what the ``bridge`` adapter expects of it, on any arm."""

    bridge_timeout: Seconds = 3.0  # the bridge must answer within this long
    heartbeat_timeout: Seconds = 0.5  # no joint state for this long: fault, safe stop
    fallback_to_sim: StrictBool = False  # start on the stand-in when the bridge does not answer
    command: Literal["joint_velocity", "ee_velocity"] = "joint_velocity"


class BridgeLimitsSpec(_Model):
    """Limits the robot-side bridge enforces itself, whatever it is sent (``[bridge]``).

    The daemon keeps to the same values, so they act only on a faulty or hostile sender.
    """

    #: each joint's speed at most this (and at most its specification), rad/s
    joint_speed_cap: Annotated[float, Strict(), Field(gt=0, le=4.545)] = 0.8
    #: the endpoint's linear speed at most this, m/s (measured by the robot)
    ee_speed_cap: Speed = 0.2
    #: the endpoint stays inside ``[workspace]`` grown by this, m (motion outward is refused)
    workspace_margin: Annotated[float, Strict(), Field(ge=0.0, le=0.2)] = 0.02
    #: a command moves the arm at most this long after its receipt, s
    max_ttl: Annotated[float, Strict(), Field(gt=0, le=1.0)] = 0.2
    #: commands per second at most (a burst of :data:`COMMAND_BURST` more); beyond, the
    #: command is refused and the arm stops
    command_rate_hz: Rate = 60.0


#: Commands the bridge accepts in a burst beyond its rate (token bucket depth).
COMMAND_BURST = 5


class TransportSpec(_Model):
    """zenoh settings used when no --zenoh-config file is given: loopback peer, no scouting."""

    mode: Literal["peer", "client"] = "peer"
    listen: list[Endpoint] = ["tcp/127.0.0.1:7447"]
    connect: list[Endpoint] = []
    multicast_scouting: StrictBool = False


class CanSpec(_Model):
    """Frame layout of a CAN joystick: three signed 16-bit axes, little-endian, and a
    button byte, in one frame of ``arbitration_id``; ``scale`` maps raw counts to [-1, 1]."""

    arbitration_id: Annotated[int, Strict(), Field(ge=0, le=0x1FFFFFFF)] = 0x100
    axis_offsets: tuple[int, int, int] = (0, 2, 4)
    button_offset: Annotated[int, Field(ge=0, le=63)] = 6
    scale: Annotated[float, Strict(), Field(gt=0)] = 32767.0
    invert: tuple[StrictBool, StrictBool, StrictBool] = (False, False, False)
    #: bit 2 of the button byte is a hold-to-run (enable) button; ``false``: every frame is
    #: enabled and the frame stream itself is the dead-man signal
    enable_bit: StrictBool = False
    #: the rotation axes (turns about the base frame's x, y, z): three more signed 16-bit
    #: little-endian values at these offsets, scaled and inverted as the axes; ``null``:
    #: the device has none
    rotation_offsets: tuple[int, int, int] | None = None
    rotation_invert: tuple[StrictBool, StrictBool, StrictBool] = (False, False, False)


class ProfileSpec(_Model):
    schema_version: Literal[1]
    name: Name
    robot: Name
    #: ``sim``: the MuJoCo stand-in; ``bridge``: the real arm through its robot-side bridge
    #: (docs/bridge.md), any arm; ``sawyer``: the same on the Sawyer (the older name)
    adapter: Literal["sim", "bridge", "sawyer"]
    #: the arm's description (:mod:`legws_daemon.arms`): its model, joints and limits
    arm: str = DEFAULT_ARM
    description: str = ""
    control: ControlSpec = ControlSpec()
    workspace: WorkspaceBox = WorkspaceBox()
    sim: SimSpec = SimSpec()
    link: LinkSpec = Field(default=LinkSpec(), validation_alias=AliasChoices("link", "sawyer"))
    bridge: BridgeLimitsSpec = BridgeLimitsSpec()
    transport: TransportSpec = TransportSpec()
    can: CanSpec = CanSpec()

    @model_validator(mode="after")
    def _consistent(self) -> ProfileSpec:
        if self.arm not in arm_names():
            raise field_error(("arm",), f"expected one of: {', '.join(arm_names())}")
        if self.adapter == "sawyer" and self.arm != "sawyer":
            raise field_error(
                ("arm",), 'the sawyer adapter drives the Sawyer only (adapter = "bridge": any arm)'
            )
        if self.control.assist_speed < self.control.v_max / 10:
            raise field_error(("control", "assist_speed"), "implausibly slow next to v_max")
        if self.control.deadman_timeout < 1.0 / self.control.rate_hz:
            raise field_error(
                ("control", "deadman_timeout"),
                f"shorter than one control period ({1.0 / self.control.rate_hz:g} s)",
            )
        fastest = max(self.control.v_max, self.control.assist_speed)
        if self.bridge.ee_speed_cap < fastest:
            raise field_error(
                ("bridge", "ee_speed_cap"),
                f"below the daemon's own top speed {fastest:g} m/s (control.v_max, "
                "control.assist_speed): the bridge would cut every fast command",
            )
        if self.bridge.command_rate_hz < self.control.rate_hz:
            raise field_error(
                ("bridge", "command_rate_hz"),
                f"below the control rate {self.control.rate_hz:g} Hz",
            )
        if self.bridge.max_ttl < 2.0 / self.control.rate_hz:
            raise field_error(
                ("bridge", "max_ttl"),
                f"shorter than two control periods ({2.0 / self.control.rate_hz:g} s): "
                "the daemon's commands would expire between ticks",
            )
        return self


def with_arm(spec: ProfileSpec, arm: str) -> ProfileSpec:
    """``spec`` on the arm ``arm`` (``--robot``), validated as the profile's own ``arm``."""
    if arm == spec.arm:
        return spec
    return validate(ProfileSpec, {**spec.model_dump(), "arm": arm}, "--robot", None)


def load_profile(path: Path) -> ProfileSpec:
    """Read and validate a hardware profile; errors name the file, the line and the field
    (every one of them). A ``control.operator`` file is read and validated too (its path
    made absolute)."""
    data, where = read_toml_with_lines(path, "hardware profile")
    spec = validate(ProfileSpec, data, str(path), where)
    if spec.control.operator is None:
        return spec
    return _with_operator(spec, Path(path), where)


def _with_operator(spec: ProfileSpec, path: Path, where: SourceText) -> ProfileSpec:
    """``control.operator`` resolved against the profile's folder and validated."""
    from legws_daemon.formats.operator_file import load_operator

    assert spec.control.operator is not None
    given = Path(spec.control.operator)
    full = (given if given.is_absolute() else path.parent / given).absolute()
    try:
        load_operator(full)
    except InputError as err:
        source = where.at(str(path), ("control", "operator"))
        raise within(err, source, "control.operator") from None
    control = spec.control.model_copy(update={"operator": str(full)})
    return spec.model_copy(update={"control": control})


def profiles_dir() -> Path:
    """The repository's ``hw_profiles/`` folder, or ``$LEGWS_PROFILES``."""
    env = os.environ.get("LEGWS_PROFILES")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "hw_profiles"


def load_profile_named(name_or_path: str | Path) -> ProfileSpec:
    """A profile by name (``sim`` -> ``hw_profiles/sim.toml``) or from a ``.toml`` path.

    An unknown name lists the known ones, and says ``did you mean 'sim'?`` for a close
    one; a ``.toml`` path that does not exist does so for the profiles of its folder."""
    text = str(name_or_path)
    if text.endswith(".toml") or os.sep in text:
        path = Path(text)
        if not _exists(path):
            raise _no_such_profile_file(path)
        return load_profile(path)
    path = profiles_dir() / f"{text}.toml"
    if not path.is_file():
        names = sorted(p.stem for p in profiles_dir().glob("*.toml"))
        guess = did_you_mean(text, names)
        hint = f"; did you mean '{guess}'?" if guess is not None else ";"
        known = ", ".join(names) or "(none)"
        raise InputError(f"unknown hardware profile '{text}'{hint} known: {known}", field="profile")
    return load_profile(path)


def _exists(path: Path) -> bool:
    """Whether anything (a dangling link too) is at ``path``; a path :func:`load_profile`
    refuses for its own reason (a NUL character) counts as existing."""
    if "\0" in str(path):
        return True
    try:
        return path.exists() or path.is_symlink()
    except (OSError, ValueError):
        return True


def _no_such_profile_file(path: Path) -> InputError:
    """``no such file``, with the closest profile file of the same folder, if one is close."""
    try:
        stems = sorted(p.stem for p in path.parent.glob("*.toml") if p.is_file())
    except OSError:
        stems = []
    guess = did_you_mean(path.stem, stems)
    hint = f"; did you mean '{path.parent / guess}.toml'?" if guess is not None else ""
    return InputError(f"no such file{hint}", source=str(path))
