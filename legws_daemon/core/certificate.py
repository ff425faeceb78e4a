"""The trajectory-margin slack certificate (method.md section 4), batched over layouts.

For every true goal ``i`` and alternative ``j != i``:

1. nominal straight line from ``p0`` toward ``p_i`` at ``v_max``, orientation held at
   ``R0``, for ``T_i = ceil(eta |p_i - p0| / (v_max dt))`` steps, ending at
   ``pbar_i = p0 + L_i unit(p_i - p0)`` with ``L_i = T_i v_max dt``;
2. margin ``m_ij = beta (C_j - C_i)`` at ``pbar_i`` and ``L_i``;
3. sensitivity ``a_ij = d(C_j - C_i)/d pbar_i`` (``L_i`` held fixed);
4. variance ``v_ij = beta^2 a_ij^T Sigma a_ij`` with ``Sigma = T_i sigma^2 dt^2 I``;
5. slack ``s_ij = m_ij - Phi^-1(1 - alpha / (M - 1)) sqrt(v_ij)``;
6. objective ``J = min_i min_{j != i} s_ij``.

``J > 0`` certifies ``P(argmax at the horizon = g_i) >= 1 - alpha`` for every goal under
the model's assumptions (Gaussian, linearised, straight-line nominal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ndtri

from legws_daemon.core.costs import path_costs
from legws_daemon.core.geometry import FloatArray, IntArray, safe_unit, symmetric_angle
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.guard import guarded, spread_trace
from legws_daemon.core.operator import (
    MAX_HORIZON_STEPS,
    OperatorModel,
    UserMotion,
    ar1_sum_variance,
    horizon_steps,
    nominal_path,
)
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError

__all__ = ["MAX_HORIZON_STEPS", "horizon_steps"]  # re-exported for their older importers


@dataclass(frozen=True, slots=True)
class CertificateBatch:
    """Certificate of B layouts with M goals each.

    Attributes:
        margin: ``(B, M, M)``; ``[b, i, j]`` is the margin of alternative ``j`` when ``i``
            is the true goal. The diagonal is 0.
        variance: ``(B, M, M)`` margin variances (diagonal 0).
        slack: ``(B, M, M)`` slacks (diagonal ``+inf``).
        steps: ``(B, M)`` horizon steps ``T_i`` per true goal.
        objective: ``(B,)`` the layout objective ``J``.
        quantile: ``Phi^-1(1 - alpha / (M - 1))``.
    """

    margin: FloatArray
    variance: FloatArray
    slack: FloatArray
    steps: IntArray
    objective: FloatArray
    quantile: float


@dataclass(frozen=True, slots=True)
class NominalTerms:
    """Intermediate quantities of the certificate, exposed for tests and diagnostics."""

    steps: IntArray  # (B, M)
    length: FloatArray  # (B, M) nominal path length L_i
    endpoint: FloatArray  # (B, M, 3) nominal end pbar_i
    dist_start: FloatArray  # (B, M) d(x0, g_j)
    rot_term: FloatArray  # (B, M) lambda_R * angle(R0, R_j)
    costs: FloatArray  # (B, M, M) C_j at the nominal end of true goal i
    sensitivity: FloatArray  # (B, M, M, 3) a_ij
    distances: FloatArray  # (B, M, M) |pbar_i - p_j|
    trans0: FloatArray  # (B, M) |p_i - p0|


def upper_quantile(tail: ArrayLike) -> FloatArray | float:
    """``Phi^-1(1 - tail)``, the standard normal quantile with ``tail`` above it, computed as
    ``-Phi^-1(tail)``: exact for any tail down to the smallest double (``1 - tail`` rounds
    to 1, and the quantile to infinity, once ``tail`` is below ~1e-16)."""
    z = -ndtri(np.asarray(tail, dtype=np.float64))
    return float(z) if np.ndim(z) == 0 else np.asarray(z, dtype=np.float64)


def goal_arrays(
    p0: ArrayLike, goal_positions: ArrayLike, goal_rotations: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``p0``, goal positions ``(B, M>=2, 3)`` and rotations ``(B, M, 3, 3)`` as float arrays.

    Raises:
        InputError: on other shapes.
    """
    p = np.asarray(p0, dtype=np.float64)
    pg = np.asarray(goal_positions, dtype=np.float64)
    Rg = np.asarray(goal_rotations, dtype=np.float64)
    if pg.ndim != 3 or pg.shape[-1] != 3 or pg.shape[1] < 2:
        raise InputError(f"expected goal positions of shape (B, M>=2, 3), got {pg.shape}")
    if Rg.shape != (*pg.shape[:2], 3, 3):
        raise InputError(f"expected goal rotations of shape {(*pg.shape[:2], 3, 3)}")
    return p, pg, Rg


