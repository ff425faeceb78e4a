"""Statistics of the protocol's report (method.md §9): Kaplan–Meier, the group bootstrap and
the exact binomial bound of a rate at 0 % or 100 %.

Numpy (and, for the exact bound, scipy's incomplete beta). Times to a commit are
right-censored (a pick that ends without one tells only that the commit did not come before
its end), so their median is the Kaplan–Meier median.
Picks of one layout are not independent (same geometry), so intervals resample *groups*
(layouts, or optimisation runs) with replacement and recompute the statistic over the pooled
picks of the resampled groups (a percentile bootstrap).

Undefined values are ``nan`` (e.g. a mean over no commits); a Kaplan–Meier median that is
never reached (the survival stays above one half) is ``inf``.

A rate where every pick succeeded (or none did) has a bootstrap interval of one point,
``[100, 100]``, whatever the number of picks: no resample can hold a failure that never
happened. :func:`rate_interval` gives such a rate the exact (Clopper–Pearson) bound on its
``k`` of ``n`` picks instead (:func:`~legws_daemon.core.montecarlo.clopper_pearson`, picks
taken as independent), and keeps the bootstrap over groups, which accounts for the picks of
one layout being alike, for every other rate.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.montecarlo import clopper_pearson
from legws_daemon.errors import InputError

T = TypeVar("T")

#: Resamples of a bootstrap interval.
RESAMPLES = 2000
#: Coverage of the intervals.
LEVEL = 0.95


def _sample(times: ArrayLike, observed: ArrayLike) -> tuple[FloatArray, IntArray]:
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    o = np.asarray(observed, dtype=bool).reshape(-1)
    if t.shape != o.shape:
        raise InputError(f"{t.size} times but {o.size} event flags")
    if not np.all(np.isfinite(t)):
        raise InputError("times must be finite")
    return t, o.astype(np.int64)


def km_counts(
    samples: Sequence[tuple[ArrayLike, ArrayLike]],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sufficient statistics of the Kaplan–Meier estimate, per group.

    Args:
        samples: per group, ``(times, observed)``: each subject's time and whether its
            event happened then (``False``: censored then).

    Returns:
        ``(u, d, r)``: the distinct event times over all groups (ascending, ``(K,)``), and
        per group (``(G, K)``) the events at each and the subjects at risk just before each
        (time ``>= u[k]``: a subject censored at an event time is still at risk then).
        Weighted sums of the rows are the statistics of the pooled, weighted groups.
    """
    data = [_sample(t, o) for t, o in samples]
    events = [t[o == 1] for t, o in data]
    u = np.unique(np.concatenate(events)) if events else np.zeros(0)
    d = np.zeros((len(data), u.size))
    r = np.zeros((len(data), u.size))
    for g, (t, o) in enumerate(data):
        if u.size == 0:
            break
        # events at each distinct time: the times are exactly those of u
        idx = np.searchsorted(u, t[o == 1])
        np.add.at(d[g], idx, 1.0)
        # at risk at u[k]: subjects with time >= u[k]
        r[g] = t.size - np.searchsorted(np.sort(t), u, side="left")
    return u, d, r


def km_survival(d: FloatArray, r: FloatArray) -> FloatArray:
    """Survival just after each event time from the (weighted) counts ``d``, ``r`` of
    :func:`km_counts` (``(..., K)``); a time with nobody at risk changes nothing."""
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(r > 0, 1.0 - d / np.where(r > 0, r, 1.0), 1.0)
    out: FloatArray = np.cumprod(factor, axis=-1, dtype=np.float64)
    return out


def km_median_counts(u: FloatArray, d: FloatArray, r: FloatArray) -> FloatArray:
    """The Kaplan–Meier median (the first event time whose survival is ``<= 0.5``, up to
    rounding) of each row of ``d``, ``r`` (``(B, K)``, ``u``: ``(K,)``); ``inf`` where it
    is never reached."""
    d2, r2 = np.atleast_2d(d), np.atleast_2d(r)
    if u.size == 0:
        return np.full(d2.shape[0], np.inf)
    reached = km_survival(d2, r2) <= 0.5 + 1e-12
    out: FloatArray = np.where(reached.any(axis=-1), u[np.argmax(reached, axis=-1)], np.inf)
    return out


