"""Compiled kernels of the design objectives: J, K, R and T per layout and true goal.

The layout search (:meth:`~legws_daemon.design.problem.LayoutProblem.evaluate`) scores 90
layouts per iteration. The numpy reference (``core.certificate.certify_batch``,
``core.commit.commit_batch``, ``commit_chance_batch``, ``commit_time_batch``) builds
``(B, M, T, M)`` arrays and evaluates every step to arrival; these kernels compute the same
numbers one (layout, true goal) at a time, in registers, and evaluate only the steps the
definition needs:

* J (method.md §4, §10): the nominal at the horizon only (closed form for a straight
  operator; the operator's closed loop with bias about z and quantised steering
  otherwise, the goals of a layout followed together);
* K (§9), R, T: exact terms at a few steps; every other step is settled by bounds that
  follow from the exact terms of an earlier (or, for R, a later) step (see "jumps" below):
  K needs the first commit crossing ``t_c``, the arrival step and the wrong-commit terms
  that can be negative; T the first noise-free crossing; R the step of the largest
  ``c0 / sd`` (stopping once its chance is 1 to 1.3e-12).

J and K of an operator with the robot's clip are guarded as in the reference
(core.guard): the exact terms are guarded, the jumps bound the guarded terms (the guard
only lowers ``m - z sd``, so the commit crossing's skips start from the linearised terms;
the wrong-commit skips bound the guard over their window, :func:`_guard_window`).

Same definitions and, term for term, the same arithmetic as the reference: they agree
with it to ~1e-12 on J, K, R and T per goal, with the same certified flags and ``t_c``
(tests/design/test_fast_objectives.py checks ``<= 1e-9`` for every objective, cost form,
commit form and operator of the family). ``w`` is exact where negative (the only place
kappa or the certified flag depend on its value); where it is not, the value reported is
the smallest wrong-commit term evaluated, also ``>= 0``. The reports (``summary.json``,
``plan.json``, ``legws certify``) keep using the numpy reference; only the search calls
these.

numba compiles them on first use (``cache=True``: once per machine and version of this
file, into ``$NUMBA_CACHE_DIR``, which ``./dev`` sets to ``.cache/numba``; without it into
``__pycache__`` next to this file). Only the search imports this module: the daemon and
``legws certify`` never load numba for it.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from legws_daemon.core.certificate import goal_arrays, start_terms, upper_quantile, who_steers
from legws_daemon.core.commit import COMMIT_FORMS, thresholds
from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.guard import spread_trace
from legws_daemon.core.kernels import aim as _aim
from legws_daemon.core.kernels import jit as _jit
from legws_daemon.core.operator import (
    MAX_OPERATOR_STEPS,
    STEERINGS,
    OperatorModel,
    UserMotion,
    ar1_sum_variance,
    arrival_steps,
    horizon_steps,
)
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError

#: A point this close to a goal coincides with it (no gradient), m: as core.geometry and
#: core.commit.
_EPS = 1e-12
#: The arrival guard of core.operator (in units of ``v_max dt``).
_ARRIVAL_GUARD = 1e-9
#: Variance of J: section 4's as written (``sigma dt``), isotropic, along/across the way
#: (straight nominal), the widest on every axis (curved nominal).
_AS_WRITTEN, _ISOTROPIC, _ALONG_ACROSS, _WIDEST = 0, 1, 2, 3
#: What the commit kernel computes.
_K, _R, _T = 0, 1, 2

#: Threads the kernels run in (they release the GIL): the layouts of a batch are split
#: between them. ``LEGWS_SEARCH_THREADS`` overrides (1: no threads, e.g. when several
#: searches share the CPUs already).
SEARCH_THREADS = int(os.environ.get("LEGWS_SEARCH_THREADS", min(2, os.cpu_count() or 1)))
#: Below this many layouts a batch is not split.
_SPLIT_LAYOUTS = 16


@lru_cache(maxsize=1)
def _pool() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=SEARCH_THREADS, thread_name_prefix="legws-kernel")


def _in_threads(run: Callable[[slice], None], b: int) -> None:
    """``run`` over slices of the ``b`` layouts, one per thread (the results are the same:
    every layout is computed on its own)."""
    parts = SEARCH_THREADS if b >= _SPLIT_LAYOUTS else 1
    if parts <= 1:
        run(slice(0, b))
        return
    edges = np.linspace(0, b, parts + 1).astype(int)
    futures = [_pool().submit(run, slice(int(a), int(z))) for a, z in itertools.pairwise(edges)]
    for f in futures:
        f.result()


# --- the nominal ------------------------------------------------------------------------


@_jit
def _follow_layout(
    p0: FloatArray, pg: FloatArray, b: int, step: float, bc: float, bs: float, turn: bool,
    steering: int, grid: FloatArray, thr2: float, steps: IntArray, arrive: bool,
    paths: FloatArray, arrival: IntArray,
) -> None:  # fmt: skip
    """:func:`_follow` for every goal of layout ``b`` at once (``paths[g]``, ``arrival[g]``;
    at least ``steps[b, g]`` steps each): the goals' closed loops are independent, so the
    processor overlaps them."""
    m = pg.shape[1]
    here = np.empty((m, 3))
    done = np.zeros(m, dtype=np.bool_)
    limit = 1
    for g in range(m):
        here[g, 0], here[g, 1], here[g, 2] = p0[0], p0[1], p0[2]
        arrival[g] = 0
        limit = max(limit, steps[b, g])
    if arrive:
        limit = max(limit, MAX_OPERATOR_STEPS)
    for t in range(1, limit + 1):
        active = 0
        for g in range(m):
            if done[g]:
                continue
            gx, gy, gz = pg[b, g, 0], pg[b, g, 1], pg[b, g, 2]
            hx, hy, hz = here[g, 0], here[g, 1], here[g, 2]
            ax, ay, az = _aim(hx, hy, hz, gx, gy, gz, bc, bs, turn, steering, grid)
            hx, hy, hz = hx + step * ax, hy + step * ay, hz + step * az
            here[g, 0], here[g, 1], here[g, 2] = hx, hy, hz
            paths[g, 0, t - 1], paths[g, 1, t - 1], paths[g, 2, t - 1] = hx, hy, hz
            if arrive and arrival[g] == 0 and t <= MAX_OPERATOR_STEPS:
                lx, ly, lz = gx - hx, gy - hy, gz - hz
                if lx * lx + ly * ly + lz * lz < thr2:
                    arrival[g] = t
            if t >= steps[b, g] and (not arrive or arrival[g] > 0):
                done[g] = True
            else:
                active += 1
        if active == 0:
            break


# --- J: section 4 under an operator ---------------------------------------------------


@_jit
def _slack_at_point(
    b: int, i: int, hx: float, hy: float, hz: float, L: float, s_t: float, p0: FloatArray,
    pg: FloatArray, trans0: FloatArray, rot_term: FloatArray, mean: float, ratio: bool,
    beta: float, jpar: FloatArray, grad: FloatArray, cost: FloatArray,
) -> float:  # fmt: skip
    """``min_{j != i} s_ij`` with the nominal of ``i`` at its horizon ``(hx, hy, hz)``,
    path length ``L`` and ``S_rho(T) = s_t`` (core.certificate.certify_batch, operation for
    operation). ``jpar``: ``z, (sigma dt)^2, beta^2 (v_max dt)^2, along^2, across^2,
    widest^2``, the variance's form and ``tr C`` (core.guard: every form but the model as
    written is guarded). ``cost``: ``(2, M)`` scratch (costs, distances)."""
    m = trans0.shape[1]
    z, written_var, var_scale = jpar[0], jpar[1], jpar[2]
    along2, across2, widest2, mode = jpar[3], jpar[4], jpar[5], int(jpar[6])
    pos_var = var_scale * s_t / (beta * beta)
    gw = math.sqrt(widest2)
    inv_si = 1.0 / (trans0[b, i] + rot_term[b, i] if ratio else mean)
    wx = wy = wz = 0.0
    if mode == _ALONG_ACROSS:
        wx, wy, wz = hx - p0[0], hy - p0[1], hz - p0[2]
        norm = math.sqrt(wx * wx + wy * wy + wz * wz)
        if norm > _EPS:
            d = max(norm, _EPS)
            wx, wy, wz = wx / d, wy / d, wz / d
        else:
            wx, wy, wz = 0.0, 0.0, 0.0
    for j in range(m):
        ex, ey, ez = hx - pg[b, j, 0], hy - pg[b, j, 1], hz - pg[b, j, 2]
        tn = math.sqrt(ex * ex + ey * ey + ez * ez)
        d0 = trans0[b, j] + rot_term[b, j]
        scale = d0 if ratio else mean
        cost[1, j] = tn
        if ratio:
            cost[0, j] = (L + (tn + rot_term[b, j])) / d0
        else:
            cost[0, j] = (L + (tn + rot_term[b, j]) - d0) / mean
        if tn > _EPS:
            d = max(tn, _EPS)
            grad[j, 0], grad[j, 1], grad[j, 2] = ex / d / scale, ey / d / scale, ez / d / scale
        else:
            grad[j, 0], grad[j, 1], grad[j, 2] = 0.0, 0.0, 0.0
    best = np.inf
    for j in range(m):
        if j == i:
            continue
        ax = grad[j, 0] - grad[i, 0]
        ay = grad[j, 1] - grad[i, 1]
        az = grad[j, 2] - grad[i, 2]
        a2 = ax * ax + ay * ay + az * az
        if mode == _AS_WRITTEN:
            var = beta * beta * (s_t * written_var) * a2
        else:
            if mode == _ISOTROPIC:
                spread = along2 * a2
            elif mode == _WIDEST:
                spread = widest2 * a2
            else:
                au = ax * wx + ay * wy + az * wz
                spread = across2 * a2 + (along2 - across2) * au * au
            var = var_scale * s_t * spread
        margin = beta * (cost[0, j] - cost[0, i])
        sd = math.sqrt(var)
        if mode != _AS_WRITTEN:
            inv_sj = 1.0 / (trans0[b, j] + rot_term[b, j] if ratio else mean)
            margin, sd = _guard(margin, sd, cost[1, j], cost[1, i], trans0[b, i], inv_sj,
                                inv_si, pos_var, gw, jpar[7], beta)  # fmt: skip
        best = min(best, margin - z * sd)
    return best


@_jit
def _guard(
    margin: float, sd: float, tn: float, tn_i: float, d_i: float, inv_sj: float,
    inv_si: float, pos_var: float, wid: float, trace: float, beta: float,
) -> tuple[float, float]:  # fmt: skip
    """core.guard.guarded of one margin: ``(mean bound, sd bound)`` from the distances to
    the alternative (``tn``) and the true goal (``tn_i``; ``d_i`` from the start), the cost
    normalisers' inverses, ``(v_max dt)^2 S_rho(t)`` and the per-step covariance's widest
    and trace."""
    bridged = pos_var * min(max(tn_i / d_i, 0.0), 1.0)
    spread2 = bridged * trace
    drop = beta * inv_si * (math.sqrt(tn_i * tn_i + spread2) - tn_i)
    extra = 0.0
    if spread2 > 0.0:
        inv_ri = 1.0 / tn_i if tn_i > _EPS else np.inf
        inv_rj = 1.0 / tn if tn > _EPS else np.inf
        c = 2.0 * (inv_si * inv_ri + inv_sj * inv_rj)
        extra = beta * (math.sqrt(bridged) * wid) * c * math.sqrt(spread2)
    cap = beta * (math.sqrt(pos_var) * wid) * (inv_si + inv_sj)
    bound = math.sqrt(sd * sd + extra * extra)
    return margin - drop, (cap if not bound < cap else bound)


@_jit
def _unit(x: float, y: float, z: float) -> tuple[float, float, float]:
    """core.geometry.safe_unit of one vector."""
    norm = math.sqrt(x * x + y * y + z * z)
    if not norm > _EPS:
        return 0.0, 0.0, 0.0
    d = max(norm, _EPS)
    return x / d, y / d, z / d


@_jit
def _straight_point(p0: FloatArray, g: FloatArray, L: float) -> tuple[float, float, float]:
    """``p0 + L unit(g - p0)``: a straight nominal after ``L`` metres."""
    dx, dy, dz = _unit(g[0] - p0[0], g[1] - p0[1], g[2] - p0[2])
    return p0[0] + L * dx, p0[1] + L * dy, p0[2] + L * dz


@_jit
def _layout_mean(trans0: FloatArray, rot_term: FloatArray, b: int) -> float:
    """``D = mean_g d(x0, g)``."""
    m = trans0.shape[1]
    total = 0.0
    for j in range(m):
        total += trans0[b, j] + rot_term[b, j]
    return float(total / m)


@_jit
def _slack_kernel(
    p0: FloatArray, pg: FloatArray, trans0: FloatArray, rot_term: FloatArray,
    horizon: IntArray, length: FloatArray, sums: FloatArray, ratio: bool, beta: float,
    jpar: FloatArray, straight: bool, step: float, bc: float, bs: float, turn: bool,
    steering: int, grid: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    """``out[b, i] = min_{j != i} s_ij``: section 4's slack of each true goal."""
    n_b, m = trans0.shape
    paths = np.empty((m, 3, 1 if straight or not n_b else max(1, horizon.max())))
    arrival = np.zeros(m, dtype=np.int64)
    grad = np.empty((m, 3))
    cost = np.empty((2, m))
    for b in range(n_b):
        mean = _layout_mean(trans0, rot_term, b)
        if not straight:
            _follow_layout(p0, pg, b, step, bc, bs, turn, steering, grid, 0.0, horizon, False,
                           paths, arrival)  # fmt: skip
        for i in range(m):
            L = length[b, i]
            if straight:
                hx, hy, hz = _straight_point(p0, pg[b, i], L)
            else:
                steps = horizon[b, i]
                hx, hy, hz = paths[i, 0, steps - 1], paths[i, 1, steps - 1], paths[i, 2, steps - 1]
            out[b, i] = _slack_at_point(b, i, hx, hy, hz, L, sums[b, i], p0, pg, trans0,
                                        rot_term, mean, ratio, beta, jpar, grad, cost)  # fmt: skip


