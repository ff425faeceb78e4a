"""Kaplan–Meier and the group bootstrap of the eval report, against hand-computed values."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.sim.statistics import (
    bootstrap_ci,
    bootstrap_ci_counts,
    kaplan_meier,
    km_counts,
    km_median,
    km_median_counts,
    percentile_interval,
    resample_counts,
)


def test_kaplan_meier_with_censoring_by_hand() -> None:
    # at 1: 5 at risk, 1 event -> 4/5; 2: censored; at 3: 3 at risk, 1 event -> * 2/3;
    # at 4: 2 at risk, 1 event -> * 1/2; 5: censored
    t, s = kaplan_meier([1, 2, 3, 4, 5], [1, 0, 1, 1, 0])
    np.testing.assert_array_equal(t, [1, 3, 4])
    np.testing.assert_allclose(s, [0.8, 0.8 * 2 / 3, 0.8 * 2 / 3 * 1 / 2])
    # 0.8, 0.533 > 0.5, then 0.267: the median is 4
    assert km_median([1, 2, 3, 4, 5], [1, 0, 1, 1, 0]) == 4.0
    # input order does not matter
    assert km_median([5, 4, 3, 2, 1], [0, 1, 1, 0, 1]) == 4.0


def test_kaplan_meier_ties_put_the_event_before_the_censoring() -> None:
    # at 2: 3 at risk (the one censored at 2 included), 1 event -> 2/3; at 3: 1 at risk -> 0
    t, s = kaplan_meier([2, 2, 3], [1, 0, 1])
    np.testing.assert_array_equal(t, [2, 3])
    np.testing.assert_allclose(s, [2 / 3, 0.0])
    # two events at one time
    t, s = kaplan_meier([1, 1, 2, 3], [1, 1, 0, 1])
    np.testing.assert_allclose(s, [0.5, 0.0])
    assert km_median([1, 1, 2, 3], [1, 1, 0, 1]) == 1.0


def test_without_censoring_the_median_is_where_half_have_had_the_event() -> None:
    _, s = kaplan_meier([3, 1, 2, 4], [1, 1, 1, 1])
    np.testing.assert_allclose(s, [0.75, 0.5, 0.25, 0.0])
    assert km_median([3, 1, 2, 4], [1, 1, 1, 1]) == 2.0  # survival exactly 0.5 counts
    assert km_median([7.5], [True]) == 7.5


def test_median_is_none_when_all_censored_or_never_half() -> None:
    t, s = kaplan_meier([1, 2, 3], [0, 0, 0])
    assert t.size == 0 and s.size == 0
    assert km_median([1, 2, 3], [0, 0, 0]) is None
    assert km_median([], []) is None
    # 0.75 after the only event, then censored: the median is beyond the longest time
    assert km_median([1, 2, 3, 4], [1, 0, 0, 0]) is None
    with pytest.raises(InputError, match="2 times but 1 event flags"):
        km_median([1, 2], [1])


def test_weighted_group_counts_pool_the_groups() -> None:
    """Drawing group A twice and B once is the KM of A's subjects twice and B's once."""
    a = ([1.0, 4.0, 6.0], [True, False, True])
    b = ([2.0, 3.0, 8.0, 9.0], [False, True, True, False])
    u, d, r = km_counts([a, b])
    w = np.array([[2.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    got = km_median_counts(u, w @ d, w @ r)
    pooled = (a[0] * 2 + b[0], a[1] * 2 + b[1])
    assert got[0] == km_median(*pooled)
    assert got[1] == km_median(*a)
    assert got[2] == km_median(*b)
    _, s = kaplan_meier(*pooled)
    assert s[-1] < 0.5  # a reached median, not a vacuous one


def test_resample_counts_draw_every_group_with_replacement() -> None:
    c = resample_counts(7, np.random.default_rng(0), 500)
    assert c.shape == (500, 7)
    np.testing.assert_array_equal(c.sum(axis=1), 7)
    assert (c == 0).any() and (c > 1).any()  # replacement: some left out, some twice
    # every group is drawn about as often as the others
    np.testing.assert_allclose(c.mean(axis=0), 1.0, atol=0.15)


def test_percentile_interval_keeps_inf_and_drops_nan() -> None:
    v = np.arange(1.0, 101.0)  # 1..100: central 90 % from the 6th to the 95th value
    assert percentile_interval(v, 0.9) == (6.0, 95.0)
    v[-10:] = np.inf
    assert percentile_interval(v, 0.9) == (6.0, math.inf)
    assert percentile_interval([np.nan, 4.0, 2.0, 1.0, 3.0], 0.5) == (2.0, 3.0)
    assert percentile_interval([np.nan, np.nan]) is None


def _groups(n: int, rng: np.random.Generator) -> list[list[float]]:
    """Groups of 20 Bernoulli picks with a per-group rate (groups differ)."""
    rates = rng.uniform(0.3, 0.9, n)
    return [list((rng.random(20) < p).astype(float)) for p in rates]


def _pooled_mean(groups: Sequence[list[float]]) -> float | None:
    return float(np.mean([x for g in groups for x in g]))


def test_bootstrap_interval_contains_the_estimate_and_shrinks_with_more_groups() -> None:
    data = np.random.default_rng(1)
    few, many = _groups(8, data), _groups(200, data)
    width = {}
    for name, groups in (("few", few), ("many", many)):
        ci = bootstrap_ci(groups, _pooled_mean, np.random.default_rng(2), n=500)
        assert ci is not None
        lo, hi = ci
        point = _pooled_mean(groups)
        assert point is not None and lo <= point <= hi
        assert lo < hi
        width[name] = hi - lo
    # the spread of a mean over groups falls like 1 / sqrt(groups): 200 / 8 -> 5 times
    assert width["many"] < width["few"] / 3


def test_bootstrap_is_seeded_and_the_vectorised_form_agrees() -> None:
    groups = _groups(12, np.random.default_rng(3))
    a = bootstrap_ci(groups, _pooled_mean, np.random.default_rng(7), n=300)
    b = bootstrap_ci(groups, _pooled_mean, np.random.default_rng(7), n=300)
    c = bootstrap_ci(groups, _pooled_mean, np.random.default_rng(8), n=300)
    assert a == b and a != c
    sums = np.array([sum(g) for g in groups])
    sizes = np.array([float(len(g)) for g in groups])

    def vectorised(counts: np.ndarray) -> np.ndarray:
        result: np.ndarray = (counts @ sums) / (counts @ sizes)
        return result

    v = bootstrap_ci_counts(len(groups), vectorised, np.random.default_rng(7), n=300)
    assert v is not None and a is not None
    np.testing.assert_allclose(v, a)


def test_bootstrap_needs_two_groups_and_a_defined_statistic() -> None:
    rng = np.random.default_rng(0)
    assert bootstrap_ci([[1.0, 0.0]], _pooled_mean, rng) is None
    assert bootstrap_ci([[1.0], [0.0]], lambda g: None, rng, n=50) is None
    # undefined in some resamples only: those are left out
    ci = bootstrap_ci([[1.0], [2.0]], lambda g: None if len(set(map(tuple, g))) == 1 else 1.5,
                      rng, n=200)  # fmt: skip
    assert ci == (1.5, 1.5)
