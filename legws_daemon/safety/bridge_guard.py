"""The bridge's own limits: what joint velocity a robot-side bridge may actually apply.

The bridge contract (``docs/bridge.md``) lets any *valid* command through: up to each
joint's specification speed, for up to 1 s. A :class:`BridgeGuard` stands between the
commands a bridge receives and the velocities it applies, and enforces the hardware
profile's ``[bridge]`` limits (:class:`~legws_daemon.formats.profile.BridgeLimitsSpec`)
whatever it is sent — by a faulty daemon or by a foreign peer on an unauthenticated
network alike. The rules, in the order they apply:

On receipt of a command that passed the contract's validation (:meth:`BridgeGuard.receive`):

1. **rate** — a token bucket of :data:`~legws_daemon.formats.profile.COMMAND_BURST`
   commands, refilled at ``command_rate_hz``: a command beyond it is refused *and the arm
   stops* (the current command is cleared);
2. **stop latch** — after a stop (:meth:`BridgeGuard.stop`, from any role) commands are
   ignored until :meth:`BridgeGuard.resume`;
3. **joint speed** — each joint at most ``min(joint_speed_cap, its specification limit)``;
   a faster command is scaled down uniformly (its direction kept);
4. **ttl** — a command moves the arm at most ``min(ttl, max_ttl)`` after its receipt.

On every integration step from ``t0`` to ``t1`` (:meth:`BridgeGuard.step`; the caller
keeps steps short — a bridge period — so the endpoint checks apply along the way):

5. **deadman** — the live command acts only until it expires; then it is cleared;
6. **joint position limits** — a joint stops at its limit; past it, only inward motion;
7. **EE speed** — the endpoint's speed over the step, ``|FK(q + dq·τ) − FK(q)| / τ``
   (forward kinematics of the robot's own joints), at most ``ee_speed_cap``: faster steps
   are scaled down uniformly to the cap;
8. **workspace** — the step must end inside the profile's ``[workspace]`` box grown by
   ``workspace_margin``, or, when the endpoint is outside already, no farther from that
   box than it started; otherwise the step is not taken, *the arm stops* and the command is
   cleared. Steps back toward the box are allowed.

Each rule that changed or refused something is reported (:meth:`BridgeGuard.take_limited`,
the state message's ``limited``) and counted (:attr:`BridgeGuard.counts`).

Pure: time comes in as arguments, forward kinematics as a callable, nothing is shared. Not
thread-safe: the bridge calls it under its own lock.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.bridge_messages import (
    JOINT_LOWER,
    JOINT_SPEED_LIMITS,
    JOINT_UPPER,
    Limit,
)
from legws_daemon.formats.profile import COMMAND_BURST, BridgeLimitsSpec, WorkspaceBox
from legws_daemon.safety.envelope import Box, clamp_joint_velocity, within_speed

#: Every limit, in the order the state message lists them.
LIMITS: tuple[Limit, ...] = get_args(Limit)
#: What became of a received command: ``accepted`` (it is the live command now),
#: ``refused`` (over the rate: the arm stopped) or ``ignored`` (a latched stop).
Verdict = Literal["accepted", "refused", "ignored"]
#: Rescalings tried to bring a step's EE speed under the cap; past them the step is zero.
EE_SCALE_ATTEMPTS = 8
#: How far under the cap a rescaled step aims: the chord of a curved path does not shrink
#: quite in proportion to the step, so aiming exactly at the cap would need more attempts.
_EE_AIM = 1.0 - 1e-9

EePosition = Callable[[FloatArray], FloatArray]


@dataclass(frozen=True, slots=True)
class Step:
    """The motion of one integration step: ``velocity`` (7,) rad/s for ``duration`` s."""

    velocity: FloatArray
    duration: float

    @property
    def displacement(self) -> FloatArray:
        """The joint angle change of the step, rad."""
        return np.asarray(self.velocity * self.duration, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class LiveCommand:
    """The command being applied: its (capped) velocities and its lifetime."""

    dq: FloatArray  # (7,) rad/s, within the joint speed caps
    received: float  # s, the caller's clock
    expires: float  # s: received + min(ttl, max_ttl)


def grown(workspace: WorkspaceBox, margin: float) -> Box:
    """The box of a profile's ``[workspace]`` grown by ``margin`` on every side, m."""
    box = Box.of(workspace)
    return Box(box.lower - margin, box.upper + margin)