# --- K, R, T: section 9 and its surrogates along the nominal -----------------------------


@_jit
def _ndtr(x: float) -> float:
    """``Phi(x)`` (scipy's ndtr: erf near 0, erfc in the tails)."""
    if np.isnan(x):
        return np.nan
    y = x * (1.0 / math.sqrt(2.0))
    zz = abs(y)
    if zz < 1.0 / math.sqrt(2.0):
        return 0.5 + 0.5 * math.erf(y)
    half = 0.5 * math.erfc(zz)
    return 1.0 - half if y > 0.0 else half


# --- jumps: steps the definition provably does not need ------------------------------
#
# Along any nominal the path length grows by ``step`` per step and every distance changes
# by at most ``step``, so each margin changes by at most ``delta_up`` upward and
# ``delta_down`` downward per step (straight toward the true goal: never downward), and the
# noise-free posterior slack ``c0`` rises by at most the largest ``delta_up``. The spread
# ``sigma_j = sd_j / sqrt(v_t)`` (``v_t = beta^2 (v_max dt)^2 S_rho(t)``, non-decreasing) is
# a norm of the sensitivity ``a_j = u_j / s_j - u_i / s_i``: at most ``sigma_max`` ever,
# and it changes by at most ``omega`` per step (the unit vectors turn by at most
# ``step / distance``; toward the true goal along a straight nominal ``u_i`` does not turn).
# From the exact terms of one step these bound every later step's margins, spreads, commit
# slack and wrong-commit terms; steps whose bounds settle the outcome are not computed:
#
# * K: a step is skipped while some alternative's upper bound of ``m - z_c sd`` stays below
#   the crossing threshold (``tau_c`` for the min form; ``tau_w`` for the sum, whose slack
#   is at most ``-tau_w + min_j l_j``), and an alternative's terms while its wrong-commit
#   term's lower bound stays at or above 0 (``w`` is needed exactly only when negative);
# * T: a step is skipped while ``c0`` cannot have reached 0.
#
# Every bound carries a relative slack of 1e-9 and decisions a margin of 1e-9, so the
# outcome (crossing step, certified, K, T) is the one every step would give.

