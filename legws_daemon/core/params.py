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
        alpha: accepted failure probability of the certificate.
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
        for name, (lo, hi) in _RANGES.items():
            value = getattr(self, name)
            if not (_is_real(value) and math.isfinite(value) and lo <= value <= hi):
                raise InputError(
                    f"expected a number in [{lo:g}, {hi:g}], got {value!r}", field=name
                )
        unit_open = {"alpha": self.alpha, "p_thresh": self.p_thresh}
        for name, value in unit_open.items():
            if not (_is_real(value) and 0.0 < value < 1.0):
                raise InputError(f"expected a number in (0, 1), got {value!r}", field=name)
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


#: Closed ranges of the physical parameters: wide enough for any real set-up, narrow enough
#: that no computation downstream overflows or runs for ever.
_RANGES: dict[str, tuple[float, float]] = {
    "beta": (1e-6, 1e3),
    "rotation_weight": (0.0, 10.0),
    "sigma": (1e-9, 10.0),
    "v_max": (1e-3, 10.0),
    "dt": (1e-4, 10.0),
}


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)
