"""The commit certificate (method.md section 9), batched over layouts.

Section 4's slack certifies the observer's *argmax* at three quarters of the way; a person
is helped only when the observer **commits** (posterior ``>= p_thresh``) before they
arrive. For each true goal ``i`` this module follows the nominal of section 4 step by step
up to arrival, ``T_a = floor(|p_i - p0| / (v_max dt))``:

* at step ``t`` the nominal is ``pbar_t = p0 + t v_max dt u_i``, ``L_t = t v_max dt``, with
  margins ``m_ij(t) = beta (C_j - C_i)``, sensitivities ``a_ij(t)`` and variances
  ``v_ij(t) = beta^2 |a_ij(t)|^2 t sigma^2 dt^2`` exactly as in section 4;
* commit slack ``c(t) = min_j [m_ij(t) - z_c sqrt(v_ij(t))] - tau_c`` with
  ``tau_c = ln((M-1) p / (1-p))`` and ``z_c = Phi^-1(1 - alpha / (2 (M-1)))``: when every
  margin exceeds ``tau_c`` the posterior of ``i`` is at least ``p``;
* the certified commit step ``t_c`` is the first ``t`` with ``c(t) >= 0``; its fraction of
  the way ``kappa = t_hat / T_a`` interpolates the zero crossing (``c(0) = -tau_c``);
* wrong-commit slack ``w = min_{t <= t_end} min_j [m_ij(t) + tau_w - z_w sqrt(v_ij(t))]``
  with ``tau_w = ln(p / (1-p))`` and ``z_w = Phi^-1(1 - alpha / (2 (M-1) t_end))`` (union
  bound over steps and alternatives), ``t_end = t_c`` or ``T_a``;
* the goal is *commit-certified* when ``t_c`` exists and ``w >= 0``: then
  ``P(the first commit is on i and comes at or before t_c) >= 1 - alpha`` under the model
  of section 2. Otherwise ``kappa = 1 + max(0, -c(T_a)) + max(0, -w)``;
* the layout objective is ``K = max_i kappa_i``: ``K <= 1`` certifies every goal, smaller
  is earlier.

Two forms of the commit slack share everything else. ``"min"`` is section 9's (the floor):
each alternative must clear ``tau_c``, i.e. the budget ``(1-p)/p`` is split evenly over the
``M-1`` alternatives. ``"sum"`` treats the sum exactly: with the same per-alternative lower
bounds ``l_ij = m_ij - z_c sqrt(v_ij)`` (all hold at once with probability
``>= 1 - alpha/2``), ``P(g*) >= p`` as soon as ``sum_j exp(-l_ij) <= (1-p)/p``, so
``c(t) = ln((1-p)/p) - ln sum_j exp(-l_ij(t))``. It is never below the ``min`` form's
(equal when every alternative is equally close), starts at the same ``c(0) = -tau_c`` and
keeps the same promise under the same union bound; an alternative that is far away no
longer costs the close ones their share of the budget.

The robot clips the commanded speed to ``v_max`` (method.md §2), which the section's model
does not: a clipped noisy user advances only ~0.67 ``v_max`` toward the goal per step, with
less lateral noise per metre. :class:`UserMotion` carries the per-step moments of the
deflection along the way and across it; :func:`clipped_user` computes them for the robot's
clip, and the same computation then certifies the commit in the robot's own time
(``legws certify --commit --clip-speed``). The default is section 9's unclipped user
exactly (mean 1, standard deviation ``sigma / v_max`` on every axis).

**Under an operator** (method.md §10, :mod:`~legws_daemon.core.operator`) the same
computation runs along that operator's nominal — straight at its speed ``s`` without bias
and with free steering (the closed form above), else its noise-free closed loop with bias
and quantised steering (:func:`_path_terms`) — with ``T_a`` the first step closer than
``v_max dt`` to the goal, and every variance's ``t`` replaced by ``S_rho(t)``, the variance
of a sum of ``t`` AR(1) terms. Section 2's user gives section 9 exactly (bit for bit).
With the robot's clip (a person's certificate, what the daemon shows) every margin and
standard deviation is guarded against the linearisation (:mod:`~legws_daemon.core.guard`:
the mean lowered by Jensen's bound, the spread raised by Poincaré's) before the slacks;
the search surrogates (:func:`commit_chance_batch`, :func:`commit_time_batch`) keep the
linearised terms.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr

from legws_daemon.core.certificate import (
    cost_scales,
    goal_arrays,
    start_terms,
    step_spread,
    upper_quantile,
    who_steers,
)
from legws_daemon.core.costs import path_costs
from legws_daemon.core.geometry import FloatArray, IntArray, safe_unit
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.guard import guarded, spread_trace
from legws_daemon.core.operator import (
    OperatorModel,
    UserMotion,
    ar1_sum_variance,
    arrival_steps,
    nominal_path,
    nominal_steps,
)
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError

__all__ = ["UserMotion", "arrival_steps"]  # re-exported for their older importers

#: Forms of the commit slack: section 9's even split of the budget, or the exact sum.
COMMIT_FORMS = ("min", "sum")

#: Elements of the largest intermediate array ``(B, M, T, M)`` built at once; batches are
#: split by layouts to stay below it (~32 MB of float64 each), and one layout whose
#: ``M x T x M`` is larger by its true goals (rows), down to one row of ``T x M`` elements
#: (at most 64 goals x 100,000 steps: 51 MB): memory stays bounded whatever the horizon. A
#: curved nominal (an operator's bias or quantised steering) builds ``(B, M, T, M, 3)``
#: arrays and takes a quarter of it.
CHUNK_ELEMENTS = 4_000_000
#: A nominal point this close to a goal coincides with it (its distance term has no
#: gradient), m.
_COINCIDENT = 1e-12


def unclipped_user(params: Params) -> UserMotion:
    """Section 2's model as the certificate takes it: ``u = e + eps / v_max``."""
    return OperatorModel.paper(params).motion(params)