#: Relative slack on the Lipschitz constants, absolute margin on the decisions of a jump.
_SAFE = 1e-9
#: The guard's parameters when off (R and T, the search's surrogates, are not guarded).
_NO_GUARD = np.zeros(4)


@_jit
def _true_at(
    t: int, straight: bool, path: FloatArray, step: float, ratio: bool, inv_mean: float,
    var_c: float, s_table: FloatArray, goal: FloatArray, g_i: FloatArray,
) -> tuple[float, float, float, float, float, float, float]:  # fmt: skip
    """The true goal's terms at step ``t``: ``(cost, on, v_t, grad x, y, z, distance)``
    (as :func:`_true_terms`)."""
    c = t - 1
    L = t * step
    gx = gy = gz = 0.0
    if straight:
        tn = goal[0] - L
    else:
        dx, dy, dz = path[0, c] - g_i[0], path[1, c] - g_i[1], path[2, c] - g_i[2]
        tn = math.sqrt(dx * dx + dy * dy + dz * dz)
        f = (1.0 / tn if tn > _EPS else 0.0) * goal[3]
        gx, gy, gz = dx * f, dy * f, dz * f
    cost = (L + (tn + goal[1])) / goal[2] if ratio else (L + (tn + goal[1]) - goal[2]) * inv_mean
    return cost, (1.0 if tn > _EPS else 0.0), var_c * s_table[c], gx, gy, gz, tn


@_jit
def _element(
    t: int, a: int, straight: bool, path: FloatArray, step: float, ratio: bool,
    inv_mean: float, beta: float, across2: float, dal: float, curved2: float,
    alt: FloatArray, goal: FloatArray, ti: tuple[float, float, float, float, float, float, float],
    need_sd: bool,
) -> tuple[float, float, float]:  # fmt: skip
    """Alternative ``a`` at step ``t``: ``(margin, sd, distance)`` (as the rows)."""
    c = t - 1
    L = t * step
    scale = 1.0 / alt[2, a] if ratio else inv_mean
    shift = 0.0 if ratio else alt[2, a]
    cost_i, on_i, v_t, gix, giy, giz = ti[0], ti[1], ti[2], ti[3], ti[4], ti[5]
    dx = dy = dz = 0.0
    if straight:
        e = alt[6, a]
        tn = math.sqrt(max(alt[0, a] * alt[0, a] + 2 * L * e + L * L, 0.0))
    else:
        dx, dy, dz = path[0, c] - alt[7, a], path[1, c] - alt[8, a], path[2, c] - alt[9, a]
        tn = math.sqrt(dx * dx + dy * dy + dz * dz)
    margin = beta * ((L + (tn + alt[1, a]) - shift) * scale - cost_i)
    if not need_sd:
        return margin, 0.0, tn
    on = tn > _EPS
    r = 1.0 / tn if on else 0.0
    if straight:
        es = alt[6, a] + L
        a2 = (1.0 if on else 0.0) * alt[4, a] + on_i * goal[4] + 2 * (es * r * on_i) * alt[5, a]
        au = es * r * alt[3, a] + on_i * goal[3]
        sd = math.sqrt(v_t * max(across2 * a2 + dal * au * au, 0.0))
    else:
        f = r * alt[3, a]
        ax, ay, az = dx * f - gix, dy * f - giy, dz * f - giz
        sd = math.sqrt(max(v_t * (curved2 * (ax * ax + ay * ay + az * az)), 0.0))
    return margin, sd, tn


@_jit
def _window(
    k: int, straight: bool, m: float, sig: float, tn: float, tn_i: float, a: int,
    bnd: FloatArray, inv_si: float, step: float, wid: float, beta: float, omega: float,
    klim: float, forward: bool = True,
) -> tuple[float, float, float, float]:  # fmt: skip
    """Bounds ``(m_lo, m_hi, sigma_lo, sigma_hi)`` of alternative ``a``'s margin and spread
    ``k`` steps from an exact step (margin ``m``, spread ``sig``, distances ``tn`` to it and
    ``tn_i`` to the true goal). Straight nominal, forwards: the margin never falls, rises by
    at most ``k up``; the spread moves by at most ``k omega`` (for ``k <= klim``). Curved
    (either way): the nominal is within ``k step`` of where it was, so the margin moves by
    at most ``beta (k step |a| + (k step)^2 H / 2)`` besides the path length's own share
    (``H = 1/(s_j d_j) + 1/(s_i d_i)`` bounds the curvature, ``d`` the distances shrunk by
    ``k step``) and the spread by ``wid k step H``; no closer than that, the crude bounds.
    Backwards (``forward`` off) the straight nominal's margin never rises, and its spread's
    bound holds all the way."""
    up, down, sigmax = bnd[0, a], bnd[1, a], bnd[2, a]
    if straight:
        lo, hi = (m, m + k * up) if forward else (m - k * up, m)
        if k <= klim or not forward:
            return lo, hi, max(sig - k * omega, 0.0), min(sig + k * omega, sigmax)
        return lo, hi, 0.0, sigmax
    if not forward:
        up, down = down, up
    reach = k * step
    if reach < 0.5 * min(tn, tn_i):
        H = bnd[4, a] / (tn - reach) + inv_si / (tn_i - reach)
        move = beta * (sig / wid * reach + 0.5 * H * reach * reach) * (1.0 + _SAFE)
        drift = beta * reach * bnd[5, a] * (1.0 if forward else -1.0)  # path length's share
        turn = wid * reach * H * (1.0 + _SAFE)
        return (
            max(m + drift - move, m - k * down),
            min(m + drift + move, m + k * up),
            max(sig - turn, 0.0),
            min(sig + turn, sigmax),
        )
    return m - k * down, m + k * up, 0.0, sigmax


@_jit
def _reach(kmax: int, v0: float, v1: float, thr: float) -> int:
    """A first guess of how many steps a rising bound (``v0`` at 0, ``v1 < thr`` after one
    step) stays below ``thr``: the straight line through them, shortened by a tenth (the
    bounds curve upwards), at least 1 and at most ``kmax``. The callers halve it until the
    bound holds there, which by monotonicity covers every step before."""
    rate = v1 - v0
    if not rate > 0.0:
        return kmax
    k = 1.0 + 0.9 * (thr - v1) / rate
    return int(max(1.0, min(k, float(kmax))))


