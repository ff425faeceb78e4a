"""The operator model of method.md §10: how a given person steers.

``O = (speed s, sigma, rho, bias b, steering)``:

* mean deflection ``mu(x, g) = s Q(R_z(b) pi_h(x, g))``: aim at the goal, turned by ``b``
  about the base z axis (anticlockwise seen from above), quantised by ``Q`` (``free``: the
  identity; ``axes``: the one of ±x, ±y, ±z closest to the aim; ``axes+diagonals``: the
  closest of the 26 directions of a 3×3×3 grid, normalised), scaled by ``s`` in (0, 1];
* deflection ``u_t = mu(x_t, g*) + e_t / v_max`` with ``e_t`` AR(1) per axis,
  ``e_t = rho e_{t-1} + sqrt(1 - rho²) w_t``, ``w_t ~ N(0, sigma² I)``, stationary
  (``e_0 ~ N(0, sigma² I)``); the robot moves at ``v_max u_t``, clipped to ``|u_t| <= 1``.

Section 2's user is :meth:`OperatorModel.paper` ``= (1, sigma, 0, 0, free)``.

The certificates under O (:mod:`.certificate`, :mod:`.commit`) need, per step, how far the
nominal advances and how the deflection scatters around it: :class:`UserMotion` (the
model as written, or — ``clip=True`` — the moments of the deflection after the robot's
clip, by Gauss–Hermite quadrature, :func:`clipped_moments`), and the variance of a sum of
``t`` AR(1) terms, :func:`ar1_sum_variance`. The nominal itself: :func:`nominal_path` (the
noise-free closed loop, ``p̄_t = p̄_{t-1} + v_max dt mu(p̄_{t-1}, g*)``), with its arrival
and horizon steps (:func:`path_steps`). Pure numpy; everything is batched over leading
axes.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Any, Literal, get_args

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, IntArray, safe_unit
from legws_daemon.core.params import RANGES, Params, range_problem
from legws_daemon.errors import InputError

Steering = Literal["free", "axes", "axes+diagonals"]
STEERINGS: tuple[str, ...] = get_args(Steering)

#: Closed ranges of the model's numbers. ``speed`` below 0.1 would make a reach of a metre
#: last over six minutes; ``|rho|`` at 0.99 already multiplies the variance of a long sum
#: by ~200; a bias beyond 45° is not an aim at the goal any more (with axis steering the
#: nominal can then move away from it).
SPEED_RANGE = (0.1, 1.0)
RHO_RANGE = (0.0, 0.99)
BIAS_RANGE_DEG = (-45.0, 45.0)
#: Longest nominal followed before a goal counts as not reachable by this operator
#: (method.md §10: none within 10^4 steps).
MAX_OPERATOR_STEPS = 10_000
#: Longest straight-line horizon accepted (at 20 Hz, 83 minutes); longer means nonsensical
#: inputs.
MAX_HORIZON_STEPS = 100_000
#: A nominal step this much inside one ``v_max dt`` of the goal has arrived (floating-point
#: guard, in units of the step).
_ARRIVAL_GUARD = 1e-9


@dataclass(frozen=True, slots=True)
class OperatorModel:
    """How one person steers (method.md §10).

    Attributes:
        speed: ``s``, the mean deflection toward the aim, in (0, 1] (idle ticks lower it).
        sigma: per-axis velocity noise, m/s.
        rho: lag-1 autocorrelation of the noise per tick, in ``[0, 0.99]``.
        bias_deg: the aim turned about the base z axis, degrees (anticlockwise from above).
        steering: ``free``, ``axes`` or ``axes+diagonals`` (:func:`quantise`).
    """

    speed: float = 1.0
    sigma: float = 0.03
    rho: float = 0.0
    bias_deg: float = 0.0
    steering: Steering = "free"

    def __post_init__(self) -> None:
        for name, (lo, hi) in (
            ("speed", SPEED_RANGE),
            ("rho", RHO_RANGE),
            ("bias_deg", BIAS_RANGE_DEG),
        ):
            value = getattr(self, name)
            if not (_is_real(value) and math.isfinite(value) and lo <= value <= hi):
                raise InputError(
                    f"expected a number in [{lo:g}, {hi:g}], got {value!r}", field=name
                )
        lo, hi = RANGES["sigma"]
        if not (_is_real(self.sigma) and math.isfinite(self.sigma) and lo <= self.sigma <= hi):
            raise InputError(range_problem("sigma", self.sigma), field="sigma")
        if self.steering not in STEERINGS:
            raise InputError(
                f"unknown steering {self.steering!r}; known: {', '.join(STEERINGS)}",
                field="steering",
            )

    @classmethod
    def paper(cls, params: Params) -> OperatorModel:
        """Section 2's user: full deflection, white noise ``params.sigma``, aimed straight."""
        return cls(1.0, params.sigma, 0.0, 0.0, "free")

    @property
    def bias(self) -> float:
        """``b`` in radians."""
        return math.radians(self.bias_deg)

    @property
    def straight(self) -> bool:
        """The nominal is a straight line at constant speed (no bias, free steering)."""
        return self.bias_deg == 0.0 and self.steering == "free"

    def motion(self, params: Params, clip: bool = False) -> UserMotion:
        """Per-step moments of this operator's deflection around the nominal: the model as
        written (``clip=False``: mean ``s``, standard deviation ``sigma / v_max`` on every
        axis), or after the robot's clip to ``|u| <= 1`` (:func:`clipped_moments`)."""
        noise = self.sigma / params.v_max
        if not clip:
            return UserMotion(self.speed, noise, noise, self.rho)
        mean, along, across = clipped_moments(self.speed, noise)
        return UserMotion(mean, along, across, self.rho)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def describe(self) -> str:
        """One line: ``s 0.92, sigma 0.031 m/s, rho 0.83, bias -4.1°, free``."""
        return (
            f"s {self.speed:.2f}, sigma {self.sigma:.3f} m/s, rho {self.rho:.2f}, "
            f"bias {self.bias_deg:+.1f}°, {self.steering}"
        )


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


