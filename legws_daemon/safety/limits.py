"""The bridges' own limits: one guard for every bridge, standard library only.

Every robot-side bridge (the fake one in :mod:`legws_daemon.hardware.fake_bridge`, the
Intera bridge ``bridge/intera_bridge.py`` on the Sawyer's PC, and any other) runs this
module between the commands it receives and the joint velocities it applies, so the tests
that attack the fake bridge run the code that guards the real arm. It imports nothing but
the standard library and runs under Python 3.8 (ROS Noetic's): annotations stay strings,
nothing subscripts a builtin at run time, no ``match``, no dataclass slots. Time comes from
an injected clock (a callable returning seconds), so tests drive it by hand.

The limits (a hardware profile's ``[bridge]`` and ``[workspace]``, :class:`BridgeLimits`)
and the joint tables (an arm's description, :class:`Guard.for_arm` takes a
:class:`~legws_daemon.arms.spec.ArmSpec`: position limits and specification speeds,
any number of joints) are enforced in this order.

On a command (:meth:`Guard.command`, or :meth:`Guard.admit` then :meth:`Guard.accept`):

1. **validity** — a joint vector of the arm's length, finite, a finite ``ttl > 0``;
   anything else is ``rejected``: the live command is cleared, the arm stops;
2. **rate** — a token bucket of ``burst`` commands refilled at ``command_rate_hz``: a
   command beyond it is ``refused`` and the arm stops (``rate``);
3. **stop latch** — after a stop (:meth:`Guard.stop`, any role) commands are ``ignored``
   until an explicit :meth:`Guard.resume`;
4. **joint speed** — each joint at most ``min(joint_speed_cap, its specification)``: a
   faster command is scaled down uniformly, its direction kept (``joint_speed``);
5. **command life** — a command moves the arm at most ``min(ttl, max_ttl)`` after its
   receipt on the guard's clock (``ttl`` when capped).

On every step of motion from ``t0`` to ``t1`` (:meth:`Guard.step`; a bridge period):

6. **deadman** — no live command, or a command past its life: zero;
7. **joint position limits** — a joint reaches its limit (less ``limit_margin``) and
   stops there; beyond it only inward motion;
8. **endpoint speed** — at most ``ee_speed_cap`` (``ee_speed``: scaled down uniformly);
9. **workspace** — the endpoint stays inside the ``[workspace]`` box grown by the margin:
   a step that would leave it (or, outside already, go farther from it) is not taken, the
   command is cleared and the arm stops (``workspace``); steps back toward it are allowed.

Every refusal is zero velocity with a reason (:attr:`Step.reason`), never a guess: a
non-finite or wrong-length joint vector, a missing endpoint, an expired or absent command.

**How the endpoint is judged.** With forward kinematics (``ee_position(q)``, the mode every
bridge should use), the guard computes the endpoint at the step's start and end,
``FK(q)`` and ``FK(q + dq·τ)``, scales the step until the chord's speed is within the cap
and takes it only if its end is allowed. That is a check of the *commanded* step before it
is taken: exact for the arm's model, from the first tick of a new direction, and it does
not depend on what the robot reports. The alternative, Intera's *measured* endpoint
velocity, lags the command by a tick: a new direction cannot be measured before it moves,
so it has to be bounded by a worst case (the arm's reach times the sum of the joint speeds)
and may pass the box's face by :data:`PROBE` before the next tick measures it. The guard
keeps that as a documented weaker mode (no ``ee_position``; the bridge passes the measured
position and linear velocity to :meth:`Guard.step`), for a bridge without a model of its
arm. :class:`Chain` is a forward kinematics of a serial arm from fixed transforms and
revolute joints (extracted from the arm's own model by ``legws bridge bundle``), so a
bridge without MuJoCo has the first mode too.

Not thread-safe: a bridge calls it under its own lock.
"""

# zip(strict=...) needs Python 3.10; this module runs under ROS Noetic's Python 3.8.
# ruff: noqa: B905
from __future__ import annotations

import json
import math
import os
import stat
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

try:  # Python >= 3.11: a bridge reads a legws hardware profile
    import tomllib
except ImportError:  # ROS Noetic's Python 3.8: the bridge takes its limits as flags
    tomllib = None  # type: ignore[assignment]

if TYPE_CHECKING:  # annotations only: nothing here is evaluated under Python 3.8
    from collections.abc import Callable, Sequence

    Vector = Sequence[float]
    EePosition = Callable[[Sequence[float]], Sequence[float]]