@_jit
def _c_safe(
    kmax: int, straight: bool, m: float, sig: float, tn: float, tn_i: float, a: int,
    bnd: FloatArray, inv_si: float, step: float, wid: float, beta: float, omega: float,
    klim: float, A: float, thr: float,
) -> int:  # fmt: skip
    """Steps after an exact one (at most ``kmax``) whose ``m - z_c sd`` provably stays below
    ``thr``: its upper bound ``m_hi - A sigma_lo`` (``A = z_c sqrt(v_t)``) rises with ``k``."""

    def ub(k: int) -> float:
        lo_hi = _window(k, straight, m, sig, tn, tn_i, a, bnd, inv_si, step, wid, beta, omega,
                        klim)  # fmt: skip
        return lo_hi[1] - A * lo_hi[2]

    if kmax < 1:
        return 0
    u1 = ub(1)
    if u1 >= thr:
        return 0
    k = _reach(kmax, ub(0), u1, thr)  # extrapolated, then halved until it holds
    while k > 1 and ub(k) >= thr:
        k = k // 2
    return k


@_jit
def _w_safe(
    t: int, kmax: int, straight: bool, m: float, sig: float, tn: float, tn_i: float, a: int,
    bnd: FloatArray, inv_si: float, step: float, wid: float, beta: float, omega: float,
    klim: float, zw: float, tau_w: float, sq_table: FloatArray, s_table: FloatArray,
    gpar: FloatArray, inv_sj: float, d_i: float,
) -> int:  # fmt: skip
    """Steps after step ``t`` (at most ``kmax``) whose wrong-commit term ``m + tau_w - z_w
    sd`` provably stays at or above 0: its lower bound falls with ``k``. ``m``, ``sig``: the
    linearised terms; guarded (``gpar[0]``), the guard of their bounds at the distances
    shrunk by ``k step`` and the spread at ``t + k`` (it falls with both)."""

    def lb(k: int) -> float:
        lo_hi = _window(k, straight, m, sig, tn, tn_i, a, bnd, inv_si, step, wid, beta, omega,
                        klim)  # fmt: skip
        m_k, sd_k = lo_hi[0], sq_table[t + k - 1] * lo_hi[3]
        if gpar[0] != 0.0:
            m_k, sd_k = _guard_window(m_k, sd_k, tn, tn_i, k * step, straight, d_i, inv_sj,
                                      inv_si, gpar[1] * s_table[t + k - 1], gpar[3], gpar[2],
                                      beta)  # fmt: skip
        return float(m_k + tau_w - zw * sd_k)

    if kmax < 1:
        return 0
    l1 = lb(1)
    if l1 < _SAFE:
        return 0
    k = _reach(kmax, -lb(0), -l1, -_SAFE)  # extrapolated, then halved until it holds
    while k > 1 and lb(k) < _SAFE:
        k = k // 2
    return k


@_jit
def _exact_step(
    t: int, straight: bool, path: FloatArray, step: float, ratio: bool, inv_mean: float,
    beta: float, var_c: float, across2: float, dal: float, curved2: float,
    s_table: FloatArray, alt: FloatArray, goal: FloatArray, g_i: FloatArray, na: int,
    need_sd: bool, cur: FloatArray, gpar: FloatArray,
) -> float:  # fmt: skip
    """Every alternative's exact terms at step ``t`` into ``cur[0..2, a]`` (margin, sd,
    distance; guarded with ``gpar[0]``) and the linearised margin and sd into
    ``cur[3..4, a]`` (the jumps' bounds start from them); returns the true goal's
    distance."""
    ti = _true_at(t, straight, path, step, ratio, inv_mean, var_c, s_table, goal, g_i)
    for a in range(na):
        mm, sd, tn = _element(t, a, straight, path, step, ratio, inv_mean, beta, across2, dal,
                              curved2, alt, goal, ti, need_sd)  # fmt: skip
        cur[3, a], cur[4, a] = mm, sd
        if need_sd:
            mm, sd = _guarded_element(t, a, mm, sd, tn, ti[6], alt, goal, s_table, gpar, beta)
        cur[0, a], cur[1, a], cur[2, a] = mm, sd, tn
    return ti[6]


@_jit
def _guard_window(
    m_lo: float, sd_hi: float, tn: float, tn_i: float, reach: float, straight: bool,
    d_i: float, inv_sj: float, inv_si: float, pos_var: float, wid: float, trace: float,
    beta: float,
) -> tuple[float, float]:  # fmt: skip
    """A lower bound of the guarded margin and an upper bound of its sd over the steps
    within ``reach`` of an exact one (distances ``tn``, ``tn_i``; ``m_lo``, ``sd_hi`` the
    linearised terms' bounds there, ``pos_var`` the largest): the true goal's distance
    lies in ``[tn_i - reach, tn_i + reach]`` (a straight nominal only closes in), the
    alternative's is at least ``tn - reach``. The drop ``sqrt(r^2 + v tr min(r/d, 1)) - r``
    rises with ``r`` up to ``d`` and falls after it; the extra spread is
    ``2 v wid sqrt(tr) min(r_i/d, 1) (1/(r_i S_i) + 1/(r_j S_j))``, whose first term never
    rises with ``r_i`` and whose second rises with ``r_i`` and falls with ``r_j``."""
    ri_lo = max(tn_i - reach, 0.0)
    ri_hi = tn_i if straight else tn_i + reach
    rj_lo = max(tn - reach, 0.0)
    r = min(max(d_i, ri_lo), ri_hi)  # the drop's largest over the window
    spread2 = pos_var * min(r / d_i, 1.0) * trace
    drop = beta * inv_si * (math.sqrt(r * r + spread2) - r)
    first = 1.0 / d_i if ri_lo <= d_i else 1.0 / ri_lo
    second = min(ri_hi / d_i, 1.0) / rj_lo if rj_lo > _EPS else np.inf
    extra = beta * wid * math.sqrt(trace) * pos_var * 2.0 * (inv_si * first + inv_sj * second)
    cap = beta * (math.sqrt(pos_var) * wid) * (inv_si + inv_sj)
    bound = math.sqrt(sd_hi * sd_hi + extra * extra) * (1.0 + _SAFE)
    return m_lo - drop * (1.0 + _SAFE), (cap * (1.0 + _SAFE) if not bound < cap else bound)


@_jit
def _guarded_element(
    t: int, a: int, mm: float, sd: float, tn: float, tn_i: float, alt: FloatArray,
    goal: FloatArray, s_table: FloatArray, gpar: FloatArray, beta: float,
) -> tuple[float, float]:  # fmt: skip
    """:func:`_guard` of alternative ``a``'s exact terms at step ``t`` (unchanged with the
    guard off). ``gpar``: on, ``(v_max dt)^2``, ``tr C``, widest."""
    if gpar[0] == 0.0:
        return mm, sd
    return _guard(mm, sd, tn, max(tn_i, 0.0), goal[0], alt[3, a], goal[3],
                  gpar[1] * s_table[t - 1], gpar[3], gpar[2], beta)  # fmt: skip


@_jit
def _softmin_slack(
    cur: FloatArray, na: int, z: float, tau: float, exact_sum: bool, sure: bool = True
) -> float:
    """``c`` from the terms ``cur``: ``min_a (m - z sd) - tau`` (the min form, ``tau =
    tau_c``) or ``-tau - ln sum_a exp(-(m - z sd))`` (the sum, ``tau = tau_w``; without
    ``sure``, ``-inf`` where it is negative for certain: ``min_a (m - z sd) < tau``)."""
    low = np.inf
    for a in range(na):
        v = cur[0, a] - z * cur[1, a]
        low = v if v < low else low
    if not exact_sum:
        return low - tau
    if not sure and low < tau:
        return -np.inf
    total = 0.0
    for a in range(na):
        total += math.exp(low - (cur[0, a] - z * cur[1, a]))
    return -tau + low - math.log(total)