@dataclass(frozen=True, slots=True)
class UserMotion:
    """Per-step moments of the deflection ``u`` relative to the nominal's direction ``e``
    (in units of ``v_max``), and the noise's lag-1 autocorrelation.

    Attributes:
        speed: ``E[u . e]``, the nominal's advance per step.
        along: standard deviation of ``u . e``.
        across: standard deviation of ``u`` on each axis across ``e``.
        rho: lag-1 autocorrelation of the noise (:func:`ar1_sum_variance`).
    """

    speed: float
    along: float
    across: float
    rho: float = 0.0

    @property
    def isotropic(self) -> bool:
        return self.along == self.across

    @property
    def widest(self) -> float:
        """The larger standard deviation: a bound for every direction."""
        return max(self.along, self.across)


def ar1_sum_variance(t: ArrayLike, rho: float) -> FloatArray:
    """``S_rho(t)``: the variance of a sum of ``t`` terms of a stationary AR(1) process with
    unit variance, ``t (1 + rho) / (1 - rho) - 2 rho (1 - rho^t) / (1 - rho)^2``; exactly
    ``t`` for ``rho = 0`` (method.md §10)."""
    steps = np.asarray(t, dtype=np.float64)
    if rho == 0.0:
        return steps
    return np.asarray(
        steps * (1.0 + rho) / (1.0 - rho) - 2.0 * rho * (1.0 - rho**steps) / (1.0 - rho) ** 2,
        dtype=np.float64,
    )


# --- the mean policy --------------------------------------------------------------------

#: The 26 directions of a 3×3×3 grid around the origin, normalised.
_GRID = np.array(
    [
        (x, y, z)
        for x in (-1, 0, 1)
        for y in (-1, 0, 1)
        for z in (-1, 0, 1)
        if (x, y, z) != (0, 0, 0)
    ],
    dtype=np.float64,
)
GRID_DIRECTIONS: FloatArray = _GRID / np.linalg.norm(_GRID, axis=1, keepdims=True)
AXIS_DIRECTIONS: FloatArray = np.concatenate([np.eye(3), -np.eye(3)])


def rotate_z(v: ArrayLike, angle: float) -> FloatArray:
    """Vectors ``(..., 3)`` turned by ``angle`` about the z axis (anticlockwise from above)."""
    arr = np.asarray(v, dtype=np.float64)
    if angle == 0.0:
        return arr
    c, s = math.cos(angle), math.sin(angle)
    out = arr.copy()
    out[..., 0] = c * arr[..., 0] - s * arr[..., 1]
    out[..., 1] = s * arr[..., 0] + c * arr[..., 1]
    return out