def clipped_user(params: Params) -> UserMotion:
    """The moments of the robot's user: ``u = clip(e + eps / v_max)`` to norm 1 (method.md
    §2), by deterministic quadrature (:func:`~legws_daemon.core.operator.clipped_moments`)."""
    return OperatorModel.paper(params).motion(params, clip=True)


@dataclass(frozen=True, slots=True)
class CommitBatch:
    """Commit certificate of B layouts with M goals each.

    Attributes:
        fraction: ``(B, M)`` ``kappa`` per true goal (``<= 1`` when commit-certified).
        step: ``(B, M)`` the first step ``t_c`` with ``c(t) >= 0``; ``-1`` when none.
        arrival_steps: ``(B, M)`` ``T_a``.
        slack_at_arrival: ``(B, M)`` ``c(T_a)``.
        wrong_commit_slack: ``(B, M)`` ``w``.
        certified: ``(B, M)`` the goal's commit is certified.
        objective: ``(B,)`` ``K = max_i kappa_i``.
        count: ``(B,)`` commit-certified goals.
        thresholds: ``(tau_c, tau_w)``.
        quantile: ``z_c``.
        progress: ``(B, M)`` the promise in distance (method.md §10): the nominal's path
            length at ``t_c`` over ``|p_g* - p0|`` (``nan`` without a certified step).
        reachable: ``(B, M)`` the operator's nominal arrives (within 10^4 steps); an
            unreachable goal is not certified, its ``kappa`` is ``inf`` and its slacks
            ``nan``.
    """

    fraction: FloatArray
    step: IntArray
    arrival_steps: IntArray
    slack_at_arrival: FloatArray
    wrong_commit_slack: FloatArray
    certified: NDArray[np.bool_]
    objective: FloatArray
    count: IntArray
    thresholds: tuple[float, float]
    quantile: float
    progress: FloatArray
    reachable: NDArray[np.bool_]


def thresholds(m: int, p_thresh: float) -> tuple[float, float]:
    """``(tau_c, tau_w)``: every margin above ``tau_c`` gives ``P(g*) >= p``; a wrong commit
    on ``g`` needs its margin at or below ``-tau_w``."""
    odds = p_thresh / (1.0 - p_thresh)
    return math.log((m - 1) * odds), math.log(odds)