@_jit
def _omega(bnd: FloatArray, a: int, step: float, tn_i: float) -> tuple[float, float]:
    """``(omega, klim)`` of alternative ``a`` on a straight nominal: the spread's change per
    step, for as long as the nominal is over two steps from the goal (``u_i`` holds)."""
    return bnd[3, a], max(math.floor(tn_i / step) - 2.0, 0.0)


@_jit
def _commit_goal(
    n: int, exact_sum: bool, straight: bool, path: FloatArray, step: float, ratio: bool,
    inv_mean: float, beta: float, var_c: float, across2: float, dal: float, curved2: float,
    wid: float, s_table: FloatArray, sq_table: FloatArray, zw_table: FloatArray, z_c: float,
    tau_c: float, tau_w: float, goal: FloatArray, g_i: FloatArray, alt: FloatArray,
    bnd: FloatArray, na: int, cur: FloatArray, prev: FloatArray, w_next: IntArray,
    w_state: FloatArray, st_t: IntArray, st_m: FloatArray, st_sd: FloatArray,
    gpar: FloatArray,
) -> tuple[float, float, float, float]:  # fmt: skip
    """``(kappa, t_c or -1, c(T_a), w)`` of one true goal (core.commit.commit_batch),
    computing only the steps and terms the jumps leave (see above)."""
    thr = (tau_w if exact_sum else tau_c) - _SAFE  # below it, no crossing
    tau = tau_w if exact_sum else tau_c
    zw_n = zw_table[n - 1]  # the largest z_w any t_end can give
    count = 0
    w_next[:] = 0  # no term of this goal is bounded yet
    t = 1
    t_c = 0
    c_t = -np.inf
    while True:
        tn_i = _exact_step(t, straight, path, step, ratio, inv_mean, beta, var_c, across2,
                           dal, curved2, s_table, alt, goal, g_i, na, True, cur,
                           gpar)  # fmt: skip
        inv_sq = 1.0 / sq_table[t - 1]
        klim = _omega(bnd, 0, step, tn_i)[1]
        c_t = _softmin_slack(cur, na, z_c, tau, exact_sum, t == n)
        t_next = n + 1
        if c_t < 0.0 and t < n:  # the next step whose commit slack might reach 0
            A = z_c * sq_table[t - 1]
            k_c = 0
            for a in range(na):  # (the guard only lowers the linearised terms' bound)
                sig = cur[4, a] * inv_sq * (1.0 - _SAFE)
                k = _c_safe(n - t, straight, cur[3, a], sig, cur[2, a], tn_i, a, bnd,
                            goal[3], step, wid, beta, bnd[3, a], klim, A, thr)  # fmt: skip
                k_c = max(k_c, k)
            t_next = min(t + k_c + 1, n)
        for a in range(na):  # the terms for w where no bound covers them, and new bounds
            if w_next[a] <= t:
                st_t[count], st_m[count], st_sd[count] = t, cur[0, a], cur[1, a]
                count += 1
            if w_next[a] < t_next and t < n:
                sig = cur[4, a] * inv_sq * (1.0 + _SAFE)
                k = _w_safe(t, n - t, straight, cur[3, a], sig, cur[2, a], tn_i, a, bnd,
                            goal[3], step, wid, beta, bnd[3, a], klim, zw_n, tau_w,
                            sq_table, s_table, gpar, alt[3, a], goal[0])  # fmt: skip
                w_next[a] = t + k + 1
        if c_t >= 0.0:
            t_c = t
            break
        if t == n:
            break
        # alternatives whose wrong-commit bound runs out before it: their exact terms
        while True:
            a_min, s_min = 0, t_next
            for a in range(na):
                if w_next[a] < s_min:
                    a_min, s_min = a, w_next[a]
            if s_min >= t_next:
                break
            ti = _true_at(s_min, straight, path, step, ratio, inv_mean, var_c, s_table, goal,
                          g_i)  # fmt: skip
            mm, sd, tn = _element(s_min, a_min, straight, path, step, ratio, inv_mean, beta,
                                  across2, dal, curved2, alt, goal, ti, True)  # fmt: skip
            g_m, g_sd = _guarded_element(s_min, a_min, mm, sd, tn, ti[6], alt, goal, s_table,
                                         gpar, beta)  # fmt: skip
            st_t[count], st_m[count], st_sd[count] = s_min, g_m, g_sd
            count += 1
            sig = sd / sq_table[s_min - 1] * (1.0 + _SAFE)
            klim = _omega(bnd, a_min, step, ti[6])[1]
            k = _w_safe(s_min, n - s_min, straight, mm, sig, tn, ti[6], a_min, bnd, goal[3],
                        step, wid, beta, bnd[3, a_min], klim, zw_n, tau_w,
                        sq_table, s_table, gpar, alt[3, a_min], goal[0])  # fmt: skip
            w_next[a_min] = s_min + k + 1
        t = t_next
    if t_c > 0:
        crossing = 0.0
        c_prev = -tau_c
        if t_c > 1:
            _exact_step(t_c - 1, straight, path, step, ratio, inv_mean, beta, var_c, across2,
                        dal, curved2, s_table, alt, goal, g_i, na, True, prev,
                        gpar)  # fmt: skip
            c_prev = _softmin_slack(prev, na, z_c, tau, exact_sum)
        crossing = (t_c - 1) + (-c_prev) / max(c_t - c_prev, 1e-300)
        t_end = t_c
        c_end = c_t
        if t_c < n:
            _exact_step(n, straight, path, step, ratio, inv_mean, beta, var_c, across2, dal,
                        curved2, s_table, alt, goal, g_i, na, True, prev, gpar)  # fmt: skip
            c_end = _softmin_slack(prev, na, z_c, tau, exact_sum)
    else:
        crossing = 0.0
        t_end = n
        c_end = c_t
    z_w = zw_table[t_end - 1]
    w = np.inf
    for k in range(count):
        if st_t[k] <= t_end:
            v = st_m[k] + tau_w - z_w * st_sd[k]
            w = v if v < w else w
    certified = t_c > 0 and w >= 0.0
    kappa = crossing / n if certified else 1.0 + max(0.0, -c_end) + max(0.0, -w)
    return kappa, (float(t_c) if t_c > 0 else -1.0), c_end, w


@_jit
def _time_goal(
    n: int, straight: bool, path: FloatArray, step: float, ratio: bool, inv_mean: float,
    beta: float, var_c: float, s_table: FloatArray, tau_c: float, tau_w: float, dt: float,
    goal: FloatArray, g_i: FloatArray, alt: FloatArray, bnd: FloatArray, na: int,
    cur: FloatArray,
) -> tuple[float, int]:  # fmt: skip
    """``(T in seconds, the first step with c0 >= 0 or 0)`` of one true goal
    (core.commit.commit_time_batch): ``c0`` rises by at most the largest ``delta_up`` per
    step, so the steps before it can reach 0 are skipped."""
    up = 0.0
    for a in range(na):
        up = max(up, bnd[0, a])
    t = 1
    while True:
        _exact_step(t, straight, path, step, ratio, inv_mean, beta, var_c, 0.0, 0.0, 0.0,
                    s_table, alt, goal, g_i, na, False, cur, _NO_GUARD)  # fmt: skip
        c0 = _softmin_slack(cur, na, 0.0, tau_w, True)
        if c0 >= 0.0:
            c_before = -tau_c
            if t > 1:
                _exact_step(t - 1, straight, path, step, ratio, inv_mean, beta, var_c, 0.0,
                            0.0, 0.0, s_table, alt, goal, g_i, na, False, cur,
                            _NO_GUARD)  # fmt: skip
                c_before = _softmin_slack(cur, na, 0.0, tau_w, True)
            return ((t - 1) + (-c_before) / max(c0 - c_before, 1e-300)) * dt, t
        if t == n:
            return n * (1.0 + max(0.0, -c0)) * dt, 0
        k = math.floor((-c0 - _SAFE) / up) if -c0 > _SAFE else 0
        t = min(t + max(k, 0) + 1, n)