def quantise(aim: ArrayLike, steering: str) -> FloatArray:
    """``Q``: unit aims ``(..., 3)`` to the operator's steering directions (zero stays
    zero). ``axes``: the one of ±x, ±y, ±z with the largest component (ties: x before y
    before z); ``axes+diagonals``: the closest of :data:`GRID_DIRECTIONS`."""
    a = np.asarray(aim, dtype=np.float64)
    if steering == "free":
        return a
    if steering == "axes":
        flat = a.reshape(-1, 3)
        rows = np.arange(len(flat))
        k = np.argmax(np.abs(flat), axis=1)
        out = np.zeros_like(flat)
        out[rows, k] = np.sign(flat[rows, k])
        return out.reshape(a.shape)
    if steering == "axes+diagonals":
        best = np.argmax(a @ GRID_DIRECTIONS.T, axis=-1)
        out = GRID_DIRECTIONS[best]
        zero = ~np.any(a != 0.0, axis=-1)
        return np.asarray(np.where(zero[..., None], 0.0, out), dtype=np.float64)
    raise InputError(f"unknown steering {steering!r}; known: {', '.join(STEERINGS)}")


def aim(position: ArrayLike, target: ArrayLike, operator: OperatorModel) -> FloatArray:
    """``Q(R_z(b) pi_h(x, g))``: the operator's unit aim from ``position`` toward ``target``
    (zero on the target)."""
    pull = safe_unit(np.asarray(target, dtype=np.float64) - np.asarray(position, dtype=np.float64))
    return quantise(rotate_z(pull, operator.bias), operator.steering)


def mean_deflection(position: ArrayLike, target: ArrayLike, operator: OperatorModel) -> FloatArray:
    """``mu(x, g) = s Q(R_z(b) pi_h(x, g))``."""
    return np.asarray(operator.speed * aim(position, target, operator), dtype=np.float64)


# --- the robot's clip ------------------------------------------------------------------

#: Gauss–Hermite nodes along the way and Gauss–Laguerre nodes of the squared radius across
#: it: the clipped deflection's moments are a two-dimensional integral (the clip keeps the
#: direction and the noise is isotropic, so only the component along the mean and the
#: distance from it matter). Accurate to ~1e-6.
_HERMITE_NODES = 96
_LAGUERRE_NODES = 64


@lru_cache(maxsize=1)
def _nodes() -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    x, wx = np.polynomial.hermite_e.hermegauss(_HERMITE_NODES)  # weight exp(-x^2 / 2)
    e, we = np.polynomial.laguerre.laggauss(_LAGUERRE_NODES)  # weight exp(-e)
    return x, wx / wx.sum(), e, we / we.sum()


