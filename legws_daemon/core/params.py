"""Model parameters with the defaults of the method (``shared/spec/method.md``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Literal, get_args

from legws_daemon.errors import InputError

CostForm = Literal["dragan", "ratio"]
COST_FORMS: tuple[str, ...] = get_args(CostForm)


@dataclass(frozen=True, slots=True)
class Params:
    """Observer, user-model and certificate parameters.

    Attributes:
        beta: Boltzmann rationality coefficient.
        rotation_weight: ``lambda_R`` of the SE(3) distance, metres per radian.
        sigma: joystick velocity noise, m/s (per axis standard deviation).
        v_max: end-effector speed at full deflection, m/s.
        dt: control period, s.
        alpha: accepted failure probability of the certificate, in ``[1e-9, 0.5]``.
        horizon_fraction: ``eta``, fraction of the way to the goal at which the
            decision is wanted.
        cost: cost form of the observer, ``dragan`` (default) or ``ratio``.
        p_thresh: posterior at which the observer commits.
    """

    beta: float = 5.0
    rotation_weight: float = 0.04
    sigma: float = 0.03
    v_max: float = 0.05
    dt: float = 0.05
    alpha: float = 0.05
    horizon_fraction: float = 0.75
    cost: CostForm = "dragan"
    p_thresh: float = 0.9

    def __post_init__(self) -> None:
        for name, (lo, hi) in RANGES.items():
            value = getattr(self, name)
            if not (_is_real(value) and math.isfinite(value) and lo <= value <= hi):
                raise InputError(range_problem(name, value), field=name)
        p = self.p_thresh
        if not (_is_real(p) and 0.0 < p < 1.0):
            raise InputError(f"expected a number in (0, 1), got {p!r}", field="p_thresh")
        eta = self.horizon_fraction
        if not (_is_real(eta) and 0.0 < eta <= 1.0):
            raise InputError(f"expected a number in (0, 1], got {eta!r}", field="horizon_fraction")
        if self.cost not in COST_FORMS:
            raise InputError(
                f"unknown cost form {self.cost!r}; known: {', '.join(COST_FORMS)}", field="cost"
            )

    def with_cost(self, cost: CostForm) -> Params:
        return replace(self, cost=cost)

    def as_dict(self) -> dict[str, float | str]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: Closed ranges of the numeric parameters: wide enough for any real set-up, narrow enough
#: that no computation downstream overflows, turns non-finite or runs for ever. The CLI's
#: options declare the same ranges.
RANGES: dict[str, tuple[float, float]] = {
    "beta": (1e-6, 1e3),
    "rotation_weight": (0.0, 10.0),
    "sigma": (1e-9, 10.0),
    "v_max": (1e-3, 10.0),
    "dt": (1e-4, 10.0),
    "alpha": (1e-9, 0.5),
}

#: Why a range ends where it does (below its low end, above its high end), where the reason
#: is not plain physics.
_WHY: dict[str, tuple[str, str]] = {
    "alpha": (
        "a failure probability below 1e-9 is beyond what the Gaussian, linearised model can "
        "promise or a Monte Carlo check can test (and near 1e-17 its normal quantile leaves "
        "double precision)",
        "above 0.5 the certificate would promise less than a coin flip",
    ),
}


def range_problem(name: str, value: object) -> str:
    """The one-line message of a parameter outside :data:`RANGES` (with the reason)."""
    lo, hi = RANGES[name]
    text = f"expected a number in [{lo:g}, {hi:g}], got {value!r}"
    if name in _WHY and isinstance(value, int | float) and math.isfinite(value):
        low, high = _WHY[name]
        text += f": {low}" if value < lo else f": {high}" if value > hi else ""
    return text


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)
