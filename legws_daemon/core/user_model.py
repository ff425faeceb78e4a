"""The user model of method.md §2, written once.

The (simulated) user pushes the stick toward the goal with Gaussian velocity noise:
``u = pi_h(x, g) + eps / v_max``, ``pi_h(x, g) = (p_g - p) / |p_g - p|``,
``eps ~ N(0, sigma^2 I)``; the robot moves at ``v_max * u`` with ``|u|`` clipped to 1. The
certificate's model does not clip; the robot (and the stand-in) does. Used by the
certificate's Monte Carlo check (batched over trials), the simulated user of ``legws eval``,
the demos and ``legws joystick sim-user``.

:class:`SimulatedUser` generalises it to the operators of method.md §10 (speed, AR(1)
noise, bias, quantised steering: :class:`~legws_daemon.core.operator.OperatorModel`) and to
users who depart from any such model (idle ticks, heavy-tailed noise, a reaction delay).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, safe_unit
from legws_daemon.core.operator import OperatorModel, mean_deflection
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError


def deflection(position: ArrayLike, target: ArrayLike, noise: ArrayLike) -> FloatArray:
    """``pi_h(x, g) + noise`` along the last axis (any leading shape); ``noise`` is already
    in deflection units (``eps / v_max``). Zero pull when the position is on the target."""
    p = np.asarray(position, dtype=np.float64)
    pull = safe_unit(np.asarray(target, dtype=np.float64) - p)
    return np.asarray(pull + np.asarray(noise, dtype=np.float64), np.float64)


def noise(
    rng: np.random.Generator, shape: tuple[int, ...], sigma: float, v_max: float
) -> FloatArray:
    """Gaussian velocity noise ``eps / v_max`` in deflection units, ``shape + (3,)``."""
    return rng.standard_normal((*shape, 3)) * (sigma / v_max)


def clip_unit(u: ArrayLike) -> FloatArray:
    """Deflections scaled down to norm 1 where longer (direction kept), along the last axis:
    the robot's speed clip ``|v| <= v_max``."""
    arr = np.asarray(u, dtype=np.float64)
    norm = np.sqrt(np.einsum("...i,...i->...", arr, arr))[..., None]
    return np.asarray(arr / np.maximum(norm, 1.0), dtype=np.float64)


# --- simulated operators (method.md §10) --------------------------------------------------


@dataclass(frozen=True, slots=True)
class SimulatedUser:
    """A simulated operator: the model ``O`` it follows and how the simulation may depart
    from that model (the ways real users differ that the model does not describe).

    Attributes:
        operator: the model ``O`` (method.md §10); section 2's user is
            :meth:`OperatorModel.paper`.
        clip: the robot's clip ``|u| <= 1`` (the model's certificate does not clip).
        idle: the chance of an idle tick (the stick let go: ``u = 0``), drawn per tick.
        tails: Student-t noise with this many degrees of freedom (> 2) in place of the
            Gaussian, scaled to the same variance (``None``: Gaussian).
        delay: a reaction delay in ticks: the aim is taken from where the EE was this many
            ticks ago.
    """

    operator: OperatorModel
    clip: bool = False
    idle: float = 0.0
    tails: float | None = None
    delay: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.idle < 1.0:
            raise InputError(f"expected a chance in [0, 1), got {self.idle!r}", field="idle")
        if self.tails is not None and not (math.isfinite(self.tails) and self.tails > 2.0):
            raise InputError(
                f"expected more than 2 degrees of freedom, got {self.tails!r}", field="tails"
            )
        if not 0 <= self.delay <= 100:
            raise InputError(f"expected 0 to 100 ticks, got {self.delay!r}", field="delay")

    @classmethod
    def paper(cls, params: Params, clip: bool = False) -> SimulatedUser:
        """Section 2's user (with the robot's clip when ``clip``)."""
        return cls(OperatorModel.paper(params), clip=clip)

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...], v_max: float) -> FloatArray:
        """One tick's innovations ``w_t / v_max`` ``shape + (3,)``, deflection units."""
        scale = self.operator.sigma / v_max
        if self.tails is None:
            return noise(rng, shape, self.operator.sigma, v_max)
        df = self.tails
        return rng.standard_t(df, (*shape, 3)) * (scale * math.sqrt((df - 2.0) / df))


class OperatorNoise:
    """The AR(1) noise of an operator per axis, one tick at a time: ``e_0 = w_0`` (the
    stationary start), then ``e_t = rho e_{t-1} + sqrt(1 - rho^2) w_t``. With ``rho = 0``
    it is the innovations themselves, exactly."""

    def __init__(self, rho: float) -> None:
        self.rho = rho
        self._gain = math.sqrt(1.0 - rho * rho)
        self.state: FloatArray | None = None

    def step(self, w: FloatArray) -> FloatArray:
        if self.state is None or self.rho == 0.0:
            self.state = w
        else:
            self.state = self.rho * self.state + self._gain * w
        return self.state


class OperatorStick:
    """A simulated operator's hand on the stick, one deflection at a time: ``u = mu(x, g) +
    e / v_max`` (:class:`SimulatedUser`'s departures included), clipped to ``|u| <= 1`` when
    the user clips (a real stick cannot leave its rim).

    The AR(1) noise runs in continuous time with the correlation ``rho`` per control period
    ``dt``: a deflection ``h`` seconds after the last one has ``e <- rho^(h/dt) e +
    sqrt(1 - rho^(2h/dt)) w``, so a publisher faster or slower than the daemon's loop still
    shows the model's ``rho`` at the daemon's ticks (``h = dt`` is one step of the model).
    The reaction delay is in control periods of the positions given.

    Args:
        user: who steers.
        params: ``v_max`` and ``dt``.
        rng: the random stream.
    """

    def __init__(self, user: SimulatedUser, params: Params, rng: np.random.Generator) -> None:
        self.user = user
        self.params = params
        self.rng = rng
        self._e: FloatArray | None = None
        self._seen: list[FloatArray] = []

    def reset(self) -> None:
        """A new reach: the noise starts afresh (stationary) and the delay forgets."""
        self._e = None
        self._seen.clear()

    def deflection(
        self, position: ArrayLike, target: ArrayLike, elapsed: float | None = None
    ) -> FloatArray:
        """The deflection now, ``elapsed`` seconds after the last (default one period)."""
        user, params = self.user, self.params
        h = params.dt if elapsed is None else max(float(elapsed), 0.0)
        w = user.draw(self.rng, (), params.v_max)
        rho = user.operator.rho
        if self._e is None or rho == 0.0:
            self._e = w
        else:
            keep = rho ** (h / params.dt)
            self._e = keep * self._e + math.sqrt(max(1.0 - keep * keep, 0.0)) * w
        here = np.asarray(position, dtype=np.float64)
        self._seen.append(here)
        if len(self._seen) > user.delay + 1:
            self._seen.pop(0)
        u = mean_deflection(self._seen[0], target, user.operator) + self._e
        if user.idle and self.rng.random() < user.idle:
            u = np.zeros(3)
        return clip_unit(u) if user.clip else np.asarray(u, dtype=np.float64)
