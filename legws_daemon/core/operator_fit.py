"""Fitting a person's operator model from their own teleoperation (method.md §10).

Input: segments whose goal is known (a calibration's reaches, or picks that completed), per
tick the EE position ``x_t`` and the deflection sent ``u_t``. Per segment the ticks before
the first non-zero deflection (the person has not started) and those within two steps of
the goal (where the aim ``pi_h`` turns on the spot) are left out.

**Estimates** (``aim_t = Q(R_z(b) pi_h(x_t, g))``):

* ``steering``: the quantiser whose best fit leaves the smallest residual sum of squares
  (free, axes, axes+diagonals; the same number of parameters each). method.md §10 names the
  share of ticks whose deflection lies on an axis (or an axis or diagonal) within 5°; with
  the family's noise (``sigma / v_max = 0.6`` per axis) an axis operator's deflections are
  almost never within 5° of an axis, so the shares are reported (``axis_share``,
  ``grid_share``) and the residuals decide (docs/decisions.md);
* ``b``: free steering — the angle of the mean horizontal deflection in each tick's frame of
  ``pi_h`` (the mean signed horizontal angle, weighted by the horizontal pull; unbiased for
  noise symmetric about the aim, and kept by the robot's clip, which only scales);
  quantised — the turn whose quantised aims fit best (a 0.25° grid over ±45°);
* ``s``: the mean of ``u_t . aim_t``;
* ``sigma``: the per-axis standard deviation of the residuals ``r_t = v_max (u_t - s aim_t)``;
* ``rho``: their lag-1 autocorrelation within segments.

**The clip.** A deflection never leaves the unit ball (the device's rim, the message's
bound), while the model's ``u = s aim + e / v_max`` does whenever the noise is large: with
the family's ``sigma = 0.03`` m/s at ``s = 1`` most ticks are at the rim. Taken as they are,
the estimates describe the clipped signal (``s`` ~0.67, ``sigma`` ~0.019 for section 2's
user). When at least :data:`CLIPPED_SHARE` of the ticks sit at the rim, ``s`` and ``sigma``
are solved from what the clip does to the model's moments (the quadrature of
:func:`~legws_daemon.core.operator.clipped_moments_batch`: the clipped mean and residual
spread of ``clip(s e + n)``), and ``rho`` from the lag-1 correlation of clipped residuals
(a fixed-seed simulation of pairs): the fit recovers the model, and the certificates, which
apply the robot's clip to it, describe the robot's motion (docs/decisions.md).

**Intervals**: 95 % percentile bootstrap over segments (:data:`RESAMPLES` resamples of whole
segments, the statistics recomputed from per-segment sums; the clip's inversion for ``rho``
is tabulated at the point estimate). ``certify_with`` takes the conservative end of each:
smaller ``s``; larger ``sigma``, ``rho`` and ``|b|``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from legws_daemon.core.geometry import FloatArray, safe_unit
from legws_daemon.core.operator import (
    AXIS_DIRECTIONS,
    BIAS_RANGE_DEG,
    GRID_DIRECTIONS,
    RHO_RANGE,
    SPEED_RANGE,
    STEERINGS,
    OperatorModel,
    aim,
    clipped_moments_batch,
    quantise,
    rotate_z,
)
from legws_daemon.core.params import RANGES, Params
from legws_daemon.errors import InputError

#: Resamples of the bootstrap over segments.
RESAMPLES = 1000
#: Coverage of the intervals.
LEVEL = 0.95
#: A tick whose deflection is this close to norm 1 sits at the rim (clipped).
RIM = 1.0 - 1e-3
#: From this share of ticks at the rim on, the clip is undone (below it the estimates of
#: the signal as it is are the model's: the clip changes them by less than their error).
CLIPPED_SHARE = 0.005
#: Ticks closer to the goal than this many full-speed steps are left out (the aim turns on
#: the spot there).
NEAR_GOAL_STEPS = 2.0
#: Segments shorter than this (after the cuts) are left out.
MIN_SEGMENT_TICKS = 5
#: A fit needs at least this many segments (the intervals resample segments) and ticks.
MIN_SEGMENTS = 2
MIN_TICKS = 50
#: A deflection within this angle of an axis (of an axis or diagonal) counts toward
#: ``axis_share`` (``grid_share``), method.md §10.
ON_DIRECTION_DEG = 5.0
#: The bias grid of quantised steering, degrees.
BIAS_GRID = np.arange(BIAS_RANGE_DEG[0], BIAS_RANGE_DEG[1] + 1e-9, 0.25)


@dataclass(frozen=True, slots=True)
class Reach:
    """One segment as the fit uses it: positions, deflections ``(n, 3)``, the goal ``(3,)``
    and which consecutive ticks form lag-1 pairs ``(n - 1,)``."""

    ee: FloatArray
    u: FloatArray
    goal: FloatArray
    pairs: np.ndarray


@dataclass(frozen=True, slots=True)
class Fit:
    """A fitted operator.

    Attributes:
        model: the point estimates (within the model's ranges).
        intervals: name -> 95 % bootstrap interval (``speed``, ``sigma``, ``rho``,
            ``bias_deg``); empty without a bootstrap.
        certify_with: the conservative ends (the model certificates use).
        segments, ticks: what the fit used (after the cuts).
        diagnostics: how the fit went (the signal's own estimates before undoing the
            clip, the shares at the rim and on axes, the residual sums per steering, the
            segments left out).
    """

    model: OperatorModel
    intervals: dict[str, tuple[float, float]]
    certify_with: OperatorModel
    segments: int
    ticks: int
    diagnostics: dict[str, object] = field(default_factory=dict)


def prepare(
    segments: Sequence[tuple[FloatArray, FloatArray, FloatArray]], params: Params
) -> tuple[list[Reach], int]:
    """The reaches the fit uses (see the module docstring) and how many segments were left
    out."""
    near = NEAR_GOAL_STEPS * params.v_max * params.dt
    out: list[Reach] = []
    dropped = 0
    for ee, u, goal in segments:
        ee = np.asarray(ee, dtype=np.float64).reshape(-1, 3)
        u = np.asarray(u, dtype=np.float64).reshape(-1, 3)
        goal = np.asarray(goal, dtype=np.float64).reshape(3)
        moving = np.flatnonzero(np.any(u != 0.0, axis=1))
        start = int(moving[0]) if len(moving) else len(u)
        keep = np.zeros(len(u), dtype=bool)
        keep[start:] = np.linalg.norm(goal - ee[start:], axis=1) > near
        if keep.sum() < MIN_SEGMENT_TICKS:
            dropped += 1
            continue
        index = np.flatnonzero(keep)
        out.append(Reach(ee[index], u[index], goal, np.diff(index) == 1))
    return out, dropped


@dataclass(frozen=True, slots=True)
class _Sums:
    """Per-segment sums ``(K, G)`` over a grid of turns (or totals) the estimates are
    ratios of. Over all ticks: ``a`` = sum u.aim, ``n`` = sum |aim|^2, ``uu`` = sum |u|^2,
    ``ticks``; over lag-1 pairs ``(t, t+1)``: ``pu`` = sum u_t.u_t+1, ``pq`` = sum
    (u_t.aim_t+1 + aim_t.u_t+1), ``pa`` = sum aim_t.aim_t+1, and ``a0``/``a1``, ``n0``/``n1``
    the sums of u.aim and |aim|^2 over the pairs' first and second ticks."""

    a: FloatArray
    n: FloatArray
    uu: FloatArray
    ticks: FloatArray
    pu: FloatArray
    pq: FloatArray
    pa: FloatArray
    a0: FloatArray
    a1: FloatArray
    n0: FloatArray
    n1: FloatArray

    def ratios(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(s, per-axis residual sd, lag-1 correlation)`` in deflection units of sums that
        are already totals (one value per resample).

        ``s`` is estimated on the quasi-differenced ticks, ``(u_t - rho u_{t-1})`` against
        ``(aim_t - rho aim_{t-1})`` (Cochrane–Orcutt, iterated with the residuals' ``rho``):
        in the closed loop the aim at ``x_t`` has turned against the noise that moved the EE
        there, so with correlated noise the plain mean of ``u . aim`` is low (by ~0.04 at
        ``rho = 0.8``, 20 cm from the goal); the innovation of the quasi-difference is
        independent of both aims."""

        def rest(s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
            rss = self.uu - 2 * s * self.a + s * s * self.n
            lag = self.pu - s * self.pq + s * s * self.pa
            return rss, lag, lag / np.maximum(rss, 1e-300)

        s = self.a / np.maximum(self.n, 1e-300)
        rss, _, rho = rest(s)
        for _ in range(_QUASI_ITERATIONS):
            r = np.clip(rho, 0.0, RHO_RANGE[1])
            num = self.a1 - r * self.pq + r * r * self.a0
            den = self.n1 - 2 * r * self.pa + r * r * self.n0
            s = num / np.maximum(den, 1e-300)
            rss, _, rho = rest(s)
        sd = np.sqrt(np.maximum(rss, 0.0) / (3.0 * np.maximum(self.ticks, 1.0)))
        return s, sd, rho


#: Rounds of the quasi-differenced estimate of ``s`` (converged to ~1e-6 after four).
_QUASI_ITERATIONS = 6


def boundary_distance(turned: FloatArray, steering: str, radius: FloatArray) -> FloatArray:
    """How far (m) the point ``radius`` along each unit aim ``(..., 3)`` is from the nearest
    boundary of the quantiser: where the two best directions ``d1``, ``d2`` score alike,
    ``radius (a . d1 - a . d2) / |d1 - d2|`` (``axes``: the two largest ``|components|``).
    ``inf`` for free steering."""
    if steering == "free":
        return np.full(turned.shape[:-1], np.inf)
    directions = AXIS_DIRECTIONS if steering == "axes" else GRID_DIRECTIONS
    dots = turned @ directions.T
    top = np.argsort(-dots, axis=-1)[..., :2]
    s1 = np.take_along_axis(dots, top[..., :1], axis=-1)[..., 0]
    s2 = np.take_along_axis(dots, top[..., 1:], axis=-1)[..., 0]
    d1, d2 = directions[top[..., 0]], directions[top[..., 1]]
    apart = np.sqrt(np.maximum(np.einsum("...k,...k->...", d1 - d2, d1 - d2), 1e-300))
    return np.asarray(radius * (s1 - s2) / apart, dtype=np.float64)


#: A quantised operator's ticks whose EE is closer than this to a boundary of the quantiser
#: (m; :func:`boundary_distance`) are left out of the estimates of ``s``, ``sigma`` and
#: ``rho``: there, which direction the person chose depends on where they saw the arm a
#: moment ago, which a few millimetres decide (a keyboard user alternates keys along a
#: diagonal), and the aim at the recorded EE is the other one about half the time
#: (measured over zenoh on the stand-in: ``u . aim`` 0.40 within 2 mm of a boundary, 0.67
#: beyond 2 cm, for an axis operator of speed 1).
BOUNDARY_M = 0.01


def _sums(
    reaches: Sequence[Reach], steering: str, bias: FloatArray, clear_at: float | None = None
) -> _Sums:
    """The per-segment sums for each turn of ``bias`` ``(G,)`` (radians): ``(K, G)`` each.
    ``clear_at`` (radians): only the ticks at least :data:`BOUNDARY_M` from a boundary of
    the quantiser turned by it (and the pairs of two such ticks) count, the same ticks for
    every turn (free steering: every tick)."""
    rows: list[list[FloatArray]] = [[] for _ in _SUMS]
    g = len(bias)
    c, s_ = np.cos(bias)[:, None], np.sin(bias)[:, None]
    for r in reaches:
        pull = safe_unit(r.goal - r.ee)  # (n, 3)
        turned = np.stack(
            [c * pull[:, 0] - s_ * pull[:, 1], s_ * pull[:, 0] + c * pull[:, 1],
             np.broadcast_to(pull[:, 2], (g, len(pull)))], axis=-1,
        )  # fmt: skip
        q = quantise(turned, steering)  # (G, n, 3)
        u, p = r.u, r.pairs
        if clear_at is not None and steering != "free":
            radius = np.linalg.norm(r.goal - r.ee, axis=1)
            at = rotate_z(pull, clear_at)
            keep = boundary_distance(at, steering, radius) >= BOUNDARY_M  # (n,)
            for i, v in enumerate(_masked_sums(u, q, p, np.broadcast_to(keep, (g, len(u))))):
                rows[i].append(v)
            continue
        uq = np.einsum("tk,gtk->gt", u, q)
        qq = np.einsum("gtk,gtk->gt", q, q)
        cross = np.einsum("tk,gtk->gt", u[:-1], q[:, 1:]) + np.einsum(
            "gtk,tk->gt", q[:, :-1], u[1:]
        )
        values = (
            uq.sum(axis=1),
            qq.sum(axis=1),
            np.full(g, float(np.einsum("tk,tk->", u, u))),
            np.full(g, float(len(u))),
            np.full(g, float(np.einsum("tk,tk->t", u[:-1], u[1:])[p].sum())),
            cross[:, p].sum(axis=1),
            np.einsum("gtk,gtk->gt", q[:, :-1], q[:, 1:])[:, p].sum(axis=1),
            uq[:, :-1][:, p].sum(axis=1),
            uq[:, 1:][:, p].sum(axis=1),
            qq[:, :-1][:, p].sum(axis=1),
            qq[:, 1:][:, p].sum(axis=1),
        )
        for i, v in enumerate(values):
            rows[i].append(v)
    return _Sums(*(np.array(r) for r in rows))


def _masked_sums(
    u: FloatArray, q: FloatArray, p: np.ndarray, keep: np.ndarray
) -> tuple[FloatArray, ...]:
    """:func:`_sums`'s values of one segment over the ticks ``keep`` ``(G, n)`` of each
    turn (and the lag-1 pairs ``p`` of two kept ticks)."""
    w = keep.astype(np.float64)
    pk = (p[None, :] & keep[:, :-1] & keep[:, 1:]).astype(np.float64)  # (G, n - 1)
    uq = np.einsum("tk,gtk->gt", u, q)
    qq = np.einsum("gtk,gtk->gt", q, q)
    cross = np.einsum("tk,gtk->gt", u[:-1], q[:, 1:]) + np.einsum("gtk,tk->gt", q[:, :-1], u[1:])
    return (
        (w * uq).sum(axis=1),
        (w * qq).sum(axis=1),
        w @ np.einsum("tk,tk->t", u, u),
        w.sum(axis=1),
        pk @ np.einsum("tk,tk->t", u[:-1], u[1:]),
        (pk * cross).sum(axis=1),
        (pk * np.einsum("gtk,gtk->gt", q[:, :-1], q[:, 1:])).sum(axis=1),
        (pk * uq[:, :-1]).sum(axis=1),
        (pk * uq[:, 1:]).sum(axis=1),
        (pk * qq[:, :-1]).sum(axis=1),
        (pk * qq[:, 1:]).sum(axis=1),
    )


def _bias_terms(reaches: Sequence[Reach]) -> tuple[FloatArray, FloatArray]:
    """Per segment ``(sum u_h . pi_h, sum pi_h x u_h)`` (horizontal parts, unnormalised
    pull): the angle of the mean horizontal deflection in the frames of ``pi_h``."""
    along, left = [], []
    for r in reaches:
        pull = safe_unit(r.goal - r.ee)
        along.append(float(np.sum(r.u[:, 0] * pull[:, 0] + r.u[:, 1] * pull[:, 1])))
        left.append(float(np.sum(pull[:, 0] * r.u[:, 1] - pull[:, 1] * r.u[:, 0])))
    return np.array(along), np.array(left)


def _best_bias(sums: _Sums, w: FloatArray) -> np.ndarray:
    """Index into the bias grid of the best fit per weight row (the middle of the best
    plateau: a quantised fit changes only where a tick's aim crosses a boundary)."""
    first, last = _plateau(sums, w)
    return np.asarray((first + last) // 2, dtype=np.int64)


def _plateau(sums: _Sums, w: FloatArray) -> tuple[np.ndarray, np.ndarray]:
    """The first and last index into the bias grid of the best fit per weight row: every
    turn between fits the data equally well."""
    a, n = w @ sums.a, w @ sums.n  # (R, G)
    score = a * a / np.maximum(n, 1e-300)
    best = score.max(axis=1, keepdims=True)
    top = score >= best - 1e-9 * np.maximum(np.abs(best), 1.0)
    first = np.argmax(top, axis=1)
    last = score.shape[1] - 1 - np.argmax(top[:, ::-1], axis=1)
    return np.asarray(first, dtype=np.int64), np.asarray(last, dtype=np.int64)


def _shares(reaches: Sequence[Reach]) -> tuple[float, float]:
    """Shares of the moving ticks whose deflection is within :data:`ON_DIRECTION_DEG` of an
    axis, and of an axis or diagonal."""
    u = np.concatenate([r.u for r in reaches])
    norm = np.linalg.norm(u, axis=1)
    u = u[norm > 1e-6] / norm[norm > 1e-6, None]
    if not len(u):
        return 0.0, 0.0
    cos = math.cos(math.radians(ON_DIRECTION_DEG))
    on_axis = (u @ AXIS_DIRECTIONS.T).max(axis=1) >= cos
    on_grid = (u @ GRID_DIRECTIONS.T).max(axis=1) >= cos
    return float(on_axis.mean()), float(on_grid.mean())


# --- undoing the clip ------------------------------------------------------------------


def _seen_moments(speed: FloatArray, noise: FloatArray) -> tuple[FloatArray, FloatArray]:
    """What the estimates see of the model ``(s, noise)`` through the clip: the mean
    advance and the per-axis residual sd of ``clip(s e + n)``."""
    mean, along, across = clipped_moments_batch(speed, noise)
    return mean, np.sqrt((along**2 + 2.0 * across**2) / 3.0)


def undo_clip(seen_speed: FloatArray, seen_sd: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(s, noise)`` of the model whose clipped deflection shows ``seen_speed`` and
    ``seen_sd`` (arrays; damped Newton from the seen values, ``s`` kept in the model's
    range). Where no model matches (the seen values lie beyond what a clip can produce),
    the closest one on the range's edge is taken."""
    y1 = np.asarray(seen_speed, dtype=np.float64)
    y2 = np.asarray(seen_sd, dtype=np.float64)
    s = np.clip(y1, SPEED_RANGE[0], SPEED_RANGE[1])
    lam = np.maximum(y2, 1e-6)
    for _ in range(40):
        m, sd = _seen_moments(s, lam)
        r1, r2 = m - y1, sd - y2
        if np.all(np.abs(r1) < 1e-10) and np.all(np.abs(r2) < 1e-10):
            break
        hs, hl = 1e-6, 1e-6 * np.maximum(lam, 1e-3)
        m_s, sd_s = _seen_moments(s + hs, lam)
        m_l, sd_l = _seen_moments(s, lam + hl)
        j11, j21 = (m_s - m) / hs, (sd_s - sd) / hs
        j12, j22 = (m_l - m) / hl, (sd_l - sd) / hl
        det = j11 * j22 - j12 * j21
        det = np.where(np.abs(det) < 1e-14, 1e-14, det)
        ds = (j22 * r1 - j12 * r2) / det
        dl = (-j21 * r1 + j11 * r2) / det
        s = np.clip(s - np.clip(ds, -0.2, 0.2), SPEED_RANGE[0], SPEED_RANGE[1])
        lam = np.maximum(lam - np.clip(dl, -0.5 * lam, 0.5 * lam), 1e-6)
    return s, lam


# --- the fit -----------------------------------------------------------------------------


def fit_operator(
    segments: Sequence[tuple[FloatArray, FloatArray, FloatArray]],
    params: Params,
    *,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> Fit:
    """Fit ``O`` to segments ``(ee (n, 3), u (n, 3), goal (3,))`` (module docstring);
    ``resamples = 0`` gives the point estimates alone (``certify_with`` is then them).

    Raises:
        InputError: fewer than :data:`MIN_SEGMENTS` usable segments or :data:`MIN_TICKS`
            ticks.
    """
    reaches, dropped = prepare(segments, params)
    ticks = sum(len(r.u) for r in reaches)
    if len(reaches) < MIN_SEGMENTS or ticks < MIN_TICKS:
        raise InputError(
            f"{len(reaches)} usable segments with {ticks} ticks (of {len(segments)} "
            f"segments given, {dropped} too short once the ticks before the first deflection "
            f"and within {NEAR_GOAL_STEPS:g} steps of the goal are left out); a fit needs at "
            f"least {MIN_SEGMENTS} segments and {MIN_TICKS} ticks",
            field="segments",
        )
    along, left = _bias_terms(reaches)
    fits = {h: _steering_fit(reaches, h, along, left) for h in STEERINGS}
    steering = min(fits, key=lambda h: fits[h].rss)
    chosen = fits[steering]
    ones = np.ones((1, len(reaches)))
    seen = [float(v[0]) for v in chosen.estimates(ones)]
    u_all = np.concatenate([r.u for r in reaches])
    rim = float(np.mean(np.linalg.norm(u_all, axis=1) >= RIM))
    undo = _Unclip(rim >= CLIPPED_SHARE, seen, reaches, steering, chosen.bias, params)
    s0, lam0, rho0 = (float(v[0]) for v in undo(*(np.array([x]) for x in seen)))
    v_max = params.v_max
    model = _clamped(s0, lam0 * v_max, rho0, math.degrees(chosen.bias), steering)

    intervals: dict[str, tuple[float, float]] = {}
    certify_with = model
    if resamples > 0:
        k = len(reaches)
        rng = np.random.default_rng(seed)
        w = rng.multinomial(k, np.full(k, 1.0 / k), size=resamples).astype(np.float64)
        s_r, lam_r, rho_r = undo(*chosen.estimates(w))
        low_b, high_b = chosen.bias_span(w)
        replicas = {
            "speed": (np.clip(s_r, *SPEED_RANGE),) * 2,
            "sigma": (np.clip(lam_r * v_max, *RANGES["sigma"]),) * 2,
            "rho": (np.clip(rho_r, *RHO_RANGE),) * 2,
            # quantised steering: every turn of a replica's best plateau fits it as well
            "bias_deg": (np.clip(low_b, *BIAS_RANGE_DEG), np.clip(high_b, *BIAS_RANGE_DEG)),
        }
        tail = 100 * (1 - LEVEL) / 2
        for name, (lows, highs) in replicas.items():
            lo, hi = np.percentile(lows, tail), np.percentile(highs, 100 - tail)
            at = float(getattr(model, name))  # an interval holds its own point estimate
            intervals[name] = (min(float(lo), at), max(float(hi), at))
        b_lo, b_hi = intervals["bias_deg"]
        certify_with = _clamped(
            intervals["speed"][0], intervals["sigma"][1], intervals["rho"][1],
            b_lo if abs(b_lo) > abs(b_hi) else b_hi, steering,
        )  # fmt: skip
    axis_share, grid_share = _shares(reaches)
    diagnostics: dict[str, object] = {
        "rim_share": rim,
        "undid_clip": undo.active,
        "seen": {"speed": seen[0], "sigma": seen[1] * v_max, "rho": seen[2]},
        "axis_share": axis_share,
        "grid_share": grid_share,
        "residuals": {h: f.rss for h, f in fits.items()},
        "segments_left_out": dropped,
    }
    return Fit(model, intervals, certify_with, len(reaches), ticks, diagnostics)


@dataclass(frozen=True, slots=True)
class _SteeringFit:
    """The best fit of one steering: its turn ``bias`` (radians), the per-segment sums of
    its aims (one column, or one per grid turn for quantised steering) and the residual sum
    of squares of the whole data."""

    steering: str
    bias: float
    sums: _Sums
    grid: bool
    rss: float
    along: FloatArray
    left: FloatArray
    clear: _Sums  # the sums over the ticks clear of the quantiser's boundaries

    def _columns(self, w: FloatArray) -> np.ndarray:
        if not self.grid:
            return np.zeros(len(w), dtype=np.int64)
        return _best_bias(self.clear, w)

    def estimates(self, w: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`_Sums.estimates` for weights ``w`` ``(R, K)``, each row at its own best
        turn (quantised steering: over the ticks clear of the quantiser's boundaries) or at
        the point estimate's (free: the estimates do not move with the turn to first
        order)."""
        cols = self._columns(w)
        rows = np.arange(len(w))
        picked = _Sums(*((w @ getattr(self.clear, f))[rows, cols] for f in _SUMS))
        return picked.ratios()

    def biases(self, w: FloatArray) -> FloatArray:
        """The turn each weight row estimates, radians."""
        if self.grid:
            return np.asarray(np.radians(BIAS_GRID[self._columns(w)]), dtype=np.float64)
        return np.asarray(np.arctan2(w @ self.left, w @ self.along), dtype=np.float64)

    def bias_span(self, w: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The ends of each weight row's best plateau of turns (quantised steering), degrees
        (free steering: :meth:`biases` twice)."""
        if not self.grid:
            b = np.degrees(self.biases(w))
            return b, b
        first, last = _plateau(self.clear, w)
        return BIAS_GRID[first], BIAS_GRID[last]


_SUMS = ("a", "n", "uu", "ticks", "pu", "pq", "pa", "a0", "a1", "n0", "n1")


def _steering_fit(
    reaches: Sequence[Reach], steering: str, along: FloatArray, left: FloatArray
) -> _SteeringFit:
    ones = np.ones((1, len(reaches)))
    if steering == "free":
        bias = float(np.clip(math.atan2(left.sum(), along.sum()), *np.radians(BIAS_RANGE_DEG)))
        sums, grid = _sums(reaches, steering, np.array([bias])), False
        clear = sums
        col = 0
    else:
        sums, grid = _sums(reaches, steering, np.radians(BIAS_GRID)), True
        col = int(_best_bias(sums, ones)[0])
        # the turn, s, sigma and rho from the ticks clear of that fit's boundaries
        at = float(np.radians(BIAS_GRID[col]))
        clear = _sums(reaches, steering, np.radians(BIAS_GRID), at)
        bias = float(np.radians(BIAS_GRID[int(_best_bias(clear, ones)[0])]))
    # the steering is chosen on every tick (the same data for each steering)
    a, n, uu = (float((ones @ getattr(sums, f))[0, col]) for f in ("a", "n", "uu"))
    rss = uu - a * a / max(n, 1e-300)
    return _SteeringFit(steering, bias, sums, grid, rss, along, left, clear)


class _Unclip:
    """Maps what the estimates see, ``(s, sd, rho)`` in deflection units, to the model's:
    the identity when the clip is rare, else the inverse of the binding function
    :meth:`seen` (indirect inference). The fit's own segments are simulated — same starts,
    goals and cut near the goal, :data:`SIM_REPLICAS` times, with the fitted steering and
    bias, fixed random numbers — under a candidate model with the robot's clip, and the
    same estimates taken; the model whose simulation shows what the data show is solved for
    (bounded least squares from the marginal inversion :func:`undo_clip`), and a
    resample's estimates are mapped through the binding function's linearisation there.
    It accounts for everything the estimates do not: the clip, the closed loop's aim
    turning with correlated noise, quantisation."""

    def __init__(
        self,
        active: bool,
        seen: Sequence[float],
        reaches: Sequence[Reach],
        steering: str,
        bias: float,
        params: Params,
    ) -> None:
        self.active = active
        if not active:
            return
        self._reaches, self._steering, self._bias, self._params = reaches, steering, bias, params
        self._starts = np.array([r.ee[0] for r in reaches] * SIM_REPLICAS)
        self._goals = np.array([r.goal for r in reaches] * SIM_REPLICAS)
        self._limit = np.array([4 * len(r.u) + 200 for r in reaches] * SIM_REPLICAS)
        # a simulated reach ends where its segment ended: at the distance of its last tick
        self._stop = np.array(
            [float(np.linalg.norm(r.goal - r.ee[-1])) for r in reaches] * SIM_REPLICAS
        )
        rng = np.random.default_rng(_SIM_SEED)
        self._draws = rng.standard_normal((int(self._limit.max()), len(self._starts), 3))
        s0, lam0 = undo_clip(np.array([seen[0]]), np.array([seen[1]]))
        start = np.array([float(s0[0]), float(lam0[0]), float(np.clip(seen[2], 0.0, 0.98))])
        self.theta, self._jac = self._solve(np.asarray(seen, dtype=np.float64), start)
        self._seen = np.asarray(seen, dtype=np.float64)

    def seen(self, theta: FloatArray) -> FloatArray:
        """What the estimates see of the model ``(s, noise, rho)`` in simulation."""
        return np.asarray(self.seen_many(np.asarray(theta, dtype=np.float64)[None, :])[0])

    def seen_many(self, thetas: FloatArray) -> FloatArray:
        """:meth:`seen` of several models ``(M, 3)`` at once ``(M, 3)``: their segments
        simulated side by side (the same random numbers for each, as one by one)."""
        params = self._params
        m, k = len(thetas), len(self._starts)
        speed, lam, rho = np.zeros(m), np.zeros(m), np.zeros(m)
        for i, (s, lam_i, rho_i) in enumerate(thetas):
            op = OperatorModel(
                float(np.clip(s, *SPEED_RANGE)), max(float(lam_i), 1e-6) * params.v_max,
                float(np.clip(rho_i, *RHO_RANGE)), float(np.degrees(self._bias)),
                self._steering,  # type: ignore[arg-type]
            )  # fmt: skip
            speed[i], lam[i], rho[i] = op.speed, float(lam_i), op.rho
        heading = OperatorModel(1.0, params.sigma, 0.0, float(np.degrees(self._bias)),
                                self._steering)  # type: ignore[arg-type]  # fmt: skip
        # model-major rows: model i's segments are rows i k ... (i + 1) k - 1
        speed_r, lam_r, rho_r = (np.repeat(v, k)[:, None] for v in (speed, lam, rho))
        gain_r = np.sqrt(1.0 - rho_r**2)
        goals = np.tile(self._goals, (m, 1))
        stop, limit = np.tile(self._stop, m), np.tile(self._limit, m)
        step = params.v_max * params.dt
        x = np.tile(self._starts, (m, 1))
        alive = np.ones(len(x), dtype=bool)
        e = np.zeros_like(x)
        xs, us, live = [], [], []
        for t in range(int(self._limit.max())):
            w = np.tile(self._draws[t], (m, 1)) * lam_r
            e = w if t == 0 else rho_r * e + gain_r * w
            u = speed_r * aim(x, goals, heading) + e
            u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1.0)
            xs.append(x.copy())
            us.append(u)
            live.append(alive.copy())
            x = x + np.where(alive[:, None], step * u, 0.0)
            alive &= (np.linalg.norm(goals - x, axis=1) >= stop) & (t + 1 < limit)
            if not alive.any():
                break
        total = _simulated_totals(
            np.array(xs), np.array(us), np.array(live), goals, self._steering, self._bias, m
        )
        return np.stack(total.ratios(), axis=-1)

    def _solve(self, target: FloatArray, start: FloatArray) -> tuple[FloatArray, FloatArray]:
        from scipy.optimize import least_squares

        lo = np.array([SPEED_RANGE[0], 1e-3, RHO_RANGE[0]])
        hi = np.array([SPEED_RANGE[1], 10.0, RHO_RANGE[1]])
        result = least_squares(
            lambda th: self.seen(th) - target, np.clip(start, lo, hi), jac=self.jacobian,
            bounds=(lo, hi), xtol=1e-4, ftol=1e-10, max_nfev=30,
        )  # fmt: skip
        theta = np.asarray(result.x, dtype=np.float64)
        return theta, self.jacobian(theta)

    def jacobian(self, theta: FloatArray) -> FloatArray:
        """Central differences of :meth:`seen` with steps of 0.01 in each of ``(s, noise,
        rho)`` (one-sided at a bound): wide enough to average over the quantised aims'
        steps, small against the parameters' ranges."""
        lo = np.array([SPEED_RANGE[0], 1e-3, RHO_RANGE[0]])
        hi = np.array([SPEED_RANGE[1], 10.0, RHO_RANGE[1]])
        h = np.eye(3) * 0.01
        up, down = np.minimum(theta + h, hi), np.maximum(theta - h, lo)  # (3, 3): row i
        seen = self.seen_many(np.concatenate([up, down]))
        widths = np.maximum(np.diag(up) - np.diag(down), 1e-12)
        return np.asarray((seen[:3] - seen[3:]).T / widths, dtype=np.float64)

    def __call__(
        self, speed: FloatArray, sd: FloatArray, rho: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        if not self.active:
            return speed, sd, rho
        delta = np.stack([speed, sd, rho], axis=-1) - self._seen  # (R, 3)
        step = np.linalg.lstsq(self._jac, delta.T, rcond=None)[0].T
        theta = self.theta + step
        return theta[..., 0], np.maximum(theta[..., 1], 1e-6), theta[..., 2]


def _simulated_totals(
    xs: FloatArray,
    us: FloatArray,
    live: np.ndarray,
    goals: FloatArray,
    steering: str,
    bias: float,
    groups: int = 1,
) -> _Sums:
    """:func:`_sums` at the one turn ``bias`` (clear of the boundaries turned by it), summed
    over simulated segments held as ``(T, K, 3)`` arrays: segment ``k`` is its ticks
    ``live[:, k]`` (a prefix), every lag-1 pair a pair, and only segments of two ticks or
    more count — the same totals as :func:`_sums` of the segments one by one, in a few
    array operations (the binding function's share of a fit was ~60 %). ``groups``: the
    segments are that many equal runs (models), each totalled on its own ``(groups,)``."""
    ticks = live & (live.sum(axis=0) >= 2)[None, :]  # (T, K)
    pull = safe_unit(goals[None, :, :] - xs)
    turned = rotate_z(pull, bias)
    q = quantise(turned, steering)
    if steering != "free":
        radius = np.linalg.norm(goals[None, :, :] - xs, axis=-1)
        ticks = ticks & (boundary_distance(turned, steering, radius) >= BOUNDARY_M)
    pairs = ticks[:-1] & ticks[1:]  # of two counted ticks of one segment
    uq = np.einsum("tkd,tkd->tk", us, q)
    qq = np.einsum("tkd,tkd->tk", q, q)
    cross = np.einsum("tkd,tkd->tk", us[:-1], q[1:]) + np.einsum("tkd,tkd->tk", q[:-1], us[1:])

    def total(values: FloatArray, mask: np.ndarray) -> FloatArray:
        kept = np.where(mask, values, 0.0)
        return np.asarray(kept.reshape(len(kept), groups, -1).sum(axis=(0, 2)), np.float64)

    return _Sums(
        total(uq, ticks),
        total(qq, ticks),
        total(np.einsum("tkd,tkd->tk", us, us), ticks),
        total(np.ones(ticks.shape), ticks),
        total(np.einsum("tkd,tkd->tk", us[:-1], us[1:]), pairs),
        total(cross, pairs),
        total(np.einsum("tkd,tkd->tk", q[:-1], q[1:]), pairs),
        total(uq[:-1], pairs),
        total(uq[1:], pairs),
        total(qq[:-1], pairs),
        total(qq[1:], pairs),
    )


#: Copies of the fit's segments simulated by the binding function, and its random seed.
SIM_REPLICAS = 8
_SIM_SEED = 20261203


def _clamped(
    speed: float, sigma: float, rho: float, bias_deg: float, steering: str
) -> OperatorModel:
    """An :class:`OperatorModel` with every number clamped into the model's ranges."""
    return OperatorModel(
        float(np.clip(speed, *SPEED_RANGE)),
        float(np.clip(sigma, *RANGES["sigma"])),
        float(np.clip(rho, *RHO_RANGE)),
        float(np.clip(bias_deg, *BIAS_RANGE_DEG)),
        steering,  # type: ignore[arg-type]
    )
