"""The user model of method.md §2, written once.

The (simulated) user pushes the stick toward the goal with Gaussian velocity noise:
``u = pi_h(x, g) + eps / v_max``, ``pi_h(x, g) = (p_g - p) / |p_g - p|``,
``eps ~ N(0, sigma^2 I)``; the robot moves at ``v_max * u`` with ``|u|`` clipped to 1. The
certificate's model does not clip; the robot (and the stand-in) does. Used by the
certificate's Monte Carlo check (batched over trials), the simulated user of ``legws eval``,
the demos and ``legws joystick sim-user``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, safe_unit


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