#: ``Phi(7) = 1 - 1.3e-12``: once some step's ``z`` reaches it, the chance is 1 to well within
#: the kernels' agreement, and the search for a larger ``z`` stops.
_Z_CAP = 7.0


@_jit
def _chance_bound(
    k: int, t: int, c0: float, total: float, tn_i: float, straight: bool, step: float,
    wid: float, beta: float, sq_table: FloatArray, goal: FloatArray, bnd: FloatArray,
    na: int, cur: FloatArray, w_state: FloatArray,
) -> float:  # fmt: skip
    """An upper bound of ``z = c0 / sd`` at step ``t - k`` from the exact terms of step
    ``t`` (``cur``; ``w_state[3]``: the softmax numerators ``exp(low - m_a)``, ``total``
    their sum); it rises with ``k``."""
    inv_sq = 1.0 / sq_table[t - 1]
    rise = 0.0  # the margins' largest rise and fall back to step t - k
    fall = 0.0
    hi = 0.0
    mix_hi = 0.0
    mix_lo = 0.0
    for a in range(na):
        m_lo, m_hi, s_lo, s_hi = _window(
            k, straight, cur[0, a], cur[1, a] * inv_sq, cur[2, a], tn_i, a, bnd, goal[3],
            step, wid, beta, bnd[3, a], 1e9, False,
        )  # fmt: skip
        rise = max(rise, m_hi - cur[0, a])
        fall = max(fall, cur[0, a] - m_lo)
        s_hi *= 1.0 + _SAFE
        s_lo *= 1.0 - _SAFE
        hi = max(hi, s_hi)
        mix_hi += w_state[3, a] * s_hi
        mix_lo += w_state[3, a] * s_lo
    U = c0 + rise
    scale = math.exp(rise + fall) * (1.0 + _SAFE)  # the softmax weights' change
    if U < 0.0:  # the spread's upper bound over the window (sq(t) >= sq(t - k))
        return float(U / max(sq_table[t - 1] * min(hi, scale * mix_hi / total), 1e-12))
    return float(U / max(sq_table[t - k - 1] * mix_lo / (total * scale), 1e-12))


@_jit
def _chance_goal(
    n: int, straight: bool, path: FloatArray, step: float, ratio: bool, inv_mean: float,
    beta: float, var_c: float, across2: float, dal: float, curved2: float, wid: float,
    s_table: FloatArray, sq_table: FloatArray, tau_c: float, tau_w: float, goal: FloatArray,
    g_i: FloatArray, alt: FloatArray, bnd: FloatArray, na: int, cur: FloatArray,
    w_state: FloatArray,
) -> float:  # fmt: skip
    """``Phi(max_{t <= T_a} c0(t) / sd(t))`` of one true goal
    (core.commit.commit_chance_batch). The steps before the noise-free crossing (``c0 <
    0``, where a later step has ``z >= 0``) are skipped as for T; the others are visited
    from arrival backwards, skipping those whose bound ``z <= U / sd_bound`` (``U``: ``c0``'s
    upper bound; the spread's lower bound, or its upper bound where ``U < 0``) cannot beat
    the best so far."""
    lo = _time_goal(n, straight, path, step, ratio, inv_mean, beta, var_c, s_table, tau_c,
                    tau_w, 1.0, goal, g_i, alt, bnd, na, cur)[1]  # fmt: skip
    lo = max(lo, 1)
    best = -np.inf
    t = n
    while t >= lo:
        tn_i = _exact_step(t, straight, path, step, ratio, inv_mean, beta, var_c, across2,
                           dal, curved2, s_table, alt, goal, g_i, na, True, cur,
                           _NO_GUARD)  # fmt: skip
        low = np.inf
        for a in range(na):
            low = min(low, cur[0, a])
        total = 0.0
        spread = 0.0
        for a in range(na):
            weight = math.exp(low - cur[0, a])
            w_state[3, a] = weight
            total += weight
            spread += weight * cur[1, a]
        c0 = -tau_w + low - math.log(total)
        z = c0 / max(spread / total, 1e-12)
        best = z if z > best else best
        if best >= _Z_CAP or t == lo:
            break
        args = (t, c0, total, tn_i, straight, step, wid, beta, sq_table, goal, bnd, na, cur,
                w_state)  # fmt: skip

        kmax = t - lo
        k = 0
        if _chance_bound(1, *args) <= best:  # the bound rises with k: the longest window it settles
            k_lo, k_hi = 1, 2
            while k_hi <= kmax and _chance_bound(k_hi, *args) <= best:
                k_lo, k_hi = k_hi, 2 * k_hi
            if k_hi > kmax:
                if _chance_bound(kmax, *args) <= best:
                    k_lo = kmax
                k_hi = kmax + 1
            while k_hi - k_lo > 1:
                mid = (k_lo + k_hi) // 2
                if _chance_bound(mid, *args) <= best:
                    k_lo = mid
                else:
                    k_hi = mid
            k = k_lo
        t = t - k - 1
    return _ndtr(best)