def box_distance(box: Box, p: FloatArray) -> float:
    """The Euclidean distance from ``p`` to ``box`` (0 inside)."""
    out = np.maximum(np.maximum(box.lower - p, p - box.upper), 0.0)
    return float(np.linalg.norm(out))


class BridgeGuard:
    """One bridge's limits and the state they need (the token bucket, the live command,
    the stop latch).

    Args:
        limits: the profile's ``[bridge]`` table.
        workspace: the profile's ``[workspace]`` box (base frame); the endpoint must stay
            inside it grown by ``limits.workspace_margin``.
        ee_position: forward kinematics, ``q (7,) -> endpoint position (3,)`` in the base
            frame (the robot's own model).
        lower, upper: joint position limits, rad (default: the contract's).
        speed_limits: the joints' specification speed limits, rad/s (default: the
            contract's); the cap of joint ``i`` is ``min(limits.joint_speed_cap, speed_limits[i])``.
        burst: the token bucket's depth (default :data:`COMMAND_BURST`).

    Attributes:
        limits: as given.
        joint_speed_cap: (7,) per-joint speed caps, rad/s.
        box: the workspace box grown by the margin: where the endpoint may be.
        counts: per limit, how many times it was enforced (commands scaled, refused,
            capped; steps scaled or refused) since the guard was made.
        stopped_by: the role whose stop is latched, or ``None``.
    """

    def __init__(
        self,
        limits: BridgeLimitsSpec,
        workspace: WorkspaceBox,
        ee_position: EePosition,
        *,
        lower: ArrayLike = JOINT_LOWER,
        upper: ArrayLike = JOINT_UPPER,
        speed_limits: ArrayLike = JOINT_SPEED_LIMITS,
        burst: int = COMMAND_BURST,
    ) -> None:
        self.lower = np.asarray(lower, dtype=np.float64)
        self.upper = np.asarray(upper, dtype=np.float64)
        spec = np.asarray(speed_limits, dtype=np.float64)
        if self.lower.shape != (7,) or self.upper.shape != (7,) or spec.shape != (7,):
            raise InputError("joint limits need 7 values each")
        if np.any(self.lower >= self.upper) or not np.all(spec > 0.0):
            raise InputError("joint limits must be ordered and speed limits positive")
        if burst < 1:
            raise InputError(f"must be at least 1, got {burst}", field="burst")
        self.limits = limits
        self.joint_speed_cap = np.minimum(limits.joint_speed_cap, spec)
        self.box = grown(workspace, limits.workspace_margin)
        self.burst = burst
        self.counts: dict[Limit, int] = dict.fromkeys(LIMITS, 0)
        self.stopped_by: str | None = None
        self._ee_position = ee_position
        self._tokens = float(burst)
        self._refilled: float | None = None  # the bucket's time; None: full, never used
        self._live: LiveCommand | None = None
        self._since: set[Limit] = set()

    # --- what there is to know ----------------------------------------------------
    @property
    def live(self) -> LiveCommand | None:
        """The command being applied, if any."""
        return self._live

    def take_limited(self) -> tuple[Limit, ...]:
        """The limits enforced since the previous call (in :data:`LIMITS` order)."""
        out = tuple(limit for limit in LIMITS if limit in self._since)
        self._since.clear()
        return out

    def _report(self, limit: Limit) -> None:
        self.counts[limit] += 1
        self._since.add(limit)

    # --- commands -------------------------------------------------------------------
    def receive(self, dq: ArrayLike, ttl: float, now: float) -> Verdict:
        """A valid command arrives at ``now``: :meth:`admit`, then :meth:`accept`."""
        if not self.admit(now):
            return "refused"
        return self.accept(dq, ttl, now)

    def admit(self, now: float) -> bool:
        """The rate limit: take a token for a command arriving at ``now``.

        Without one the command is refused and the arm stops (``rate``). A bridge calls
        this for every valid command, also while it ignores them (disabled, stopped), so
        the bucket measures the sender.
        """
        if self._refilled is not None:
            elapsed = now - self._refilled
            if elapsed > 0.0:
                self._tokens = min(
                    float(self.burst), self._tokens + elapsed * self.limits.command_rate_hz
                )
                self._refilled = now
        else:
            self._refilled = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        self._live = None
        self._report("rate")
        return False

    def accept(self, dq: ArrayLike, ttl: float, now: float) -> Verdict:
        """Make an admitted command the live one, within the joint speed caps and the ttl
        cap; ``ignored`` while a stop is latched (the live command stays cleared)."""
        if self.stopped_by is not None:
            return "ignored"
        v = np.asarray(dq, dtype=np.float64)
        if v.shape != (7,) or not np.all(np.isfinite(v)) or not (ttl > 0.0 and math.isfinite(ttl)):
            self._live = None  # the contract's validation lets none of this through
            return "ignored"
        capped = within_speed(v, self.joint_speed_cap)
        if capped is not v:
            v = capped
            self._report("joint_speed")
        if ttl > self.limits.max_ttl:
            self._report("ttl")
        life = min(ttl, self.limits.max_ttl)
        self._live = LiveCommand(v, now, now + life)
        return "accepted"

    def clear(self) -> None:
        """Stop: no live command (a rejected command, a disabled robot, a shutdown)."""
        self._live = None

    def stop(self, role: str) -> None:
        """A stop from ``role``: clear the command and latch (the first role is kept)."""
        self._live = None
        if self.stopped_by is None:
            self.stopped_by = role

    def resume(self) -> bool:
        """Clear the stop latch; ``True`` if one was latched. No command comes back."""
        latched = self.stopped_by is not None
        self.stopped_by = None
        return latched

    # --- motion ---------------------------------------------------------------------
    def step(self, q: ArrayLike, t0: float, t1: float) -> Step:
        """The motion allowed from ``t0`` to ``t1`` starting at joint angles ``q``.

        The caller integrates ``q + step.displacement`` (the velocity acts during
        ``step.duration`` ≤ ``t1 - t0``: the command may expire inside the step).
        """
        live = self._live
        zero = Step(np.zeros(7), 0.0)
        if live is None or not t1 > t0:
            return zero
        if t1 >= live.expires:
            self._live = None  # the deadman: after this step, no motion
        tau = min(t1, live.expires) - max(t0, live.received)
        if not tau > 0.0:
            return zero
        qq = np.asarray(q, dtype=np.float64)
        if qq.shape != (7,) or not np.all(np.isfinite(qq)):
            self._live = None
            return zero
        v = clamp_joint_velocity(qq, live.dq, tau, self.lower, self.upper, self.joint_speed_cap)
        if not np.any(v):
            return zero
        p0 = np.asarray(self._ee_position(qq), dtype=np.float64)
        if p0.shape != (3,) or not np.all(np.isfinite(p0)):
            self._live = None  # no endpoint to judge by: no motion
            return zero
        v, p1 = self._ee_speed_limited(qq, v, tau, p0)
        if p1 is None:
            return zero
        if not self._may_end_at(p0, p1):
            self._live = None
            self._report("workspace")
            return zero
        return Step(v, tau)

    def _may_end_at(self, p0: FloatArray, p1: FloatArray) -> bool:
        """The workspace rule: a step from ``p0`` may end at ``p1`` if that is inside the
        box, or, from outside it, no farther from it."""
        box = self.box
        if box.contains(p1, tol=0.0):
            return True
        return not box.contains(p0, tol=0.0) and box_distance(box, p1) <= box_distance(box, p0)

    def _ee_speed_limited(
        self, q: FloatArray, v: FloatArray, tau: float, p0: FloatArray
    ) -> tuple[FloatArray, FloatArray | None]:
        """``v`` scaled down uniformly until the endpoint's speed over the step is at most
        the cap, and the step's end position (``None``: no acceptable step)."""
        cap = self.limits.ee_speed_cap
        scaled = False
        for _ in range(EE_SCALE_ATTEMPTS):
            p1 = np.asarray(self._ee_position(q + v * tau), dtype=np.float64)
            if p1.shape != (3,) or not np.all(np.isfinite(p1)):
                self._live = None
                return v, None
            speed = float(np.linalg.norm(p1 - p0)) / tau
            if speed <= cap:
                if scaled:
                    self._report("ee_speed")
                return v, p1
            v = v * (cap / speed * _EE_AIM)
            scaled = True
        self._report("ee_speed")
        return v, None
