"""The guard of a person's certificates against their linearisation (method.md §10).

Sections 4 and 9 take the margin ``f(x) = beta (C_j(x) - C_i(x))`` at the noisy position
``x ~ N(pbar, Sigma)`` as Gaussian with mean ``f(pbar)`` and variance ``grad^T Sigma grad``
at the nominal. That holds while the spread is small against the distances to the goals.
A correlated operator (rho 0.8 and above) spreads over centimetres, as far as the nominal
still is from its goal near the horizon, and there the margin is neither centred nor
narrow (on a breakfast layout at rho 0.95 the simulated margin's mean was -0.09 where the
linearisation said 0.16, its standard deviation three times the linearised one), and the
grid measured certified goals that failed their promise. The guard replaces both by
bounds:

* **mean**: only ``C_i``'s distance ``|x - p_i|`` is convex against the margin; by Jensen,
  ``E|x - p_i| <= sqrt(r_i^2 + tr Sigma')`` with ``r_i = |pbar - p_i|``, so the mean margin
  is at least ``f(pbar) - beta (sqrt(r_i^2 + tr Sigma') - r_i) / S_i`` (``C_j``'s convexity
  only raises it: left out);
* **spread**: the Gaussian Poincaré inequality ``Var f(x) <= E[grad f^T Sigma grad f]``
  with ``grad f(x) = beta (a + Delta(x))`` and ``|Delta(x)| <= c |x - pbar|``,
  ``c = 2 (1/(r_i S_i) + 1/(r_j S_j))`` (a unit vector ``(x - p)/|x - p|`` moves by at most
  ``2 |x - pbar| / |pbar - p|``): the linearised variance plus
  ``beta^2 lambda_max' c^2 tr Sigma'`` (the cross term, of higher order, left out), and
  never more than ``beta^2 lambda_max (1/S_i + 1/S_j)^2``, the largest gradient there is.

``S_g`` is the cost's normaliser (``D`` for dragan, ``d(x0, g)`` for ratio); ``Sigma`` the
open-loop covariance of the position after ``t`` steps, ``(v_max dt)^2 S_rho(t) C`` with
``C`` the per-step covariance of the deflection (``lambda_max = (v_max dt)^2 S_rho(t)
widest^2``, ``tr Sigma = (v_max dt)^2 S_rho(t) tr C``). ``Sigma'`` is the spread that is
left of it closing on the goal, ``Sigma r_i / d_i`` (``d_i = |p_i - p0|``): a person aims at
the goal from where the arm is, so what drifted across the way shrinks with the distance
still to go (for white noise the position is a Brownian bridge pinned at the goal, whose
variance at a remaining share ``r/d`` of the way is the open loop's times ``r/d``); without
it the guard would take the open loop's centimetres for the last millimetres of a reach,
and withdraw half of M = 8's commit certificates at rho 0, which the grid had measured
honest. Both
corrections vanish as the spread shrinks. The guard applies to the certificates of an
operator with the robot's clip (what the daemon certifies for a person); section 2's model
as written keeps sections 4 and 9 exactly (the paper's numbers); the search's surrogates R
and T are not guarded.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.operator import UserMotion

#: A point this close to a goal has no direction to it (as core.commit), m.
_COINCIDENT = 1e-12


def spread_trace(user: UserMotion, straight: bool) -> float:
    """``tr C`` of one step's deflection covariance (deflection units²): along the way and
    twice across it on a straight nominal, else the widest on every axis."""
    if user.isotropic:
        return 3.0 * user.along**2
    if straight:
        return user.along**2 + 2.0 * user.across**2
    return 3.0 * user.widest**2


def guarded(
    margin: ArrayLike,
    sd: ArrayLike,
    r_true: ArrayLike,
    r_alt: ArrayLike,
    start: ArrayLike,
    inv_s_true: ArrayLike,
    inv_s_alt: ArrayLike,
    pos_var: ArrayLike,
    widest: float,
    trace: float,
    beta: float,
) -> tuple[FloatArray, FloatArray]:
    """``(mean bound, sd bound)`` of the margins (broadcast arrays): ``margin`` and ``sd``
    the linearised ones, ``r_true``/``r_alt`` the nominal's distances to the true goal and
    the alternative, ``start`` the true goal's distance from the start (the bridge's
    ``r_i / d_i``), ``inv_s_*`` the cost normalisers' inverses, ``pos_var`` ``(v_max dt)^2
    S_rho(t)`` (m² per deflection unit²), ``widest`` and ``trace`` of the per-step
    covariance (:func:`spread_trace`)."""
    r_i = np.asarray(r_true, dtype=np.float64)
    r_j = np.asarray(r_alt, dtype=np.float64)
    v = np.asarray(pos_var, dtype=np.float64)
    inv_si, inv_sj = np.asarray(inv_s_true), np.asarray(inv_s_alt)
    bridged = v * np.clip(r_i / np.asarray(start), 0.0, 1.0)
    spread2 = bridged * trace  # E|x - pbar|^2 closing on the goal
    drop = beta * inv_si * (np.sqrt(r_i * r_i + spread2) - r_i)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_ri = np.where(r_i > _COINCIDENT, 1.0 / np.where(r_i > _COINCIDENT, r_i, 1.0), np.inf)
        inv_rj = np.where(r_j > _COINCIDENT, 1.0 / np.where(r_j > _COINCIDENT, r_j, 1.0), np.inf)
        c = 2.0 * (inv_si * inv_ri + inv_sj * inv_rj)
        extra = np.where(
            spread2 > 0.0, beta * np.sqrt(bridged) * widest * c * np.sqrt(spread2), 0.0
        )
    cap = beta * np.sqrt(v) * widest * (inv_si + inv_sj)  # the largest gradient, open loop
    sd_lin = np.asarray(sd, dtype=np.float64)
    bound = np.minimum(cap, np.sqrt(sd_lin * sd_lin + extra * extra))
    return (
        np.asarray(np.asarray(margin, dtype=np.float64) - drop, dtype=np.float64),
        np.asarray(bound, dtype=np.float64),
    )