def commit_batch(
    p0: ArrayLike,
    R0: ArrayLike,
    goal_positions: ArrayLike,
    goal_rotations: ArrayLike,
    symmetry: ArrayLike,
    params: Params,
    user: UserMotion | None = None,
    form: str = "min",
    operator: OperatorModel | None = None,
) -> CommitBatch:
    """Commit certificate of B layouts at once (arguments as
    :func:`~legws_daemon.core.certificate.certify_batch`; ``operator``: who steers,
    method.md §10, default section 2's user; ``user``: the per-step moments of its
    deflection, default the operator's as written; ``form``: the commit slack's, ``"min"``
    of section 9 or the exact ``"sum"``)."""
    if form not in COMMIT_FORMS:
        raise InputError(
            f"unknown commit form {form!r}; known: {', '.join(COMMIT_FORMS)}",
            field="--commit-form",
        )
    bt = _Batch.of(p0, R0, goal_positions, goal_rotations, symmetry, params, operator, user)
    b, m = bt.pg.shape[:2]
    tau_c, tau_w = thresholds(m, params.p_thresh)
    z_c = float(upper_quantile(params.alpha / (2 * (m - 1))))

    fraction, step, c_arrival, w = (np.zeros((b, m)) for _ in range(4))
    for sl, rows in bt.pieces():
        fraction[sl, rows], step[sl, rows], c_arrival[sl, rows], w[sl, rows] = _chunk(
            bt.part(sl), params, form, tau_c, tau_w, z_c, rows
        )
    lost = ~bt.reachable
    fraction[lost], step[lost], c_arrival[lost], w[lost] = np.inf, -1, np.nan, np.nan
    step_i = np.asarray(step, dtype=np.int64)
    certified = (step_i > 0) & (w >= 0.0)
    progress = np.where(certified, step_i * bt.step_length / bt.trans0, np.nan)
    return CommitBatch(
        fraction=fraction,
        step=step_i,
        arrival_steps=np.where(bt.reachable, bt.t_a, 0),
        slack_at_arrival=c_arrival,
        wrong_commit_slack=w,
        certified=np.asarray(certified),
        objective=np.asarray(fraction.max(axis=1) if b else np.zeros(0), dtype=np.float64),
        count=np.asarray(certified.sum(axis=1), dtype=np.int64),
        thresholds=(tau_c, tau_w),
        quantile=z_c,
        progress=np.asarray(progress, dtype=np.float64),
        reachable=bt.reachable,
    )


@dataclass(frozen=True, slots=True)
class _Batch:
    """A batch's start, goals, who steers and each true goal's arrival (``t_a`` at least 1
    so that every row computes; ``reachable`` says whose arrival is real)."""

    p0: FloatArray
    pg: FloatArray  # (b, M, 3)
    rot_term: FloatArray  # (b, M)
    trans0: FloatArray  # (b, M)
    t_a: IntArray  # (b, M)
    reachable: NDArray[np.bool_]  # (b, M)
    operator: OperatorModel
    user: UserMotion
    step_length: float  # the nominal's advance per step, m
    guarded: bool  # the margins under core.guard (an operator with the robot's clip)

    @classmethod
    def of(
        cls,
        p0: ArrayLike,
        R0: ArrayLike,
        goal_positions: ArrayLike,
        goal_rotations: ArrayLike,
        symmetry: ArrayLike,
        params: Params,
        operator: OperatorModel | None,
        user: UserMotion | None,
    ) -> _Batch:
        op, motion = who_steers(params, operator, user)
        p0_, pg, Rg = goal_arrays(p0, goal_positions, goal_rotations)
        b, m = pg.shape[:2]
        sym = np.broadcast_to(np.asarray(symmetry), (b, m))
        trans0, rot_term = start_terms(p0_, R0, pg, Rg, sym, params)  # (B, M) each
        if op.straight:
            t_a = arrival_steps(trans0, params, motion.speed)
        else:
            t_a = nominal_steps(p0_, pg, op, motion, params)[0]
        reachable = np.asarray(t_a > 0)
        step = motion.speed * params.v_max * params.dt
        guard = motion != op.motion(params)
        return cls(
            p0_, pg, rot_term, trans0, np.maximum(t_a, 1), reachable, op, motion, step, guard
        )  # fmt: skip

    def part(self, sl: slice) -> _Batch:
        return replace(
            self, pg=self.pg[sl], rot_term=self.rot_term[sl], trans0=self.trans0[sl],
            t_a=self.t_a[sl], reachable=self.reachable[sl],
        )  # fmt: skip

    def pieces(self) -> Iterator[tuple[slice, slice]]:
        """:func:`_pieces` of the batch (a quarter of the elements for a curved nominal,
        whose arrays carry 3-vectors)."""
        limit = CHUNK_ELEMENTS if self.operator.straight else CHUNK_ELEMENTS // 4
        return _pieces(self.t_a, limit)