def start_terms(
    p0: FloatArray,
    R0: ArrayLike,
    pg: FloatArray,
    Rg: FloatArray,
    symmetry: ArrayLike,
    params: Params,
) -> tuple[FloatArray, FloatArray]:
    """``(|p_g - p0|, lambda_R angle(R0, R_g))`` of goals ``(..., M, 3)``: the start
    distance ``d(x0, g)`` of method.md §2 is their sum; the rotation term stays constant
    along a nominal (the user's deflection is translational)."""
    delta = pg - p0
    trans0 = np.sqrt(np.einsum("...i,...i->...", delta, delta))
    rot = params.rotation_weight * symmetric_angle(R0, Rg, symmetry)
    return np.asarray(trans0, dtype=np.float64), np.asarray(rot, dtype=np.float64)


def nominal_terms(
    p0: ArrayLike,
    R0: ArrayLike,
    goal_positions: ArrayLike,
    goal_rotations: ArrayLike,
    symmetry: ArrayLike,
    params: Params,
    operator: OperatorModel | None = None,
    user: UserMotion | None = None,
) -> NominalTerms:
    """Nominal trajectories, costs and sensitivities for a batch of layouts.

    Args:
        p0: ``(3,)`` start position.
        R0: ``(3, 3)`` start orientation.
        goal_positions: ``(B, M, 3)`` grasp positions.
        goal_rotations: ``(B, M, 3, 3)`` grasp orientations.
        symmetry: ``(M,)`` or ``(B, M)`` symmetry orders.
        params: model parameters (``cost`` selects the form).
        operator: who steers (method.md §10; default section 2's user): the nominal follows
            its aim, bias and steering.
        user: the per-step moments of its deflection (default: the operator's as written,
            :meth:`OperatorModel.motion`); only ``speed`` matters here.
    """
    p0, pg, Rg = goal_arrays(p0, goal_positions, goal_rotations)
    operator, user = who_steers(params, operator, user)
    step = user.speed * params.v_max * params.dt

    trans0, rot_term = start_terms(p0, R0, pg, Rg, symmetry, params)  # (B, M) each
    delta = pg - p0  # (B, M, 3)
    dist_start = trans0 + rot_term
    steps = horizon_steps(trans0, params, user.speed)
    length = np.asarray(steps * step, dtype=np.float64)
    if operator.straight:
        endpoint = p0 + length[..., None] * safe_unit(delta)  # (B, M, 3)
    else:  # the closed loop's own path, at its horizon
        path = nominal_path(p0, pg, operator, user, params, int(steps.max()))
        endpoint = np.take_along_axis(path, (steps - 1)[..., None, None], axis=-2)[..., 0, :]

    # Distances from the nominal end of true goal i to every goal j.
    diff = endpoint[:, :, None, :] - pg[:, None, :, :]  # (B, i, j, 3)
    trans_now = np.sqrt(np.einsum("bijk,bijk->bij", diff, diff))
    dist_now = trans_now + rot_term[:, None, :]
    costs = path_costs(length, dist_now, dist_start[:, None, :], params.cost)  # (B, i, j)

    unit = safe_unit(diff)  # d|pbar_i - p_j| / d pbar_i
    grad_c = unit / cost_scales(dist_start, params)[:, None, :, None]
    diag = np.einsum("biik->bik", grad_c)  # gradient of C_i at pbar_i
    sensitivity = grad_c - diag[:, :, None, :]
    return NominalTerms(
        steps, length, endpoint, dist_start, rot_term, costs, sensitivity, trans_now, trans0
    )


def cost_scales(dist_start: FloatArray, params: Params) -> FloatArray:
    """The cost's normaliser per goal ``(B, M)`` from the start distances ``d(x0, g)``:
    ``D = mean_g d(x0, g)`` (dragan) or ``d(x0, g)`` itself (ratio)."""
    b, m = dist_start.shape
    if params.cost == "dragan":
        return np.broadcast_to(np.mean(dist_start, axis=1)[:, None], (b, m))
    return dist_start


def who_steers(
    params: Params, operator: OperatorModel | None, user: UserMotion | None
) -> tuple[OperatorModel, UserMotion]:
    """The operator (default: section 2's user of ``params``) and the per-step moments of
    its deflection (default: the operator's as written, unclipped)."""
    op = operator if operator is not None else OperatorModel.paper(params)
    return op, user if user is not None else op.motion(params)


def step_spread(sensitivity: FloatArray, way: FloatArray | None, user: UserMotion) -> FloatArray:
    """``a^T C a`` of one step's deflection covariance ``C`` (deflection units²) for
    sensitivities ``(..., 3)``: isotropic, ``along`` on the unit way ``(..., 3)`` and
    ``across`` off it when the nominal keeps its direction (``way``), else the wider of
    the two on every axis (a bound: the direction turns along a curved nominal)."""
    a2 = np.einsum("...k,...k->...", sensitivity, sensitivity)
    if user.isotropic:
        return np.asarray(user.along**2 * a2, dtype=np.float64)
    if way is None:
        return np.asarray(user.widest**2 * a2, dtype=np.float64)
    a_u = np.einsum("...k,...k->...", sensitivity, way)
    return np.asarray(user.across**2 * a2 + (user.along**2 - user.across**2) * a_u**2, np.float64)


