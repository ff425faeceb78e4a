"""The bridge guard in numpy terms: a thin adapter over :mod:`legws_daemon.safety.limits`.

Every bridge runs the one guard of :mod:`legws_daemon.safety.limits` (standard library
only, so the bridges on a robot's own computer run it too; its docstring lists the rules,
their order and why the endpoint is judged by forward kinematics of the commanded step).
This adapter takes a profile's ``[bridge]`` and ``[workspace]`` (pydantic models), numpy
joint vectors and a numpy forward kinematics, for the fake bridge
(:mod:`legws_daemon.hardware.fake_bridge`) and the daemon-side tests.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, cast, get_args

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.arms import ArmSpec, arm
from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.bridge_messages import Limit
from legws_daemon.formats.profile import COMMAND_BURST, BridgeLimitsSpec, WorkspaceBox
from legws_daemon.safety import limits as core
from legws_daemon.safety.envelope import Box

#: Every limit, in the order the state message lists them.
LIMITS: tuple[Limit, ...] = get_args(Limit)
#: What became of a received command (:data:`legws_daemon.safety.limits.VERDICTS`).
Verdict = Literal["accepted", "refused", "ignored", "rejected"]

EePosition = Callable[[FloatArray], FloatArray]


@dataclass(frozen=True, slots=True)
class Step:
    """The motion of one integration step: ``velocity`` (n,) rad/s for ``duration`` s;
    ``reason`` says why it is zero (``None``: it moves)."""

    velocity: FloatArray
    duration: float
    reason: str | None = None

    @property
    def displacement(self) -> FloatArray:
        """The joint angle change of the step, rad."""
        return np.asarray(self.velocity * self.duration, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class LiveCommand:
    """The command being applied: its (capped) velocities and its lifetime."""

    dq: FloatArray
    received: float
    expires: float


def bridge_limits(
    limits: BridgeLimitsSpec, workspace: WorkspaceBox, burst: int = COMMAND_BURST
) -> core.BridgeLimits:
    """The module's limits of a profile's ``[bridge]`` and ``[workspace]``."""
    try:
        return core.BridgeLimits(
            **limits.model_dump(), workspace=(workspace.x, workspace.y, workspace.z), burst=burst
        )
    except ValueError as err:
        raise InputError(str(err)) from None


def grown(workspace: WorkspaceBox, margin: float) -> Box:
    """The box of a profile's ``[workspace]`` grown by ``margin`` on every side, m."""
    box = Box.of(workspace)
    return Box(box.lower - margin, box.upper + margin)


def box_distance(box: Box, p: FloatArray) -> float:
    """The Euclidean distance from ``p`` to ``box`` (0 inside)."""
    return core.box_distance(p.tolist(), box.lower.tolist(), box.upper.tolist())


class BridgeGuard:
    """One bridge's limits (:class:`legws_daemon.safety.limits.Guard`), in numpy terms.

    Args:
        limits: the profile's ``[bridge]`` table.
        workspace: the profile's ``[workspace]`` box (base frame).
        ee_position: forward kinematics, ``q (n,) -> endpoint position (3,)``.
        spec: the arm whose joint tables apply (default: the Sawyer).
        lower, upper, speed_limits: other joint tables (default: the arm's).
        burst: the token bucket's depth.
        clock: seconds, monotonic (the times a method is not given).
    """

    def __init__(
        self,
        limits: BridgeLimitsSpec,
        workspace: WorkspaceBox,
        ee_position: EePosition,
        *,
        spec: ArmSpec | None = None,
        lower: ArrayLike | None = None,
        upper: ArrayLike | None = None,
        speed_limits: ArrayLike | None = None,
        burst: int = COMMAND_BURST,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        a = spec if spec is not None else arm("sawyer")
        tables = [
            np.asarray(a.lower if lower is None else lower, dtype=np.float64),
            np.asarray(a.upper if upper is None else upper, dtype=np.float64),
            np.asarray(a.speed_limits if speed_limits is None else speed_limits, dtype=np.float64),
        ]
        if any(t.shape != (a.dof,) for t in tables):
            raise InputError(f"joint limits need {a.dof} values each (the {a.title}'s joints)")
        if burst < 1:
            raise InputError(f"must be at least 1, got {burst}", field="burst")

        def fk(q: object) -> list[float]:
            return [float(x) for x in ee_position(np.asarray(q, dtype=np.float64))]

        try:
            self.core = core.Guard(
                tables[0].tolist(),
                tables[1].tolist(),
                tables[2].tolist(),
                bridge_limits(limits, workspace, burst),
                clock=clock,
                ee_position=fk,
            )
        except ValueError as err:
            raise InputError(str(err)) from None
        self.limits = limits
        self.lower, self.upper = tables[0], tables[1]
        self.joint_speed_cap = np.asarray(self.core.joint_caps, dtype=np.float64)
        self.box = Box(np.array(self.core.box_lower), np.array(self.core.box_upper))
        self.burst = burst

    @property
    def counts(self) -> dict[Limit, int]:
        """Per limit, how many times it was enforced since the guard was made."""
        return cast(dict[Limit, int], self.core.counts)

    @property
    def stopped_by(self) -> str | None:
        return self.core.stopped_by

    @property
    def live(self) -> LiveCommand | None:
        live = self.core.live
        if live is None:
            return None
        return LiveCommand(np.asarray(live.dq, dtype=np.float64), live.received, live.expires)

    def take_limited(self) -> tuple[Limit, ...]:
        return cast(tuple[Limit, ...], self.core.take_limited())

    def receive(self, dq: ArrayLike, ttl: float, now: float | None = None) -> Verdict:
        return cast(Verdict, self.core.command(np.asarray(dq, dtype=np.float64).tolist(), ttl, now))

    def admit(self, now: float | None = None) -> bool:
        return self.core.admit(now)

    def accept(self, dq: ArrayLike, ttl: float, now: float | None = None) -> Verdict:
        return cast(Verdict, self.core.accept(np.asarray(dq, dtype=np.float64).tolist(), ttl, now))

    def clear(self) -> None:
        self.core.clear()

    def stop(self, role: str) -> None:
        self.core.stop(role)

    def resume(self, role: str = core.RESUME_AUTHORITY) -> bool:
        return self.core.resume(role)

    def step(self, q: ArrayLike, t0: float | None = None, t1: float | None = None) -> Step:
        """The motion allowed from ``t0`` to ``t1`` from joint angles ``q``."""
        qq = np.asarray(q, dtype=np.float64).ravel().tolist()
        s = self.core.step(qq, t0, t1)
        return Step(np.asarray(s.velocity, dtype=np.float64), s.duration, s.reason)