def clipped_moments_batch(
    speed: ArrayLike, noise: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`clipped_moments` for arrays of ``speed`` and ``noise`` (broadcast)."""
    s = np.asarray(speed, dtype=np.float64)[..., None, None]
    lam = np.asarray(noise, dtype=np.float64)[..., None, None]
    x, wx, e, we = _nodes()
    a = s + lam * x[:, None]  # the component along the mean direction
    r2 = 2.0 * lam**2 * e[None, :]  # the squared distance across it (chi-squared, 2 dof)
    scale = 1.0 / np.maximum(np.sqrt(a * a + r2), 1.0)
    w = wx[:, None] * we[None, :]
    mean = np.sum(w * a * scale, axis=(-2, -1))
    along2 = np.sum(w * (a * scale) ** 2, axis=(-2, -1)) - mean**2
    across2 = 0.5 * np.sum(w * r2 * scale**2, axis=(-2, -1))
    return (
        np.asarray(mean, dtype=np.float64),
        np.sqrt(np.maximum(along2, 0.0)),
        np.sqrt(np.maximum(across2, 0.0)),
    )


@lru_cache(maxsize=256)
def clipped_moments(speed: float, noise: float) -> tuple[float, float, float]:
    """``(E[c . e], sd(c . e), sd across)`` of the clipped deflection
    ``c = clip(s e + n)`` (scaled to norm 1 where longer), ``n ~ N(0, noise² I)``,
    ``e`` a unit vector: how far the robot's EE advances per step and how it scatters."""
    mean, along, across = clipped_moments_batch(speed, noise)
    return float(mean), float(along), float(across)


# --- the nominal -----------------------------------------------------------------------


def horizon_steps(distance: ArrayLike, params: Params, speed: float = 1.0) -> IntArray:
    """Section 4's horizon ``T = ceil(eta |p_g* - p0| / (s v_max dt))`` (at least one
    step): the first step whose path length reaches ``eta |p_g* - p0|`` at ``s`` steps.

    Raises:
        InputError: when a horizon exceeds :data:`MAX_HORIZON_STEPS`.
    """
    d = np.asarray(distance, dtype=np.float64)
    raw = params.horizon_fraction * d / (speed * params.v_max * params.dt)
    if not np.all(raw <= MAX_HORIZON_STEPS):
        raise InputError(
            f"a goal {float(np.max(d)):.3g} m away needs {float(np.max(raw)):.3g} steps of "
            f"{speed * params.v_max * params.dt:.3g} m; at most {MAX_HORIZON_STEPS} are "
            "accepted (check v_max, dt, the operator's speed and the positions)"
        )
    # Guard against 7.000000000001 becoming 8 through floating-point noise.
    steps = np.ceil(raw - 1e-9).astype(np.int64)
    return np.asarray(np.maximum(steps, 1), dtype=np.int64)


def arrival_steps(distance: ArrayLike, params: Params, speed: float = 1.0) -> IntArray:
    """``T_a`` of a straight nominal advancing ``speed v_max dt`` per step: the first step
    closer than ``v_max dt`` to the goal (method.md §10), which for ``speed = 1`` is §9's
    ``floor(|p_g* - p0| / (v_max dt))`` (1e-9 guard, at least one step).

    Raises:
        InputError: when a horizon exceeds :data:`MAX_HORIZON_STEPS`.
    """
    d = np.asarray(distance, dtype=np.float64)
    raw = d / (params.v_max * params.dt)
    if not np.all(raw <= speed * MAX_HORIZON_STEPS):
        raise InputError(
            f"a goal {float(np.max(d)):.3g} m away needs {float(np.max(raw) / speed):.3g} steps "
            f"of {speed * params.v_max * params.dt:.3g} m; at most {MAX_HORIZON_STEPS} are "
            "accepted"
        )
    # x - 1 + 1 is x exactly: speed 1 is floor(x + 1e-9); 7.999999999 steps of noise is 8
    steps = np.floor((raw - 1.0 + speed) / speed + 1e-9)
    return np.asarray(np.maximum(steps, 1).astype(np.int64), dtype=np.int64)


def nominal_steps(
    p0: ArrayLike,
    goals: ArrayLike,
    operator: OperatorModel,
    motion: UserMotion,
    params: Params,
) -> tuple[IntArray, IntArray]:
    """``(T_a, T)`` of each goal ``(..., 3)``: the arrival step (the first step whose
    nominal is closer than ``v_max dt`` to the goal; ``0`` when none within
    :data:`MAX_OPERATOR_STEPS`: not reachable by this operator) and section 4's horizon (the
    first step whose path length reaches ``eta |p_g - p0|``, at least 1). The nominal
    advances ``motion.speed v_max dt`` per step along the operator's aim."""
    p = np.asarray(p0, dtype=np.float64)
    g = np.asarray(goals, dtype=np.float64)
    delta = g - p
    d = np.sqrt(np.einsum("...i,...i->...", delta, delta))
    speed = motion.speed
    # the path length after t steps is t s v_max dt whatever the aim: the horizon in closed
    # form (as section 4's, at speed s)
    horizon = horizon_steps(d, params, speed)
    if operator.straight:
        # the remaining distance after t steps is (x - t s) steps of v_max dt
        return arrival_steps(d, params, speed), horizon
    step = speed * params.v_max * params.dt
    here = np.broadcast_to(p, g.shape).copy()
    arrival = np.zeros(g.shape[:-1], dtype=np.int64)
    threshold = (params.v_max * params.dt) * (1.0 - _ARRIVAL_GUARD)
    for t in range(1, MAX_OPERATOR_STEPS + 1):
        here += step * aim(here, g, operator)
        left = g - here
        near = np.einsum("...i,...i->...", left, left) < threshold**2
        arrival = np.where((arrival == 0) & near, t, arrival)
        if np.all(arrival > 0):
            break
    return arrival, horizon


def nominal_path(
    p0: ArrayLike, goals: ArrayLike, operator: OperatorModel, motion: UserMotion,
    params: Params, steps: int,
) -> FloatArray:  # fmt: skip
    """The nominal toward each goal ``(..., 3)`` at steps ``1..steps``: ``(..., steps, 3)``.
    A straight operator's in closed form; otherwise the noise-free closed loop."""
    p = np.asarray(p0, dtype=np.float64)
    g = np.asarray(goals, dtype=np.float64)
    step = motion.speed * params.v_max * params.dt
    if operator.straight:
        u = safe_unit(g - p)
        ticks = np.arange(1, steps + 1, dtype=np.float64)
        return np.asarray(p + ticks[:, None] * step * u[..., None, :], dtype=np.float64)
    out = np.empty((*g.shape[:-1], steps, 3))
    here = np.broadcast_to(p, g.shape).copy()
    for t in range(steps):
        here += step * aim(here, g, operator)
        out[..., t, :] = here
    return out