def _pieces(t_a: IntArray, limit: int | None = None) -> Iterator[tuple[slice, slice]]:
    """``(layouts, true goals)`` pieces of a batch whose ``(b, rows, T, M)`` arrays hold at
    most ``limit`` (:data:`CHUNK_ELEMENTS`) elements (at least one layout and one row
    each). Every row of a layout is computed on its own, so the pieces give exactly the
    unsplit result."""
    limit = CHUNK_ELEMENTS if limit is None else limit
    b, m = t_a.shape
    t_max = int(t_a.max()) if b else 1
    per_layout = m * m * t_max
    if per_layout <= limit:
        chunk = limit // per_layout
        for s in range(0, b, chunk):
            yield slice(s, s + chunk), slice(0, m)
        return
    rows = max(1, limit // (m * t_max))
    for s in range(b):
        for r in range(0, m, rows):
            yield slice(s, s + 1), slice(r, r + rows)


def commit_chance_batch(
    p0: ArrayLike,
    R0: ArrayLike,
    goal_positions: ArrayLike,
    goal_rotations: ArrayLike,
    symmetry: ArrayLike,
    params: Params,
    user: UserMotion | None = None,
    operator: OperatorModel | None = None,
) -> FloatArray:
    """Estimated chance that each goal's first commit comes before arrival, ``(B, M)``.

    Not a certificate: a smooth search surrogate of the *rate* a person sees, where the
    certificate (:func:`commit_batch`) bounds the worst goal. At each step ``t <= T_a`` the
    noise-free posterior slack ``c0(t) = ln((1-p)/p) - ln sum_j exp(-m_ij(t))`` is divided
    by the standard deviation of its linearisation, ``sum_j w_j sqrt(v_ij(t))`` with the
    softmax weights ``w_j ~ exp(-m_ij)`` of the alternatives; the chance is
    ``Phi(max_t c0(t) / sd(t))``. It ignores the correlation over steps (the real first
    passage is likelier) and the union over alternatives (less likely); measured against
    the Monte Carlo of :func:`~legws_daemon.core.montecarlo.simulate_commits` in the tests
    and in ``benchmarks/commit_ceiling.py``. A goal the operator does not reach gets 0.
    """
    bt = _Batch.of(p0, R0, goal_positions, goal_rotations, symmetry, params, operator, user)
    bt = replace(bt, guarded=False)  # a surrogate: the linearised terms (as the kernels)
    b, m = bt.pg.shape[:2]
    _, tau_w = thresholds(m, params.p_thresh)
    out = np.zeros((b, m))
    for sl, rows in bt.pieces():
        part = bt.part(sl)
        t, margin, sd = _terms(part, params, rows)
        others = _others(m, rows)
        c0, weight, total = _posterior_slack(np.where(others, margin, np.inf), tau_w)
        spread = (weight * np.where(others, sd, 0.0)).sum(axis=-1) / total  # 0 on the true goal
        z = c0 / np.maximum(spread, 1e-12)
        z = np.where(t[None, None, :] <= part.t_a[:, rows][:, :, None], z, -np.inf)
        out[sl, rows] = ndtr(z.max(axis=-1))
    out[~bt.reachable] = 0.0
    return np.asarray(out, dtype=np.float64)


def commit_time_batch(
    p0: ArrayLike,
    R0: ArrayLike,
    goal_positions: ArrayLike,
    goal_rotations: ArrayLike,
    symmetry: ArrayLike,
    params: Params,
    user: UserMotion | None = None,
    operator: OperatorModel | None = None,
) -> FloatArray:
    """Each goal's noise-free commit time in seconds, ``(B, M)``: when the posterior of the
    nominal reaches ``p`` (the zero crossing of ``c0(t)`` of :func:`commit_chance_batch`,
    interpolated between steps from ``c0(0) = -tau_c``), which is also the median commit
    time of that surrogate. A goal whose nominal never commits before arrival gets
    ``T_a dt (1 + max(0, -c0(T_a)))``: later than any commit, and worse the further from
    one; a goal the operator does not reach gets ``inf``. Not a certificate: the search
    surrogate of ``--objective time``."""
    bt = _Batch.of(p0, R0, goal_positions, goal_rotations, symmetry, params, operator, user)
    bt = replace(bt, guarded=False)  # a surrogate: the linearised terms (as the kernels)
    b, m = bt.pg.shape[:2]
    tau_c, tau_w = thresholds(m, params.p_thresh)
    out = np.zeros((b, m))
    for sl, rows in bt.pieces():
        part = bt.part(sl)
        t, margin, _ = _terms(part, params, rows)
        c0 = _posterior_slack(np.where(_others(m, rows), margin, np.inf), tau_w)[0]  # (b, i, T)
        t_rows = part.t_a[:, rows]
        c0 = np.where(t[None, None, :] <= t_rows[:, :, None], c0, -np.inf)
        has, _, crossing = _first_crossing(c0, tau_c)
        c_end = np.take_along_axis(c0, (t_rows - 1)[..., None], -1)[..., 0]
        late = t_rows * (1.0 + np.maximum(0.0, -c_end))
        out[sl, rows] = np.where(has, crossing, late) * params.dt
    out[~bt.reachable] = np.inf
    return np.asarray(out, dtype=np.float64)


def commit_time_estimate(
    goals: GoalSet, params: Params, operator: OperatorModel | None = None
) -> float:
    """``T``: the mean over the goals of :func:`commit_time_batch` for the robot's
    speed-clipped user (or ``operator`` with the robot's clip), seconds (the ``time``
    design objective of one goal set)."""
    return _goal_set_mean(commit_time_batch, goals, params, operator)


def commit_rate_estimate(
    goals: GoalSet, params: Params, operator: OperatorModel | None = None
) -> float:
    """``R``: the mean over the goals of :func:`commit_chance_batch` for the robot's
    speed-clipped user (or ``operator`` with the robot's clip; the ``rate`` design objective
    of one goal set)."""
    return _goal_set_mean(commit_chance_batch, goals, params, operator)


def _goal_set_mean(
    batch: Callable[..., FloatArray],
    goals: GoalSet,
    params: Params,
    operator: OperatorModel | None,
) -> float:
    """The mean over one goal set's goals of a batched estimate, with the robot's clip."""
    op = operator if operator is not None else OperatorModel.paper(params)
    values = batch(
        goals.x0.position, goals.x0.rotation, goals.positions[None], goals.rotations[None],
        goals.symmetry, params, op.motion(params, clip=True), op,
    )  # fmt: skip
    return float(values.mean())


def _others(m: int, rows: slice) -> NDArray[np.bool_]:
    """``(1, i, 1, j)``: goal ``j`` is an alternative of the true goal ``i`` in ``rows``."""
    return np.asarray(np.arange(m)[rows][:, None] != np.arange(m)[None, :])[None, :, None, :]


def _posterior_slack(alt: FloatArray, tau_w: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``ln((1-p)/p) - ln sum_j exp(-alt_j)`` over the last axis (``alt`` is ``+inf`` on the
    true goal, which adds nothing), with the unnormalised softmax weights
    ``exp(l_min - alt_j)`` and their sum. Stable: ``l_min - ln sum_j exp(l_min - l_j)``;
    about half the time of scipy's general logsumexp, which dominated the commit
    objective's search."""
    low = alt.min(axis=-1)
    weight = np.exp(low[..., None] - alt)
    total = weight.sum(axis=-1)
    return -tau_w + low - np.log(total), weight, total


def _first_crossing(c: FloatArray, tau_c: float) -> tuple[NDArray[np.bool_], IntArray, FloatArray]:
    """``(has, first, t_hat)`` of slacks ``c (..., T)`` at steps ``1..T``: whether ``c``
    reaches 0, the index of the first step where it does (0 without one) and the zero
    crossing interpolated from the step before (``c(0) = -tau_c``)."""
    reached = c >= 0.0
    has = reached.any(axis=-1)
    first = np.argmax(reached, axis=-1)
    c_at = np.take_along_axis(c, first[..., None], -1)[..., 0]
    c_before = np.where(
        first > 0, np.take_along_axis(c, np.maximum(first - 1, 0)[..., None], -1)[..., 0],
        -tau_c,
    )  # fmt: skip
    crossing = first + (-c_before) / np.maximum(c_at - c_before, 1e-300)
    return np.asarray(has), np.asarray(first, dtype=np.int64), np.asarray(crossing)


def _terms(bt: _Batch, params: Params, rows: slice) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(t, m_ij(t), sqrt(v_ij(t)))`` along the nominal of each true goal ``i`` in ``rows``
    up to their longest ``T_a``, against every goal ``j``: steps ``(T,)``, margins and
    standard deviations ``(b, i, T, j)``. The variance is
    ``beta^2 v_max^2 dt^2 S_rho(t) a^T C a`` (``C`` the per-step covariance of the
    deflection, :func:`~legws_daemon.core.certificate.step_spread`), section 9's
    ``beta^2 |a|^2 t sigma^2 dt^2`` for its user."""
    if not bt.operator.straight:
        return _path_terms(bt, params, rows)
    pg, rot_term, trans0, user = bt.pg, bt.rot_term, bt.trans0, bt.user
    b, m = pg.shape[:2]
    true = np.arange(m)[rows]  # the true goals' indices
    k = len(true)
    step_len = bt.step_length
    n_t = int(bt.t_a[:, rows].max())
    t = np.arange(1, n_t + 1, dtype=np.float64)  # (T,)
    s = (t * step_len)[None, None, :, None]  # (1, 1, T, 1) distance travelled
    dist_start = trans0 + rot_term  # (b, M)
    eye = true[:, None] == np.arange(m)[None, :]  # (i, j): j is the true goal i
    # Distances from the nominal pbar_t = p0 + s u_i to every goal j, from scalars alone:
    # |pbar_t - p_j|^2 = |p0 - p_j|^2 + 2 s (p0 - p_j).u_i + s^2 (no (b, i, T, j, 3) arrays).
    u = safe_unit(pg[:, rows] - bt.p0)  # (b, i, 3)
    e = np.einsum("bik,bjk->bij", u, bt.p0 - pg)[:, :, None, :]  # (b, i, 1, j)
    q = (trans0**2)[:, None, None, :]
    along = (trans0[:, rows, None, None] - s) * eye[None, :, None, :]  # |pbar_t - p_i|, exact
    trans_now = np.where(
        eye[None, :, None, :], along, np.sqrt(np.maximum(q + 2 * s * e + s * s, 0))
    )
    margin = _margins(trans_now, rot_term, dist_start, t * step_len, true, params)

    # |a_ij|^2 = |unit_j / S_j - unit_i / S_i|^2 with unit_g = (pbar - p_g) / |pbar - p_g|
    # (zero where the point coincides) and unit_i = -u_i before arrival.
    scale = cost_scales(dist_start, params)
    on_j = trans_now > _COINCIDENT
    at_true = np.broadcast_to(true[None, :, None, None], (b, k, n_t, 1))
    on_i = np.take_along_axis(on_j, at_true, axis=-1)  # (b, i, T, 1)
    s_j = scale[:, None, None, :]
    s_i = scale[:, rows, None, None]
    dot = -(e + s) / np.where(on_j, trans_now, 1.0)  # unit_j . unit_i
    a2 = on_j / s_j**2 + on_i / s_i**2 - 2 * np.where(on_j & on_i, dot, 0.0) / (s_i * s_j)
    # a . u_i (unit_j . u_i = (e + s) / |pbar - p_j|, unit_i . u_i = -1): the noise along
    # the way and across it may differ (the clipped user); equal, this is t sigma^2 dt^2 |a|^2
    a_u = np.where(on_j, (e + s) / np.where(on_j, trans_now, 1.0), 0.0) / s_j + on_i / s_i
    per_step = (params.v_max * params.dt) ** 2
    spread = user.across**2 * a2 + (user.along**2 - user.across**2) * a_u**2
    sums = ar1_sum_variance(t, user.rho)
    var = params.beta**2 * per_step * sums[None, None, :, None] * np.maximum(spread, 0.0)
    sd = np.sqrt(np.maximum(var, 0.0))
    if bt.guarded:
        r_true = np.maximum(trans0[:, rows, None, None] - s, 0.0)
        margin, sd = _guard(bt, params, margin, sd, r_true, trans_now, scale, rows, sums)
    return t, margin, sd


def _guard(
    bt: _Batch,
    params: Params,
    margin: FloatArray,
    sd: FloatArray,
    r_true: FloatArray,
    r_alt: FloatArray,
    scale: FloatArray,
    rows: slice,
    sums: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Margins and standard deviations ``(b, i, T, j)`` under :func:`~.guard.guarded`, from
    the nominal's distances to the true goals ``(b, i, T, 1)`` and to every goal, the cost
    normalisers ``(b, M)`` and ``S_rho(t)`` ``(T,)``."""
    pos_var = (params.v_max * params.dt) ** 2 * sums[None, None, :, None]
    return guarded(
        margin, sd, r_true, r_alt, bt.trans0[:, rows, None, None],
        1.0 / scale[:, rows, None, None], 1.0 / scale[:, None, None, :],
        pos_var, bt.user.widest, spread_trace(bt.user, bt.operator.straight), params.beta,
    )  # fmt: skip


def _margins(
    trans_now: FloatArray,
    rot_term: FloatArray,
    dist_start: FloatArray,
    length: FloatArray,
    true: IntArray,
    params: Params,
) -> FloatArray:
    """``m_ij(t) = beta (C_j - C_i)`` from the distances ``(b, i, T, j)`` of the nominal to
    every goal and its path lengths ``(T,)``."""
    b, k, n_t, _ = trans_now.shape
    dist_now = trans_now + rot_term[:, None, None, :]
    costs = path_costs(
        np.broadcast_to(length, (b, k, n_t)), dist_now, dist_start[:, None, None, :], params.cost
    )
    at_true = np.broadcast_to(true[None, :, None, None], (b, k, n_t, 1))
    c_true = np.take_along_axis(costs, at_true, axis=-1)[..., 0]  # (b, i, T)
    return np.asarray(params.beta * (costs - c_true[..., None]), dtype=np.float64)


def _path_terms(
    bt: _Batch, params: Params, rows: slice
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`_terms` along a curved nominal (an operator's bias or quantised steering):
    from the nominal's own points, with the wider of the per-step standard deviations on
    every axis (:func:`~legws_daemon.core.certificate.step_spread`)."""
    pg, user = bt.pg, bt.user
    m = pg.shape[1]
    true = np.arange(m)[rows]
    n_t = int(bt.t_a[:, rows].max())
    t = np.arange(1, n_t + 1, dtype=np.float64)
    path = nominal_path(bt.p0, pg[:, rows], bt.operator, user, params, n_t)  # (b, i, T, 3)
    diff = path[:, :, :, None, :] - pg[:, None, None, :, :]  # (b, i, T, j, 3)
    trans_now = np.sqrt(np.einsum("bitjk,bitjk->bitj", diff, diff))
    dist_start = bt.trans0 + bt.rot_term
    margin = _margins(trans_now, bt.rot_term, dist_start, t * bt.step_length, true, params)
    on = trans_now > _COINCIDENT
    unit = np.where(on[..., None], diff / np.where(on, trans_now, 1.0)[..., None], 0.0)
    scale = cost_scales(dist_start, params)
    grad = unit / scale[:, None, None, :, None]
    at_true = np.broadcast_to(true[None, :, None, None, None], (*grad.shape[:3], 1, 3))
    sensitivity = grad - np.take_along_axis(grad, at_true, axis=-2)
    spread = step_spread(sensitivity, None, user)
    sums = ar1_sum_variance(t, user.rho)
    var = params.beta**2 * (params.v_max * params.dt) ** 2 * sums[None, None, :, None] * spread
    sd = np.sqrt(np.maximum(var, 0.0))
    if bt.guarded:
        r_true = np.take_along_axis(trans_now, at_true[..., 0], axis=-1)  # (b, i, T, 1)
        margin, sd = _guard(bt, params, margin, sd, r_true, trans_now, scale, rows, sums)
    return t, margin, sd


def _chunk(
    bt: _Batch,
    params: Params,
    form: str,
    tau_c: float,
    tau_w: float,
    z_c: float,
    rows: slice,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(kappa, t_c or -1, c(T_a), w)`` of a chunk of layouts and the true goals ``rows``,
    each ``(b, rows)``."""
    m = bt.pg.shape[1]
    t, margin, sd = _terms(bt, params, rows)
    t_a = bt.t_a[:, rows]
    valid = t[None, None, :] <= t_a[:, :, None]  # (b, i, T)
    others = _others(m, rows)  # (1, i, 1, j)
    lower = np.where(others, margin - z_c * sd, np.inf)  # (b, i, T, j)
    # "sum": ln((1-p)/p) - ln sum_j exp(-l_j)
    c = lower.min(axis=-1) - tau_c if form == "min" else _posterior_slack(lower, tau_w)[0]
    c = np.where(valid, c, -np.inf)
    has, first, crossing = _first_crossing(c, tau_c)  # first: the index of t_c - 1
    t_c = np.where(has, first + 1, -1)
    c_arrival = np.take_along_axis(c, (t_a - 1)[..., None], axis=-1)[..., 0]

    t_end = np.where(has, t_c, t_a)  # (b, i)
    z_w = np.asarray(upper_quantile(params.alpha / (2 * (m - 1) * t_end)))  # (b, i)
    wrong = np.where(others, margin + tau_w - z_w[:, :, None, None] * sd, np.inf).min(axis=-1)
    in_window = t[None, None, :] <= t_end[:, :, None]
    w = np.where(in_window, wrong, np.inf).min(axis=-1)

    certified = has & (w >= 0.0)
    kappa = np.where(
        certified,
        crossing / t_a,
        1.0 + np.maximum(0.0, -c_arrival) + np.maximum(0.0, -w),
    )
    return kappa, t_c.astype(np.float64), c_arrival, w


@dataclass(frozen=True, slots=True)
class GoalCommit:
    """Commit certificate of one true goal (interfaces.md ``commit.goals``)."""

    fraction: float
    step: int | None  # t_c when the goal's commit is certified, else None
    arrival_steps: int
    slack_at_arrival: float
    wrong_commit_slack: float
    certified: bool
    crossing_step: int | None  # first step with c(t) >= 0 (even when w < 0), else None
    progress: float | None = None  # path length at t_c over |p_g* - p0| (certified only)
    reachable: bool = True  # False: the operator's nominal never arrives (kappa inf)


@dataclass(frozen=True, slots=True)
class CommitCertificate:
    """Commit certificate of one goal set."""

    objective: float
    certified: int
    goals: dict[str, GoalCommit]
    thresholds: tuple[float, float]
    quantile: float


def certify_commit(
    goals: GoalSet,
    params: Params,
    user: UserMotion | None = None,
    form: str = "min",
    operator: OperatorModel | None = None,
) -> CommitCertificate:
    """Commit certificate of one goal set: ``K``, certified goals and each goal's terms (for
    ``operator``, default section 2's user, with the moments ``user``: :func:`commit_batch`)."""
    batch = commit_batch(
        goals.x0.position,
        goals.x0.rotation,
        goals.positions[None],
        goals.rotations[None],
        goals.symmetry,
        params,
        user,
        form,
        operator,
    )
    per_goal = {}
    for i, name in enumerate(goals.names):
        cert = bool(batch.certified[0, i])
        t_c = int(batch.step[0, i])
        per_goal[name] = GoalCommit(
            fraction=float(batch.fraction[0, i]),
            step=t_c if cert else None,
            arrival_steps=int(batch.arrival_steps[0, i]),
            slack_at_arrival=float(batch.slack_at_arrival[0, i]),
            wrong_commit_slack=float(batch.wrong_commit_slack[0, i]),
            certified=cert,
            crossing_step=t_c if t_c > 0 else None,
            progress=float(batch.progress[0, i]) if cert else None,
            reachable=bool(batch.reachable[0, i]),
        )
    return CommitCertificate(
        objective=float(batch.objective[0]),
        certified=int(batch.count[0]),
        goals=per_goal,
        thresholds=batch.thresholds,
        quantile=batch.quantile,
    )
