"""The two path-efficiency cost forms of the observer (method.md section 3) and the posterior.

Both take the path length ``L`` so far, the SE(3) distances ``d(x_t, g)`` from the current
pose and ``d(x_0, g)`` from the start pose, and return ``C(xi_0:t, g)`` per goal:

* ``dragan``: ``(L + d(x_t, g) - d(x_0, g)) / D`` with ``D = mean_g d(x_0, g)``;
* ``ratio``:  ``(L + d(x_t, g)) / d(x_0, g)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.params import COST_FORMS, CostForm
from legws_daemon.errors import InputError


def path_costs(
    length: ArrayLike, dist_now: ArrayLike, dist_start: ArrayLike, cost: CostForm
) -> FloatArray:
    """Costs ``(..., M)``.

    Args:
        length: path length so far, shape ``(...)``.
        dist_now: ``d(x_t, g)``, shape ``(..., M)``.
        dist_start: ``d(x_0, g)``, shape ``(..., M)`` (broadcast against ``dist_now``).
        cost: ``"dragan"`` or ``"ratio"``.
    """
    L = np.asarray(length, dtype=np.float64)[..., None]
    dn = np.asarray(dist_now, dtype=np.float64)
    d0 = np.asarray(dist_start, dtype=np.float64)
    if cost == "dragan":
        scale = np.mean(d0, axis=-1, keepdims=True)
        return np.asarray((L + dn - d0) / scale, dtype=np.float64)
    if cost == "ratio":
        return np.asarray((L + dn) / d0, dtype=np.float64)
    raise InputError(f"unknown cost form {cost!r}; known: {', '.join(COST_FORMS)}", field="cost")


def posterior(costs: ArrayLike, beta: float) -> FloatArray:
    """Boltzmann posterior ``P(g) ∝ exp(-beta C_g)`` with a uniform prior, over the last axis."""
    logits = -beta * np.asarray(costs, dtype=np.float64)
    logits = logits - np.max(logits, axis=-1, keepdims=True)
    p = np.exp(logits)
    return np.asarray(p / np.sum(p, axis=-1, keepdims=True), dtype=np.float64)