@_jit
def _commit_kernel(
    what: int, exact_sum: bool, p0: FloatArray, pg: FloatArray, trans0: FloatArray,
    rot_term: FloatArray, t_arrival: IntArray, straight: bool, step: float, bc: float,
    bs: float, turn: bool, steering: int, grid: FloatArray, thr2: float, ratio: bool,
    beta: float, var_c: float, along2: float, across2: float, curved2: float,
    s_table: FloatArray, zw_table: FloatArray, z_c: float, tau_c: float, tau_w: float,
    dt: float, want_slack: bool, horizon: IntArray, j_sums: FloatArray, jpar: FloatArray,
    gpar: FloatArray, out0: FloatArray, out1: FloatArray, out2: FloatArray,
    out3: FloatArray, arrived: IntArray, slack: FloatArray,
) -> None:  # fmt: skip
    """Per (layout, true goal): ``what = K``: ``out0..3 = (kappa, t_c or -1, c(T_a), w)``;
    ``R``: ``out0`` the chance; ``T``: ``out0`` the commit time (s). ``arrived``: ``T_a``
    (0: the nominal never arrives). With ``want_slack``, also section 4's slack along the
    same nominal into ``slack`` (horizon steps ``horizon``, ``S_rho(T) = j_sums``).
    ``gpar``: K's guard (core.guard; on, ``(v_max dt)^2``, ``tr C``, widest)."""
    n_b, m = trans0.shape
    na = m - 1
    cap = max(2, t_arrival.max()) if n_b else 2
    if want_slack and n_b:
        cap = max(cap, horizon.max())
    paths = np.empty((m, 3, 1 if straight else max(cap, MAX_OPERATOR_STEPS)))
    arrival = np.zeros(m, dtype=np.int64)
    alt = np.zeros((10, na))
    goal = np.empty(5)
    g_i = np.empty(3)
    grad = np.empty((m, 3))
    cost = np.empty((2, m))
    dal = along2 - across2
    wid = math.sqrt(max(along2, across2)) if straight else math.sqrt(curved2)
    sq_table = np.sqrt(var_c * s_table)
    bnd = np.zeros((6, na))
    cur = np.empty((5, na))
    prev = np.empty((5, na))
    w_next = np.zeros(na, dtype=np.int64)
    w_state = np.zeros((4, na))
    st_t = np.empty(cap * na, dtype=np.int64)
    st_m = np.empty(cap * na)
    st_sd = np.empty(cap * na)
    for b in range(n_b):
        mean = _layout_mean(trans0, rot_term, b)
        inv_mean = 1.0 / mean
        if not straight:
            _follow_layout(p0, pg, b, step, bc, bs, turn, steering, grid, thr2, horizon, True,
                           paths, arrival)  # fmt: skip
        for i in range(m):
            path = paths[i]
            g_i[0], g_i[1], g_i[2] = pg[b, i, 0], pg[b, i, 1], pg[b, i, 2]
            d0_i = trans0[b, i] + rot_term[b, i]
            s_i = d0_i if ratio else mean
            goal[0], goal[1], goal[2] = trans0[b, i], rot_term[b, i], d0_i
            goal[3], goal[4] = 1.0 / s_i, 1.0 / s_i**2
            ux, uy, uz = 0.0, 0.0, 0.0
            T = horizon[b, i] if want_slack else 1
            if straight:
                n = t_arrival[b, i]
                ux, uy, uz = _unit(g_i[0] - p0[0], g_i[1] - p0[1], g_i[2] - p0[2])
            else:
                n = arrival[i]
            if want_slack:
                L = T * step
                if straight:
                    hx, hy, hz = _straight_point(p0, g_i, L)
                else:
                    hx, hy, hz = path[0, T - 1], path[1, T - 1], path[2, T - 1]
                slack[b, i] = _slack_at_point(b, i, hx, hy, hz, L, j_sums[b, i], p0, pg,
                                              trans0, rot_term, mean, ratio, beta, jpar,
                                              grad, cost)  # fmt: skip
            arrived[b, i] = n
            if n == 0:  # not reachable by this operator
                if what == _K:
                    out0[b, i], out1[b, i], out2[b, i], out3[b, i] = np.inf, -1.0, np.nan, np.nan
                else:
                    out0[b, i] = 0.0 if what == _R else np.inf
                continue
            a = 0
            for j in range(m):
                if j == i:
                    continue
                s_j = trans0[b, j] + rot_term[b, j] if ratio else mean
                alt[0, a], alt[1, a] = trans0[b, j], rot_term[b, j]
                alt[2, a] = trans0[b, j] + rot_term[b, j]
                alt[3, a], alt[4, a], alt[5, a] = 1.0 / s_j, 1.0 / s_j**2, 1.0 / (s_i * s_j)
                alt[6, a] = (
                    ux * (p0[0] - pg[b, j, 0]) + uy * (p0[1] - pg[b, j, 1])
                    + uz * (p0[2] - pg[b, j, 2])
                )  # fmt: skip
                alt[7, a], alt[8, a], alt[9, a] = pg[b, j, 0], pg[b, j, 1], pg[b, j, 2]
                a += 1
            # the bounds of the jumps: margins' change per step up and down, the
            # spread's largest value and (straight) its change per step
            for a in range(na):
                s_j = 1.0 / alt[3, a]
                up = 2.0 * beta * step * (alt[3, a] if ratio else inv_mean)
                down = 0.0 if straight else 2.0 * beta * step * (goal[3] if ratio else inv_mean)
                bnd[0, a], bnd[1, a] = up * (1.0 + _SAFE), down * (1.0 + _SAFE)
                bnd[2, a] = wid * (alt[3, a] + goal[3]) * (1.0 + _SAFE)
                h2 = alt[0, a] * alt[0, a] - alt[6, a] * alt[6, a]  # the line's distance^2
                h = math.sqrt(max(h2, 0.0))
                bnd[3, a] = wid * step / (h * s_j) * (1.0 + _SAFE) if h > 1e-9 else np.inf
                bnd[4, a] = alt[3, a]
                bnd[5, a] = alt[3, a] - goal[3] if ratio else 0.0
            if what == _K:
                if n * na > st_t.shape[0]:
                    st_t = np.empty(n * na, dtype=np.int64)
                    st_m = np.empty(n * na)
                    st_sd = np.empty(n * na)
                out0[b, i], out1[b, i], out2[b, i], out3[b, i] = _commit_goal(
                    n, exact_sum, straight, path, step, ratio, inv_mean, beta, var_c,
                    across2, dal, curved2, wid, s_table, sq_table, zw_table, z_c, tau_c,
                    tau_w, goal, g_i, alt, bnd, na, cur, prev, w_next, w_state, st_t, st_m,
                    st_sd, gpar,
                )  # fmt: skip
            elif what == _R:
                out0[b, i] = _chance_goal(n, straight, path, step, ratio, inv_mean, beta,
                                          var_c, across2, dal, curved2, wid, s_table,
                                          sq_table, tau_c, tau_w, goal, g_i, alt, bnd, na,
                                          cur, w_state)  # fmt: skip
            else:  # T: the noise-free crossing of c0 from c0(0) = -tau_c
                out0[b, i] = _time_goal(n, straight, path, step, ratio, inv_mean, beta, var_c,
                                        s_table, tau_c, tau_w, dt, goal, g_i, alt, bnd, na,
                                        cur)[0]  # fmt: skip


# --- the batch -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CommitTerms:
    """:func:`~legws_daemon.core.commit.commit_batch`'s per-goal terms, ``(B, M)`` each.

    Attributes:
        fraction: ``kappa`` (``inf`` for a goal the operator does not reach).
        step: ``t_c`` (the first step with ``c >= 0``), ``-1`` when none.
        slack_at_arrival: ``c(T_a)`` (``nan`` when not reached).
        wrong_commit_slack: ``w`` (``nan`` when not reached).
        certified: commit-certified.
        arrival_steps: ``T_a`` (0 when not reached).
        objective: ``(B,)`` ``K = max kappa``.
    """

    fraction: FloatArray
    step: IntArray
    slack_at_arrival: FloatArray
    wrong_commit_slack: FloatArray
    certified: NDArray[np.bool_]
    arrival_steps: IntArray
    objective: FloatArray


@lru_cache(maxsize=32)
def _sum_table(rho: float, n: int) -> FloatArray:
    """``S_rho(t)`` for ``t = 1..n`` (the reference's own function)."""
    return np.ascontiguousarray(ar1_sum_variance(np.arange(1, n + 1, dtype=np.float64), rho))


@lru_cache(maxsize=32)
def _wrong_table(alpha: float, m: int, n: int) -> FloatArray:
    """``z_w(t_end) = Phi^-1(1 - alpha / (2 (M-1) t_end))`` for ``t_end = 1..n``."""
    t_end = np.arange(1, n + 1, dtype=np.float64)
    return np.ascontiguousarray(upper_quantile(alpha / (2 * (m - 1) * t_end)), dtype=np.float64)


def _table_size(n: int) -> int:
    """The power of two at or above ``n`` (tables are cached by their size)."""
    return 1 << max(n - 1, 1).bit_length()


@lru_cache(maxsize=1)
def _grid() -> FloatArray:
    from legws_daemon.core.operator import GRID_DIRECTIONS

    return np.ascontiguousarray(GRID_DIRECTIONS)