#: Every limit a bridge enforces, in the order its state message lists them.
LIMITS = ("joint_speed", "ee_speed", "workspace", "ttl", "rate")
#: What became of a command: it is the live one now; refused (over the rate: the arm
#: stopped); ignored (a stop is latched); rejected (not a valid command: the arm stopped).
VERDICTS = ("accepted", "refused", "ignored", "rejected")
#: The role whose resume clears every latched stop: the daemon, the only publisher of
#: ``legws/<robot>/bridge/resume`` (where each role's reset is decided).
RESUME_AUTHORITY = "daemon"

# The defaults of a legws profile's [bridge] and [workspace] (legws_daemon/formats/profile.py).
#: Each joint's speed at most this (and at most its specification), rad/s.
JOINT_SPEED_CAP = 0.8
#: The endpoint's linear speed at most this, m/s.
EE_SPEED_CAP = 0.2
#: The box the endpoint stays in (base frame, m): x, y, z ranges ...
WORKSPACE = ((0.20, 0.95), (-0.55, 0.55), (0.0, 0.60))
#: ... grown by this, m.
WORKSPACE_MARGIN = 0.02
#: A command moves the arm at most this long after its receipt, s.
TTL_CAP = 0.2
#: Commands per second at most ...
COMMAND_RATE_HZ = 60.0
#: ... and this many more in a burst (the token bucket's depth).
COMMAND_BURST = 5
#: The contract's longest command life, s, and the largest joint speed cap (the fastest
#: joint of the registered arms, the Sawyer's wrist), rad/s.
MAX_TTL = 1.0
MAX_JOINT_SPEED_CAP = 4.545

#: Rescalings tried to bring a step's endpoint speed under the cap; past them: zero.
EE_SCALE_ATTEMPTS = 8
#: A rescaled step aims this far under the cap (a curved path's chord does not shrink
#: quite in proportion to the step).
_EE_AIM = 1.0 - 1e-9

# The measured-velocity mode (no forward kinematics; weaker, see the module's docstring).
#: The farthest the endpoint is from any joint axis (the Sawyer's reach, a tool), m: a
#: motion not measured yet moves the endpoint at most this x the sum of its joint speeds.
REACH = 1.5
#: A command this parallel (cosine) to the velocities applied is predicted from the
#: measured endpoint velocity.
PARALLEL = 0.99
#: A motion not measured yet may carry the endpoint this far out of the box (+ margin), m.
PROBE = 0.0005
#: Outside the box (+ margin) by more than this less PROBE, nothing new moves, m.
OUTSIDE_LIMIT = 0.005


def _finite(values: Any, n: int) -> tuple[float, ...] | None:
    """``values`` as ``n`` finite floats, or ``None`` (wrong length, not numbers, NaN/inf)."""
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError, OverflowError):
        return None
    if len(out) != n or not all(math.isfinite(v) for v in out):
        return None
    return out


def _norm(v: Vector) -> float:
    return math.sqrt(sum(x * x for x in v))


def box_distance(p: Vector, lower: Vector, upper: Vector) -> float:
    """The distance from ``p`` to the box ``[lower, upper]`` (0 inside)."""
    return math.sqrt(sum(max(lo - x, x - hi, 0.0) ** 2 for x, lo, hi in zip(p, lower, upper)))


def cap_speeds(dq: Vector, caps: Vector) -> tuple[tuple[float, ...], bool]:
    """``dq`` scaled down uniformly (direction kept) so no joint is over its cap, and
    whether it was. Exact for any finite request (scaled as a unit vector first)."""
    peak = max((abs(v) for v in dq), default=0.0)
    if peak == 0.0:
        return tuple(float(v) for v in dq), False
    unit = [v / peak for v in dq]
    ratio = max(abs(u) / c for u, c in zip(unit, caps))
    if peak * ratio <= 1.0:
        return tuple(float(v) for v in dq), False
    return tuple(max(-c, min(c, u / ratio)) for u, c in zip(unit, caps)), True