def certify_batch(
    p0: ArrayLike,
    R0: ArrayLike,
    goal_positions: ArrayLike,
    goal_rotations: ArrayLike,
    symmetry: ArrayLike,
    params: Params,
    operator: OperatorModel | None = None,
    user: UserMotion | None = None,
) -> CertificateBatch:
    """Certificate of B layouts at once; see :func:`nominal_terms` for the arguments.

    Under an operator (method.md §10) the margin variance is
    ``beta^2 a^T C a S_rho(T) v_max^2 dt^2``: ``C`` the per-step covariance of its
    deflection (:func:`step_spread`), ``S_rho(T)`` the variance of a sum of ``T`` AR(1)
    terms (:func:`~legws_daemon.core.operator.ar1_sum_variance`). For section 2's user this
    is section 4's ``beta^2 |a|^2 T sigma^2 dt^2`` exactly. With moments other than the
    operator's as written (the robot's clip: a person's certificate) margins and variances
    are guarded against the linearisation (:mod:`~legws_daemon.core.guard`)."""
    operator, user = who_steers(params, operator, user)
    t = nominal_terms(p0, R0, goal_positions, goal_rotations, symmetry, params, operator, user)
    m = t.costs.shape[1]
    c_true = np.einsum("bii->bi", t.costs)
    margin = params.beta * (t.costs - c_true[:, :, None])
    sums = ar1_sum_variance(t.steps, user.rho)  # (B, M)
    if user == operator.motion(params):
        # the model as written: section 4's variance (bit for bit for section 2's user)
        a2 = np.einsum("bijk,bijk->bij", t.sensitivity, t.sensitivity)
        variance = params.beta**2 * (sums * (operator.sigma * params.dt) ** 2)[:, :, None] * a2
    else:
        way = None
        if operator.straight:  # the way to each true goal i, for every alternative j
            start = np.asarray(p0, dtype=np.float64)
            way = np.broadcast_to(safe_unit(t.endpoint - start)[:, :, None, :], t.sensitivity.shape)
        spread = step_spread(t.sensitivity, way, user)
        per_step = (params.v_max * params.dt) ** 2
        variance = params.beta**2 * per_step * sums[:, :, None] * spread
        margin, variance = _guarded_pairs(
            t, margin, variance, per_step * sums, operator, user, params
        )
    quantile = float(upper_quantile(params.alpha / (m - 1)))
    slack = margin - quantile * np.sqrt(variance)
    eye = np.eye(m, dtype=bool)
    margin[:, eye] = 0.0
    variance[:, eye] = 0.0
    slack[:, eye] = np.inf
    objective = slack.min(axis=(1, 2))
    return CertificateBatch(margin, variance, slack, t.steps, objective, quantile)


def _guarded_pairs(
    t: NominalTerms,
    margin: FloatArray,
    variance: FloatArray,
    pos_var: FloatArray,
    operator: OperatorModel,
    user: UserMotion,
    params: Params,
) -> tuple[FloatArray, FloatArray]:
    """Margins and variances ``(B, i, j)`` at the horizon under :func:`~.guard.guarded`
    (``pos_var``: ``(v_max dt)^2 S_rho(T_i)``, ``(B, i)``)."""
    inv_s = 1.0 / cost_scales(t.dist_start, params)
    g_margin, g_sd = guarded(
        margin, np.sqrt(variance), np.einsum("bii->bi", t.distances)[:, :, None], t.distances,
        t.trans0[:, :, None], inv_s[:, :, None], inv_s[:, None, :], pos_var[:, :, None],
        user.widest, spread_trace(user, operator.straight), params.beta,
    )  # fmt: skip
    return g_margin, g_sd**2


@dataclass(frozen=True, slots=True)
class PairCertificate:
    true: str
    other: str
    margin: float
    variance: float
    slack: float
    steps: int


@dataclass(frozen=True, slots=True)
class Certificate:
    """Certificate of one goal set, with every ordered pair."""

    objective: float
    pairs: tuple[PairCertificate, ...]
    quantile: float

    @property
    def certified(self) -> bool:
        return self.objective > 0.0


def certify(
    goals: GoalSet,
    params: Params,
    operator: OperatorModel | None = None,
    user: UserMotion | None = None,
) -> Certificate:
    """Certificate of one goal set: all ``M (M - 1)`` ordered pairs and the objective (for
    ``operator`` with the moments ``user``: :func:`certify_batch`)."""
    batch = certify_batch(
        goals.x0.position,
        goals.x0.rotation,
        goals.positions[None],
        goals.rotations[None],
        goals.symmetry,
        params,
        operator,
        user,
    )
    pairs = tuple(
        PairCertificate(
            true=goals.names[i],
            other=goals.names[j],
            margin=float(batch.margin[0, i, j]),
            variance=float(batch.variance[0, i, j]),
            slack=float(batch.slack[0, i, j]),
            steps=int(batch.steps[0, i]),
        )
        for i in range(goals.m)
        for j in range(goals.m)
        if i != j
    )
    return Certificate(float(batch.objective[0]), pairs, batch.quantile)