def kaplan_meier(times: ArrayLike, observed: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """The Kaplan–Meier estimate of the survival function.

    Args:
        times: each subject's time (finite).
        observed: whether its event happened then (``False``: censored then; at a tie an
            event comes before a censoring, as usual).

    Returns:
        ``(t, survival)``: the distinct event times, ascending, and the estimated
        probability that the event has not happened yet just after each (a step function,
        1 before ``t[0]``). Empty when no event was observed.
    """
    u, d, r = km_counts([(times, observed)])
    return u, km_survival(d[0], r[0])


def km_median(times: ArrayLike, observed: ArrayLike) -> float | None:
    """The Kaplan–Meier median: the first event time at which the survival is ``<= 0.5``;
    ``None`` when it never falls that far (more than half of the subjects are censored
    before their event: the median is beyond the longest time observed)."""
    u, d, r = km_counts([(times, observed)])
    m = float(km_median_counts(u, d, r)[0])
    return m if math.isfinite(m) else None


def resample_counts(n_groups: int, rng: np.random.Generator, n: int = RESAMPLES) -> FloatArray:
    """``(n, n_groups)``: how often each group is drawn in each of ``n`` resamples of
    ``n_groups`` groups with replacement (every row sums to ``n_groups``)."""
    idx = rng.integers(0, n_groups, size=(n, n_groups))
    flat = (np.arange(n)[:, None] * n_groups + idx).reshape(-1)
    counts = np.bincount(flat, minlength=n * n_groups).reshape(n, n_groups)
    return counts.astype(np.float64)


def percentile_interval(values: ArrayLike, level: float = LEVEL) -> tuple[float, float] | None:
    """The central ``level`` interval of the bootstrap ``values`` (order statistics, no
    interpolation: ``inf`` stays a bound). ``nan`` (the statistic is undefined in that
    resample) is left out; ``None`` when nothing is left."""
    v = np.sort(np.asarray(values, dtype=np.float64).reshape(-1))
    v = v[~np.isnan(v)]
    if v.size == 0:
        return None
    tail = (1.0 - level) / 2.0
    lo = min(math.floor(tail * v.size + 1e-9), v.size - 1)
    hi = max(math.ceil((1.0 - tail) * v.size - 1e-9) - 1, lo)
    return float(v[lo]), float(v[hi])


def bootstrap_ci_counts(
    n_groups: int,
    statistic: Callable[[FloatArray], FloatArray],
    rng: np.random.Generator,
    n: int = RESAMPLES,
    level: float = LEVEL,
) -> tuple[float, float] | None:
    """Percentile bootstrap over groups, vectorised.

    Args:
        n_groups: how many groups (layouts, optimisation runs).
        statistic: maps a ``(B, n_groups)`` matrix of how often each group is drawn to the
            ``(B,)`` statistic of each resample (``nan`` where undefined); it should be
            computed from per-group sums weighted by those counts.
        rng: the generator (seed it: same seed, same interval).
        n: resamples; level: coverage.

    Returns:
        ``(low, high)``, or ``None`` with fewer than two groups (no spread to resample) or
        when the statistic is undefined in every resample.
    """
    if n_groups < 2:
        return None
    return percentile_interval(statistic(resample_counts(n_groups, rng, n)), level)


def bootstrap_ci(
    groups: Sequence[T],
    statistic: Callable[[Sequence[T]], float | None],
    rng: np.random.Generator,
    n: int = RESAMPLES,
    level: float = LEVEL,
) -> tuple[float, float] | None:
    """Percentile bootstrap interval of ``statistic`` resampling ``groups`` with
    replacement (each resample: ``len(groups)`` groups; the statistic sees the drawn groups,
    a group drawn twice twice). ``statistic`` returns ``None`` where undefined.

    Draws the same resamples as :func:`bootstrap_ci_counts` from the same ``rng`` state, so
    the two agree on one statistic; this one calls ``statistic`` ``n`` times.
    """
    g = len(groups)

    def each(counts: FloatArray) -> FloatArray:
        out = np.empty(counts.shape[0])
        for b, row in enumerate(counts):
            drawn = [groups[i] for i in range(g) for _ in range(int(row[i]))]
            value = statistic(drawn)
            out[b] = np.nan if value is None else value
        return out

    return bootstrap_ci_counts(g, each, rng, n, level)


def ratio_interval(
    numerator: ArrayLike,
    denominator: ArrayLike,
    rng: np.random.Generator,
    n: int = RESAMPLES,
    level: float = LEVEL,
) -> tuple[float, float] | None:
    """Percentile bootstrap interval of a pooled ratio ``sum(numerator) / sum(denominator)``
    over groups (``(G,)`` per-group sums, e.g. completed and acted-on picks per layout),
    resampling the groups with replacement; ``None`` as :func:`bootstrap_ci_counts`."""
    num = np.asarray(numerator, dtype=np.float64).reshape(-1)
    den = np.asarray(denominator, dtype=np.float64).reshape(-1)
    if num.shape != den.shape:
        raise InputError(f"{num.size} numerators but {den.size} denominators")

    def ratio(counts: FloatArray) -> FloatArray:
        top, bottom = counts @ num, counts @ den
        with np.errstate(divide="ignore", invalid="ignore"):
            out: FloatArray = np.where(bottom > 0, top / np.where(bottom > 0, bottom, 1), np.nan)
        return out

    return bootstrap_ci_counts(num.size, ratio, rng, n, level)


#: How a rate's interval was obtained (:class:`RateInterval`).
IntervalKind = Literal["bootstrap", "at_least", "at_most", "no_spread", "none"]


@dataclass(frozen=True, slots=True)
class RateInterval:
    """A rate ``k / n`` with its 95 % interval.

    Attributes:
        k, n: the picks that succeeded, of how many.
        kind: ``"at_least"`` (``k = n``: ``low`` is the Clopper–Pearson lower bound, ``high``
            is 1), ``"at_most"`` (``k = 0``: ``high`` is the Clopper–Pearson upper bound,
            ``low`` 0), ``"bootstrap"`` (``low``, ``high``: the percentile bootstrap over
            groups), ``"no_spread"`` (``0 < k < n`` and the bootstrap is one point: every
            group has the same rate, so resampling them says nothing; no interval is given),
            ``"none"`` (no bootstrap: a single group; or no picks).
        low, high: the bounds, or ``None``.
    """

    k: int
    n: int
    kind: IntervalKind
    low: float | None
    high: float | None

    @property
    def rate(self) -> float | None:
        return self.k / self.n if self.n else None


def rate_interval(
    k: int,
    n: int,
    bootstrap: Sequence[float | None] | None = None,
    level: float = LEVEL,
) -> RateInterval:
    """The interval of a rate of ``k`` successes in ``n`` picks (see the module docstring):
    the Clopper–Pearson bound at level ``level`` where ``k = n`` or ``k = 0``, else the
    ``bootstrap`` interval ``(low, high)`` over groups (``None``: none was made)."""
    if n < 0 or not 0 <= k <= max(n, 0):
        raise InputError(f"need 0 <= k <= n, got {k}/{n}")
    if n == 0:
        return RateInterval(k, n, "none", None, None)
    if k == n:
        return RateInterval(k, n, "at_least", clopper_pearson(k, n, level)[0], 1.0)
    if k == 0:
        return RateInterval(k, n, "at_most", 0.0, clopper_pearson(k, n, level)[1])
    if bootstrap is None or bootstrap[0] is None or bootstrap[1] is None:
        return RateInterval(k, n, "none", None, None)
    low, high = float(bootstrap[0]), float(bootstrap[1])
    if low == high:
        return RateInterval(k, n, "no_spread", None, None)
    return RateInterval(k, n, "bootstrap", low, high)


__all__ = [
    "LEVEL",
    "RESAMPLES",
    "IntervalKind",
    "RateInterval",
    "bootstrap_ci",
    "bootstrap_ci_counts",
    "kaplan_meier",
    "km_counts",
    "km_median",
    "km_median_counts",
    "km_survival",
    "percentile_interval",
    "rate_interval",
    "ratio_interval",
    "resample_counts",
]
