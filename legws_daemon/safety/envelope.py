"""The safety envelope: what a velocity command may be, given where the robot is.

Every command sent to a robot passes through :func:`clamp_ee_velocity` (and, for joint
commands, :func:`clamp_joint_velocity`). The rules, in order:

1. anything non-finite (NaN, infinity) or of the wrong shape is a zero command;
2. the speed is scaled down (direction kept) to at most ``v_max``;
3. per axis, a component that would carry the EE out of the workspace box within one tick
   is cut so the EE stops at the box face; outside the box, only motion back toward it
   is allowed.

The result is what may be sent; the caller reports it as "what was actually sent".
Joint velocity commands (the assistance's joint-space moves) are bounded the same way:
:func:`clamp_joint_velocity` for the joints' own limits, :func:`limit_ee_speed` for the EE's
linear and angular speed; the adapter keeps the resulting step inside the box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.profile import WorkspaceBox


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned workspace box for the EE position, metres."""

    lower: FloatArray  # (3,)
    upper: FloatArray  # (3,)

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lower, float), np.asarray(self.upper, float)
        if (
            lo.shape != (3,)
            or hi.shape != (3,)
            or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)))
        ):
            raise InputError("a workspace box needs 3 finite lower and upper bounds")
        if np.any(lo >= hi):
            raise InputError(f"workspace box lower {lo.tolist()} must be below upper {hi.tolist()}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @classmethod
    def of(cls, workspace: WorkspaceBox) -> Box:
        """The box of a hardware profile's ``[workspace]``."""
        x, y, z = workspace.x, workspace.y, workspace.z
        return cls(np.array([x[0], y[0], z[0]]), np.array([x[1], y[1], z[1]]))

    def contains(self, p: ArrayLike, tol: float = 1e-9) -> bool:
        q = np.asarray(p, dtype=np.float64)
        return bool(np.all(q >= self.lower - tol) and np.all(q <= self.upper + tol))

    def with_floor(self, z: float) -> Box:
        """This box with its floor at height ``z``: raised or lowered, but never below this
        box's own floor and always below its ceiling (a non-finite ``z`` keeps the floor)."""
        lower = self.lower.copy()
        if math.isfinite(z):
            lower[2] = min(max(z, self.lower[2]), self.upper[2] - 1e-6)
        box = object.__new__(Box)  # valid by construction: no second validation per tick
        object.__setattr__(box, "lower", lower)
        object.__setattr__(box, "upper", self.upper)
        return box


def _finite_vector(v: object, n: int) -> FloatArray | None:
    try:
        arr = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        return None
    return arr


def clamp_ee_velocity(
    position: ArrayLike, velocity: object, dt: float, box: Box, v_max: float
) -> FloatArray:
    """The EE velocity that may be sent: finite, at most ``v_max``, staying in ``box``.

    Args:
        position: the EE position now (measured). Non-finite means the state is unknown:
            the command is zero.
        velocity: the requested linear velocity (3,), m/s.
        dt: the control period, s (> 0).
        box: the workspace box.
        v_max: the speed limit, m/s (>= 0).
    """
    zero = np.zeros(3)
    p = _finite_vector(position, 3)
    v = _finite_vector(velocity, 3)
    if p is None or v is None or not (dt > 0 and math.isfinite(dt)) or not (v_max >= 0):
        return zero
    speed = math.hypot(*v)  # no overflow for huge components
    if speed > v_max:
        v = v * (v_max / speed) if math.isfinite(speed) else zero
    nxt = p + v * dt
    out = v.copy()
    for i in range(3):
        lo, hi = box.lower[i], box.upper[i]
        if nxt[i] > hi:
            # stop at the face; outside already: only inward motion (v < 0) passes
            out[i] = max((hi - p[i]) / dt, 0.0) if p[i] <= hi else min(v[i], 0.0)
        elif nxt[i] < lo:
            out[i] = min((lo - p[i]) / dt, 0.0) if p[i] >= lo else max(v[i], 0.0)
    return out


def within_speed(qdot: FloatArray, qdot_max: FloatArray) -> FloatArray:
    """Finite joint velocities scaled down uniformly (direction kept) so that each is within
    its limit ``|qdot_i| <= qdot_max_i``; unchanged when they already are. Exact for any
    finite request: it is scaled as a unit vector first, so 1e308 rad/s does not overflow."""
    peak = float(np.max(np.abs(qdot), initial=0.0))
    if peak == 0.0:
        return qdot
    unit = qdot / peak
    ratio = float(np.max(np.abs(unit) / qdot_max))  # the limits are reached at 1 / ratio
    if peak * ratio <= 1.0:
        return qdot
    # the clip only removes rounding above a limit
    return np.asarray(np.clip(unit / ratio, -qdot_max, qdot_max), dtype=np.float64)


def clamp_joint_velocity(
    q: ArrayLike, qdot: object, dt: float, lower: ArrayLike, upper: ArrayLike, qdot_max: ArrayLike
) -> FloatArray:
    """The joint velocity that may be sent: finite, within speed limits (uniform scaling,
    direction kept), never carrying a joint past its position limit within one tick."""
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    vmax = np.asarray(qdot_max, dtype=np.float64)
    n = len(lo)
    zero = np.zeros(n)
    qq = _finite_vector(q, n)
    qd = _finite_vector(qdot, n)
    if qq is None or qd is None or not (dt > 0 and math.isfinite(dt)):
        return zero
    qd = within_speed(qd, vmax)
    nxt = qq + qd * dt
    out = qd.copy()
    over = nxt > hi
    under = nxt < lo
    out[over] = np.where(
        qq[over] <= hi[over], np.maximum((hi[over] - qq[over]) / dt, 0.0), np.minimum(qd[over], 0.0)
    )
    out[under] = np.where(
        qq[under] >= lo[under],
        np.minimum((lo[under] - qq[under]) / dt, 0.0),
        np.maximum(qd[under], 0.0),
    )
    return np.asarray(out, dtype=np.float64)


def limit_ee_speed(jacobian: ArrayLike, qdot: ArrayLike, v_max: float, w_max: float) -> FloatArray:
    """``qdot`` scaled down uniformly (direction kept) so that the EE moves at most
    ``v_max`` (m/s) and turns at most ``w_max`` (rad/s), to first order.

    Args:
        jacobian: ``(6, n)`` EE Jacobian, linear rows then angular rows.
        qdot: ``(n,)`` finite joint velocities (e.g. from :func:`clamp_joint_velocity`).
    """
    J = np.asarray(jacobian, dtype=np.float64)
    qd = np.asarray(qdot, dtype=np.float64)
    twist = J @ qd
    v = math.hypot(*twist[:3])
    w = math.hypot(*twist[3:])
    ratio = max(_over(v, v_max), _over(w, w_max))
    if not math.isfinite(ratio):
        return np.zeros_like(qd)
    return qd / ratio if ratio > 1.0 else qd.copy()


def _over(speed: float, limit: float) -> float:
    """How many times ``limit`` the ``speed`` is (0 for no motion, inf past a zero limit)."""
    if not speed > 0.0:
        return 0.0 if speed == 0.0 else math.inf  # NaN: refuse
    return speed / limit if limit > 0.0 else math.inf