class Objectives:
    """The design objectives of one batch of layouts ``(B, M)`` goals, from the start
    terms computed once (numpy: the rotation terms need the grasps' symmetries).

    Args: as :func:`~legws_daemon.core.certificate.certify_batch`'s first six.
    """

    def __init__(
        self,
        p0: ArrayLike,
        R0: ArrayLike,
        goal_positions: ArrayLike,
        goal_rotations: ArrayLike,
        symmetry: ArrayLike,
        params: Params,
    ) -> None:
        p, pg, Rg = goal_arrays(p0, goal_positions, goal_rotations)
        b, m = pg.shape[:2]
        sym = np.broadcast_to(np.asarray(symmetry), (b, m))
        trans0, rot_term = start_terms(p, R0, pg, Rg, sym, params)
        self.p0 = np.ascontiguousarray(p, dtype=np.float64)
        self.pg = np.ascontiguousarray(pg)
        self.trans0 = np.ascontiguousarray(trans0)
        self.rot_term = np.ascontiguousarray(rot_term)
        self.params = params
        self.shape = (b, m)

    @staticmethod
    def _steering(op: OperatorModel) -> tuple[float, float, bool, int]:
        """``cos b, sin b``, whether to turn, the steering's index."""
        bias = op.bias
        return math.cos(bias), math.sin(bias), bias != 0.0, STEERINGS.index(op.steering)

    def _slack_terms(
        self, op: OperatorModel, motion: UserMotion
    ) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
        """Section 4's horizon steps, path lengths, ``S_rho(T)`` and the kernel's ``jpar``."""
        params = self.params
        steps = np.ascontiguousarray(horizon_steps(self.trans0, params, motion.speed))
        step = motion.speed * params.v_max * params.dt
        length = np.ascontiguousarray(steps * step, dtype=np.float64)
        sums = np.ascontiguousarray(ar1_sum_variance(steps, motion.rho), dtype=np.float64)
        if motion == op.motion(params):
            mode = _AS_WRITTEN
        elif motion.isotropic:
            mode = _ISOTROPIC
        else:
            mode = _ALONG_ACROSS if op.straight else _WIDEST
        z = float(upper_quantile(params.alpha / (self.shape[1] - 1)))
        jpar = np.array([
            z, (op.sigma * params.dt) ** 2, params.beta**2 * (params.v_max * params.dt) ** 2,
            motion.along**2, motion.across**2, motion.widest**2, float(mode),
            spread_trace(motion, op.straight),
        ])  # fmt: skip
        return steps, length, sums, jpar

    def slack(
        self, operator: OperatorModel | None = None, user: UserMotion | None = None
    ) -> FloatArray:
        """``(B, M)``: each true goal's smallest slack ``min_{j != i} s_ij`` (method.md §4,
        §10); ``.min(axis=1)`` is :func:`~legws_daemon.core.certificate.certify_batch`'s
        ``objective``."""
        params = self.params
        op, motion = who_steers(params, operator, user)
        steps, length, sums, jpar = self._slack_terms(op, motion)
        bc, bs, turn, steering = self._steering(op)
        out = np.empty(self.shape)

        def run(sl: slice) -> None:
            _slack_kernel(
                self.p0, self.pg[sl], self.trans0[sl], self.rot_term[sl], steps[sl], length[sl],
                sums[sl], params.cost == "ratio", params.beta, jpar, op.straight,
                motion.speed * params.v_max * params.dt, bc, bs, turn, steering, _grid(),
                out[sl],
            )  # fmt: skip

        _in_threads(run, self.shape[0])
        return out

    def _run(
        self, what: int, operator: OperatorModel | None, user: UserMotion | None,
        exact_sum: bool = False, want_slack: bool = False,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, IntArray, FloatArray]:  # fmt: skip
        """The commit kernel: its four outputs, ``T_a`` and (``want_slack``) J per goal."""
        params = self.params
        op, motion = who_steers(params, operator, user)
        b, m = self.shape
        tau_c, tau_w = thresholds(m, params.p_thresh)
        z_c = float(upper_quantile(params.alpha / (2 * (m - 1))))
        if op.straight:
            t_a = np.ascontiguousarray(arrival_steps(self.trans0, params, motion.speed))
            n = int(t_a.max()) if b else 1
        else:
            t_a = np.zeros((b, m), dtype=np.int64)
            n = MAX_OPERATOR_STEPS
        if want_slack:
            horizon, _, j_sums, jpar = self._slack_terms(op, motion)
        else:
            horizon, j_sums = np.ones((b, m), dtype=np.int64), np.zeros((b, m))
            jpar = np.zeros(8)
        bc, bs, turn, steering = self._steering(op)
        threshold = (params.v_max * params.dt) * (1.0 - _ARRIVAL_GUARD)
        curved2 = motion.along**2 if motion.isotropic else motion.widest**2
        guard = what == _K and motion != op.motion(params)  # as core.commit
        gpar = np.array([
            float(guard), (params.v_max * params.dt) ** 2, spread_trace(motion, op.straight),
            motion.widest,
        ])  # fmt: skip
        o0, o1, o2, o3, j_out = (np.empty((b, m)) for _ in range(5))
        arrived = np.zeros((b, m), dtype=np.int64)
        sums, wrong = (
            _sum_table(motion.rho, _table_size(n)),
            _wrong_table(params.alpha, m, _table_size(n)),
        )

        def run(sl: slice) -> None:
            _commit_kernel(
                what, exact_sum, self.p0, self.pg[sl], self.trans0[sl], self.rot_term[sl],
                t_a[sl], op.straight, motion.speed * params.v_max * params.dt, bc, bs, turn,
                steering, _grid(), threshold**2, params.cost == "ratio", params.beta,
                params.beta**2 * (params.v_max * params.dt) ** 2, motion.along**2,
                motion.across**2, curved2, sums, wrong, z_c, tau_c, tau_w, params.dt,
                want_slack, horizon[sl], j_sums[sl], jpar, gpar, o0[sl], o1[sl], o2[sl],
                o3[sl], arrived[sl], j_out[sl],
            )  # fmt: skip

        _in_threads(run, b)
        return o0, o1, o2, o3, arrived, j_out

    def commit(
        self,
        user: UserMotion | None = None,
        form: str = "min",
        operator: OperatorModel | None = None,
    ) -> CommitTerms:
        """:func:`~legws_daemon.core.commit.commit_batch`'s K and its per-goal terms."""
        if form not in COMMIT_FORMS:
            raise InputError(
                f"unknown commit form {form!r}; known: {', '.join(COMMIT_FORMS)}",
                field="--commit-form",
            )
        kappa, t_c, c_end, w, arrived, _ = self._run(_K, operator, user, form == "sum")
        step = t_c.astype(np.int64)
        certified = (step > 0) & (w >= 0.0)
        objective = kappa.max(axis=1) if self.shape[0] else np.zeros(0)
        return CommitTerms(kappa, step, c_end, w, certified, arrived, objective)

    def chance(
        self, user: UserMotion | None = None, operator: OperatorModel | None = None
    ) -> FloatArray:
        """:func:`~legws_daemon.core.commit.commit_chance_batch`, ``(B, M)``."""
        return self._run(_R, operator, user)[0]

    def time(
        self, user: UserMotion | None = None, operator: OperatorModel | None = None
    ) -> FloatArray:
        """:func:`~legws_daemon.core.commit.commit_time_batch`, ``(B, M)`` seconds."""
        return self._run(_T, operator, user)[0]

    def scores(
        self,
        objective: str,
        operator: OperatorModel | None = None,
        user: UserMotion | None = None,
        form: str = "sum",
    ) -> tuple[FloatArray, FloatArray, IntArray]:
        """``(J, value, T_a)`` per goal ``(B, M)`` along one nominal for ``operator`` with
        the moments ``user``: section 4's slack, the objective's per-goal value (``commit``:
        kappa of ``form``; ``rate``: the chance; ``time``: the commit time) and the arrival
        step (0: never arrives), one pass over the nominal for all."""
        what = {"commit": _K, "rate": _R, "time": _T}[objective]
        if what == _K and form not in COMMIT_FORMS:
            raise InputError(
                f"unknown commit form {form!r}; known: {', '.join(COMMIT_FORMS)}",
                field="--commit-form",
            )
        out = self._run(what, operator, user, form == "sum", want_slack=True)
        return out[5], out[0], out[4]