@dataclass(frozen=True)
class BridgeLimits:
    """The limits a bridge enforces itself (a profile's ``[bridge]`` and ``[workspace]``;
    the defaults are the profile's). A ValueError names a field out of its range."""

    joint_speed_cap: float = JOINT_SPEED_CAP  # rad/s, each joint (and its specification)
    ee_speed_cap: float = EE_SPEED_CAP  # m/s
    workspace: tuple[tuple[float, float], ...] = WORKSPACE  # x, y, z ranges, base frame, m
    workspace_margin: float = WORKSPACE_MARGIN  # m, the box grows by this
    max_ttl: float = TTL_CAP  # s
    command_rate_hz: float = COMMAND_RATE_HZ  # commands/s
    burst: int = COMMAND_BURST  # commands beyond the rate in a burst

    def __post_init__(self) -> None:
        ranges = (
            ("joint_speed_cap", self.joint_speed_cap, 0.0, MAX_JOINT_SPEED_CAP, False),
            ("ee_speed_cap", self.ee_speed_cap, 0.0, 2.0, False),
            ("workspace_margin", self.workspace_margin, 0.0, 0.2, True),
            ("max_ttl", self.max_ttl, 0.0, MAX_TTL, False),
            ("command_rate_hz", self.command_rate_hz, 0.0, 1000.0, False),
        )
        for name, value, lo, hi, closed in ranges:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{name} must be a number, got {value!r}")
            number = float(value)
            above = number >= lo if closed else number > lo
            if not (math.isfinite(number) and above and number <= hi):
                opening = "[" if closed else "("
                raise ValueError(f"{name} must be in {opening}{lo:g}, {hi:g}], got {value!r}")
        if isinstance(self.burst, bool) or not isinstance(self.burst, int) or self.burst < 1:
            raise ValueError(f"burst must be an integer >= 1, got {self.burst!r}")
        if len(self.workspace) != 3:
            raise ValueError("workspace must have x, y and z ranges")
        for axis, pair in zip("xyz", self.workspace):
            if len(pair) != 2:
                raise ValueError(f"workspace {axis} must be [low, high]")
            lo, hi = pair
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"workspace {axis} must be [low, high] with low < high")

    def joint_caps(self, speed_limits: Vector) -> tuple[float, ...]:
        """Each joint's speed cap: the lower of ``joint_speed_cap`` and its specification."""
        return tuple(min(self.joint_speed_cap, float(s)) for s in speed_limits)

    def box(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The workspace grown by the margin: its (lower, upper) corners."""
        m = self.workspace_margin
        return (
            tuple(lo - m for lo, _ in self.workspace),
            tuple(hi + m for _, hi in self.workspace),
        )

    def describe(self) -> str:
        """The limits in one line (a bridge logs it at start-up)."""
        box = " ".join(f"{axis} [{lo:g}, {hi:g}]" for axis, (lo, hi) in zip("xyz", self.workspace))
        return (
            f"joint speed <= {self.joint_speed_cap:g} rad/s, EE speed <= {self.ee_speed_cap:g} "
            f"m/s, EE in {box} m + {self.workspace_margin:g} m, ttl <= {self.max_ttl:g} s, "
            f"<= {self.command_rate_hz:g} commands/s (burst {self.burst})"
        )


_PROFILE_BRIDGE_KEYS = (
    "joint_speed_cap",
    "ee_speed_cap",
    "workspace_margin",
    "max_ttl",
    "command_rate_hz",
)


def _profile_number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    return float(value)


#: Largest hardware profile read (as legws_daemon.formats.files.LIMITS).
MAX_PROFILE_BYTES = 256 * 1024


def profile_limits(path: str) -> BridgeLimits:
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
    unknown = sorted(set(workspace) - {"x", "y", "z"})
    if unknown:
        raise ValueError(f"{path}: workspace.{unknown[0]}: unknown field")
    values["workspace"] = tuple(ranges)
    try:
        return BridgeLimits(**values)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None


@dataclass(frozen=True)
class Step:
    """The motion of one step: ``velocity`` (rad/s, one per joint) for ``duration`` s;
    ``reason`` says why it is zero (``None``: it moves, or nothing was asked)."""

    velocity: tuple[float, ...]
    duration: float
    reason: str | None = None

    @property
    def displacement(self) -> tuple[float, ...]:
        """The joint angle change of the step, rad."""
        return tuple(v * self.duration for v in self.velocity)

    @property
    def moving(self) -> bool:
        return self.duration > 0.0 and any(self.velocity)


@dataclass(frozen=True)
class LiveCommand:
    """The command being applied: its (capped) velocities and its life on the clock."""

    dq: tuple[float, ...]
    received: float
    expires: float  # received + min(ttl, max_ttl)


class Guard:
    """One bridge's limits and the state they need (the token bucket, the live command,
    the latched stops). See the module's docstring for the rules.

    Args:
        lower, upper: the joints' position limits, rad (the arm's description).
        speed_limits: the joints' specification speeds, rad/s.
        limits: the profile's limits (default: the profile defaults).
        clock: seconds, monotonic: a command's life, the bucket, a step's default times.
        ee_position: forward kinematics ``q -> (x, y, z)`` in the base frame; ``None``: the
            weaker measured-velocity mode (:meth:`step` then needs ``measured``).
        period: a step's default length, s (the bridge's tick).
        limit_margin: joints stop this far inside their position limits, rad.

    Attributes:
        joint_caps: per joint, ``min(joint_speed_cap, specification)``, rad/s.
        box_lower, box_upper: the workspace grown by the margin.
        counts: per limit (:data:`LIMITS`), times enforced since the guard was made.
    """

    def __init__(
        self,
        lower: Vector,
        upper: Vector,
        speed_limits: Vector,
        limits: BridgeLimits | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        ee_position: EePosition | None = None,
        period: float = 0.01,
        limit_margin: float = 0.0,
    ) -> None:
        n = len(lower)
        lo, hi = _finite(lower, n), _finite(upper, n)
        spec = _finite(speed_limits, n)
        if n < 1 or lo is None or hi is None or spec is None:
            raise ValueError("the joint tables need one finite value per joint each")
        if any(a >= b for a, b in zip(lo, hi)) or not all(s > 0.0 for s in spec):
            raise ValueError("joint limits must be ordered and speed limits positive")
        if not (period > 0.0 and math.isfinite(period)):
            raise ValueError(f"period must be a positive number of seconds, got {period!r}")
        if not (limit_margin >= 0.0 and math.isfinite(limit_margin)):
            raise ValueError(f"limit_margin must be >= 0, got {limit_margin!r}")
        self.dof = n
        self.limits = limits if limits is not None else BridgeLimits()
        self.lower = tuple(a + limit_margin for a in lo)
        self.upper = tuple(b - limit_margin for b in hi)
        self.speed_limits = spec
        self.joint_caps = self.limits.joint_caps(spec)
        self.box_lower, self.box_upper = self.limits.box()
        self.clock = clock
        self.ee_position = ee_position
        self.period = float(period)
        self.counts = dict.fromkeys(LIMITS, 0)
        self._since: set[str] = set()
        self._tokens = float(self.limits.burst)
        self._refilled: float | None = None  # the bucket's time; None: full, never used
        self._live: LiveCommand | None = None
        self._stops: list[str] = []  # the latched roles, the first first
        self._applied = (0.0,) * n  # the velocity of the last step (the measured mode)

    @classmethod
    def for_arm(cls, spec: Any, limits: BridgeLimits | None = None, **kwargs: Any) -> Guard:
        """The guard of a registered arm (an ``ArmSpec``: its position and speed limits)."""
        return cls(spec.lower, spec.upper, spec.speed_limits, limits, **kwargs)

    # --- what there is to know ----------------------------------------------------
    @property
    def live(self) -> LiveCommand | None:
        """The command being applied, if any."""
        return self._live

    @property
    def stopped_by(self) -> str | None:
        """The role of the first latched stop, or ``None``."""
        return self._stops[0] if self._stops else None

    @property
    def latched(self) -> tuple[str, ...]:
        """Every role whose stop is latched."""
        return tuple(self._stops)

    def take_limited(self) -> tuple[str, ...]:
        """The limits enforced since the previous call (in :data:`LIMITS` order)."""
        out = tuple(limit for limit in LIMITS if limit in self._since)
        self._since.clear()
        return out

    def _report(self, limit: str) -> None:
        self.counts[limit] += 1
        self._since.add(limit)

    def _now(self, now: float | None) -> float:
        return float(self.clock() if now is None else now)

    # --- commands -------------------------------------------------------------------
    def command(self, dq: Vector, ttl: float, now: float | None = None) -> str:
        """A command arrives (at ``now``, default the clock): validity, :meth:`admit`,
        :meth:`accept`; the verdict (one of :data:`VERDICTS`)."""
        t = self._now(now)
        if self._valid(dq, ttl) is None:
            self._live = None
            return "rejected"
        if not self.admit(t):
            return "refused"
        return self.accept(dq, ttl, t)

    def _valid(self, dq: Any, ttl: Any) -> tuple[float, ...] | None:
        v = _finite(dq, self.dof)
        if v is None or isinstance(ttl, bool) or not isinstance(ttl, (int, float)):
            return None
        return v if (ttl > 0.0 and math.isfinite(ttl)) else None

    def admit(self, now: float | None = None) -> bool:
        """The rate: take a token for a command arriving at ``now``. Without one the
        command is refused and the arm stops (``rate``). A bridge calls this for every
        valid command, also those it then ignores, so the bucket measures the sender."""
        t = self._now(now)
        if self._refilled is None:
            self._refilled = t
        elif t > self._refilled:
            rate, burst = self.limits.command_rate_hz, float(self.limits.burst)
            self._tokens = min(burst, self._tokens + (t - self._refilled) * rate)
            self._refilled = t
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        self._live = None
        self._report("rate")
        return False

    def accept(self, dq: Vector, ttl: float, now: float | None = None) -> str:
        """Make an admitted command the live one within the joint speed caps and the life
        cap: ``accepted``; ``ignored`` while a stop is latched; ``rejected`` (and the arm
        stops) when it is not a valid command."""
        t = self._now(now)
        v = self._valid(dq, ttl)
        if v is None:
            self._live = None
            return "rejected"
        if self._stops:
            self._live = None
            return "ignored"
        v, capped = cap_speeds(v, self.joint_caps)
        if capped:
            self._report("joint_speed")
        if ttl > self.limits.max_ttl:
            self._report("ttl")
        self._live = LiveCommand(v, t, t + min(float(ttl), self.limits.max_ttl))
        return "accepted"

    def clear(self) -> None:
        """No live command: the arm stops (a disabled robot, a shutdown, a bad message)."""
        self._live = None

    def stop(self, role: str) -> None:
        """A stop from ``role``: the live command is cleared and the stop latches."""
        self._live = None
        if role not in self._stops:
            self._stops.append(role)

    def resume(self, role: str = RESUME_AUTHORITY) -> bool:
        """An explicit resume from ``role``: clears that role's latched stop; the resume
        authority's (:data:`RESUME_AUTHORITY`, the contract's ``bridge/resume``) clears
        every one. ``True`` if no stop is latched after it, and one was before. No command
        comes back: the arm moves again on the next fresh one."""
        before = bool(self._stops)
        if role == RESUME_AUTHORITY:
            self._stops = []
        elif role in self._stops:
            self._stops.remove(role)
        return before and not self._stops

    # --- motion ---------------------------------------------------------------------
    def _zero(self, reason: str | None) -> Step:
        self._applied = (0.0,) * self.dof
        return Step((0.0,) * self.dof, 0.0, reason)

    def step(
        self,
        q: Vector,
        t0: float | None = None,
        t1: float | None = None,
        *,
        horizon: float | None = None,
        measured: tuple[Vector, Vector] | None = None,
    ) -> Step:
        """The motion allowed from ``t0`` (default: the clock) to ``t1`` (default: ``t0``
        + the period) from joint angles ``q``.

        The velocity acts during ``duration`` <= ``t1 - t0`` (a command may end inside
        the step). The endpoint rules look ``horizon`` ahead (default: the duration; a
        bridge whose velocity acts until its next tick passes its period). ``measured``:
        the endpoint's measured position and linear velocity, for the measured mode.
        """
        start = self._now(t0)
        end = start + self.period if t1 is None else float(t1)
        live = self._live
        if live is None:
            return self._zero("stopped" if self._stops else "no command")
        if not end > start:
            return self._zero("no time")
        if end >= live.expires:
            self._live = None  # the deadman: after this step, no motion
        tau = min(end, live.expires) - max(start, live.received)
        if not tau > 0.0:
            return self._zero("expired")
        qq = _finite(q, self.dof)
        if qq is None:
            self._live = None
            return self._zero("invalid joint state")
        v = self._within_joint_limits(qq, live.dq, tau)
        if not any(v):
            return self._zero("joint limit")
        h = tau if horizon is None else max(float(horizon), tau)
        if self.ee_position is not None:
            out, reason = self._by_kinematics(qq, v, h)
        else:
            out, reason = self._by_measurement(v, measured)
        if out is None:
            return self._zero(reason)
        self._applied = out
        return Step(out, tau)

    def _within_joint_limits(
        self, q: tuple[float, ...], dq: tuple[float, ...], tau: float
    ) -> tuple[float, ...]:
        """Each joint reaches its limit and stops there; beyond it, only inward."""
        out = []
        for qi, vi, lo, hi in zip(q, dq, self.lower, self.upper):
            nxt = qi + vi * tau
            if nxt > hi:
                vi = max((hi - qi) / tau, 0.0) if qi <= hi else min(vi, 0.0)
            elif nxt < lo:
                vi = min((lo - qi) / tau, 0.0) if qi >= lo else max(vi, 0.0)
            out.append(vi)
        return tuple(out)

    def _endpoint(self, q: Vector) -> tuple[float, ...] | None:
        try:
            p = self.ee_position(q)  # type: ignore[misc]
        except (ValueError, ArithmeticError):
            return None
        return _finite(p, 3)

    def _inside(self, p: Vector) -> bool:
        return all(lo <= x <= hi for x, lo, hi in zip(p, self.box_lower, self.box_upper))

    def _distance(self, p: Vector) -> float:
        return box_distance(p, self.box_lower, self.box_upper)

    def _may_end_at(self, p0: Vector, p1: Vector) -> bool:
        """Inside the box, or, from outside it, no farther from it."""
        if self._inside(p1):
            return True
        return not self._inside(p0) and self._distance(p1) <= self._distance(p0)

    def _by_kinematics(
        self, q: tuple[float, ...], v: tuple[float, ...], h: float
    ) -> tuple[tuple[float, ...] | None, str]:
        """The endpoint rules on the commanded step: its chord's speed at most the cap
        (scaled down uniformly), its end allowed by the workspace."""
        p0 = self._endpoint(q)
        if p0 is None:
            self._live = None  # no endpoint to judge by: no motion
            return None, "no endpoint"
        cap = self.limits.ee_speed_cap
        scaled = False
        p1: tuple[float, ...] | None = None
        for _ in range(EE_SCALE_ATTEMPTS):
            p1 = self._endpoint([a + b * h for a, b in zip(q, v)])
            if p1 is None:
                self._live = None
                return None, "no endpoint"
            speed = math.sqrt(sum((b - a) ** 2 for a, b in zip(p0, p1))) / h
            if speed <= cap:
                break
            v = tuple(x * (cap / speed * _EE_AIM) for x in v)
            scaled = True
        else:
            self._report("ee_speed")
            return None, "ee_speed"
        if scaled:
            self._report("ee_speed")
        if not self._may_end_at(p0, p1):
            self._live = None
            self._report("workspace")
            return None, "workspace"
        return v, ""

    def _by_measurement(
        self, v: tuple[float, ...], measured: tuple[Vector, Vector] | None
    ) -> tuple[tuple[float, ...] | None, str]:
        """The weaker mode, on the measured endpoint (a tick behind the command).

        A command parallel (cosine >= :data:`PARALLEL`) to the velocities applied last
        step is predicted from the measured endpoint velocity in proportion: over the cap
        it is scaled down (``ee_speed``); a predicted position one horizon ahead that
        leaves the box (or, outside, goes farther) stops the arm (``workspace``). Any other
        command (a new direction) is bounded by :data:`REACH` x the sum of its joint
        speeds: at most to the box's face, or :data:`PROBE` past it; outside by more than
        :data:`OUTSIDE_LIMIT` less PROBE nothing new moves; its speed is checked from the
        step that measures it.
        """
        if measured is None:
            return None, "no endpoint"
        position, linear = _finite(measured[0], 3), _finite(measured[1], 3)
        if position is None or linear is None:
            return None, "no endpoint"
        h = self.period
        size, before = _norm(v), _norm(self._applied)
        parallel = size > 0.0 and before > 0.0
        if parallel:
            dot = sum(a * b for a, b in zip(v, self._applied))
            parallel = dot >= PARALLEL * size * before
        if parallel:
            velocity = [size / before * x for x in linear]
            speed = _norm(velocity)
            scale = 1.0 if speed <= self.limits.ee_speed_cap else self.limits.ee_speed_cap / speed
            if scale < 1.0:
                self._report("ee_speed")
            predicted = [p + scale * x * h for p, x in zip(position, velocity)]
            if not self._may_end_at(position, predicted):
                self._live = None
                self._report("workspace")
                return None, "workspace"
            return tuple(scale * x for x in v), ""
        if self._inside(position):
            allowed = max(
                min(
                    min(x - lo, hi - x)
                    for x, lo, hi in zip(position, self.box_lower, self.box_upper)
                ),
                PROBE,
            )
        elif self._distance(position) + PROBE <= OUTSIDE_LIMIT:
            allowed = PROBE
        else:
            self._live = None
            self._report("workspace")
            return None, "workspace"
        travel = REACH * sum(abs(x) for x in v) * h
        if travel > allowed:
            self._report("workspace")
            return tuple(x * allowed / travel for x in v), ""
        return v, ""


# --- forward kinematics without a model library ------------------------------------------
def _quat_matrix(w: float, x: float, y: float, z: float) -> tuple[tuple[float, ...], ...]:
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def _matmul(a: Any, b: Any) -> tuple[tuple[float, ...], ...]:
    (b0, b1, b2) = b
    return tuple(
        (
            r[0] * b0[0] + r[1] * b1[0] + r[2] * b2[0],
            r[0] * b0[1] + r[1] * b1[1] + r[2] * b2[1],
            r[0] * b0[2] + r[1] * b1[2] + r[2] * b2[2],
        )
        for r in a
    )


def _apply(r: Any, v: Vector) -> tuple[float, float, float]:
    return (
        r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
        r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
        r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
    )


class Chain:
    """Forward kinematics of a serial arm: a list of links from the base frame to the
    tool point, each a fixed transform (``pos``, ``quat`` ``[w, x, y, z]``) and, for a
    joint, a rotation about its ``axis`` (through ``anchor``, in the link's frame) by the
    next joint angle. ``legws bridge bundle`` extracts it from the arm's own model and
    checks it against the model's kinematics.
    """

    def __init__(self, links: Sequence[dict[str, Any]]) -> None:
        self.links = []
        joints = 0
        for link in links:
            pos = _finite(link.get("pos"), 3)
            quat = _finite(link.get("quat", (1.0, 0.0, 0.0, 0.0)), 4)
            if pos is None or quat is None or _norm(quat) == 0.0:
                raise ValueError("a chain link needs a finite pos (3) and quat (4)")
            axis = link.get("axis")
            if axis is not None:
                axis = _finite(axis, 3)
                if axis is None or _norm(axis) == 0.0:
                    raise ValueError("a chain joint needs a finite non-zero axis (3)")
                axis = tuple(a / _norm(axis) for a in axis)
                anchor = _finite(link.get("anchor", (0.0, 0.0, 0.0)), 3)
                if anchor is None:
                    raise ValueError("a chain joint's anchor must be 3 finite numbers")
                joints += 1
            else:
                anchor = (0.0, 0.0, 0.0)
            self.links.append((pos, _quat_matrix(*quat), axis, anchor))
        self.dof = joints

    @classmethod
    def from_json(cls, text: str) -> Chain:
        """A chain from ``{"links": [...]}``."""
        doc = json.loads(text)
        if not isinstance(doc, dict) or not isinstance(doc.get("links"), list):
            raise ValueError('a chain file is {"links": [...]}')
        return cls(doc["links"])

    def position(self, q: Vector) -> tuple[float, float, float]:
        """The tool point in the base frame at joint angles ``q``."""
        if len(q) != self.dof:
            raise ValueError(f"expected {self.dof} joint angles, got {len(q)}")
        r: Any = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        p: tuple[float, float, float] = (0.0, 0.0, 0.0)
        i = 0
        for pos, rot, axis, anchor in self.links:
            d = _apply(r, pos)
            p = (p[0] + d[0], p[1] + d[1], p[2] + d[2])
            r = _matmul(r, rot)
            if axis is not None:
                turn = _axis_angle(axis, float(q[i]))
                i += 1
                # about the anchor: p += R (a - turn a)
                ta = _apply(turn, anchor)
                d = _apply(r, (anchor[0] - ta[0], anchor[1] - ta[1], anchor[2] - ta[2]))
                p = (p[0] + d[0], p[1] + d[1], p[2] + d[2])
                r = _matmul(r, turn)
        return p


def _axis_angle(axis: Vector, angle: float) -> tuple[tuple[float, ...], ...]:
    x, y, z = axis
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    return (
        (t * x * x + c, t * x * y - s * z, t * x * z + s * y),
        (t * x * y + s * z, t * y * y + c, t * y * z - s * x),
        (t * x * z - s * y, t * y * z + s * x, t * z * z + c),
    )
