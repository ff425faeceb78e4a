"""The analysis on data with known effects: the mixed model recovers them within its
intervals, the GEE sees a difference in success, power grows with participants."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from legws_daemon.core.montecarlo import clopper_pearson
from legws_daemon.study.analysis import (
    fit_mixed,
    fit_success,
    power,
    questionnaire_table,
)


def _study(
    effects: dict[str, float],
    people: int = 12,
    trials: int = 6,
    seed: int = 0,
    period: float = 0.0,
    success: dict[str, float] | None = None,
) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    names = list(effects)
    rows = []
    for p in range(people):
        u = rng.normal(0, 2.0)
        order = [names[(p + k) % len(names)] for k in range(len(names))]  # a Latin square
        for pos, c in enumerate(order, start=1):
            tlx = 40 + 3 * effects[c] + rng.normal(0, 3)
            for _ in range(trials):
                rows.append({
                    "participant": f"P{p:02d}", "kind": "trial", "condition": c,
                    "position": pos, "protocol": "synthetic",
                    "time_to_task_s": 20 + u + effects[c] + period * (pos - 1) + rng.normal(0, 1.5),
                    "commit_time_s": 5 + rng.normal(0, 1.0),
                    "correct": bool(rng.random() < (success or {}).get(c, 1.0)),
                    "tlx_raw": tlx, "likert_1": 4, "likert_2": 5,
                })  # fmt: skip
    return pd.DataFrame(rows)


def test_the_mixed_model_recovers_planted_condition_and_period_effects() -> None:
    df = _study({"a": 0.0, "b": 3.0, "c": -1.5}, period=0.8)
    m = fit_mixed(df, "time_to_task_s", "a")
    assert m is not None and m.converged and m.reference == "a"
    for c, truth in (("b", 3.0), ("c", -1.5)):
        e = m.conditions[c]
        assert e.low < truth < e.high and e.p < 0.05
    assert [e.term for e in m.positions] == ["position 2", "position 3"]
    assert m.positions[0].low < 0.8 < m.positions[0].high
    assert m.positions[1].low < 1.6 < m.positions[1].high
    # the participant and residual variances, near what was drawn (2² and 1.5²)
    assert 0.8 < m.group_var < 12 and 1.5 < m.residual_var < 3.2
    # no effect: commit time
    k = fit_mixed(df, "commit_time_s", "a")
    assert k is not None and all(e.low < 0 < e.high for e in k.conditions.values())


def test_too_little_data_is_no_model() -> None:
    df = _study({"a": 0.0, "b": 1.0}, people=1)
    assert fit_mixed(df, "time_to_task_s", "a") is None
    assert fit_mixed(_study({"a": 0.0, "b": 1.0}), "time_to_task_s", "zzz") is None


def test_success_gets_odds_ratios_when_some_trials_fail() -> None:
    df = _study({"a": 0.0, "b": 0.0}, people=16, trials=10, success={"a": 0.95, "b": 0.6})
    s = fit_success(df, "a")
    assert s["model"] is not None
    ratio = s["model"]["odds_ratios"]["b"]
    assert ratio["high"] < 1 and ratio["p"] < 0.05
    assert s["rates"]["a"]["rate"] > s["rates"]["b"]["rate"]


def test_when_every_trial_succeeds_clopper_pearson_stands_in_for_the_model() -> None:
    s = fit_success(_study({"a": 0.0, "b": 0.0}), "a")
    assert s["model"] is None and s["why"] == "every trial succeeded"
    r = s["rates"]["a"]
    assert r["k"] == r["n"] == 72 and r["high"] == 1.0
    assert r["low"] == pytest.approx(0.025 ** (1 / 72))  # the exact bound of n of n


@pytest.mark.parametrize(("k", "n"), [(0, 10), (3, 10), (10, 10), (50, 100)])
def test_clopper_pearson_covers_the_rate(k: int, n: int) -> None:
    lo, hi = clopper_pearson(k, n)
    assert 0 <= lo <= k / n <= hi <= 1
    if 0 < k < n:
        from scipy.stats import binom

        # the defining tails: P(X >= k | lo) = P(X <= k | hi) = 2.5 %
        assert binom.sf(k - 1, n, lo) == pytest.approx(0.025, rel=1e-6)
        assert binom.cdf(k, n, hi) == pytest.approx(0.025, rel=1e-6)


def test_questionnaires_are_one_answer_per_participant_and_condition() -> None:
    df = _study({"a": 0.0, "b": 4.0})
    q = questionnaire_table(df)
    assert len(q) == 24 and set(q["likert"]) == {4.5}
    m = fit_mixed(q, "tlx_raw", "a", period=False)
    assert m is not None and m.conditions["b"].low < 12 < m.conditions["b"].high


def test_power_grows_with_participants_and_is_low_without_an_effect() -> None:
    df = _study({"a": 0.0, "b": 1.0}, people=8)
    m = fit_mixed(df, "time_to_task_s", "a", period=False)
    assert m is not None
    curve = power(m, ["a", "b"], trials=6, grid=[2, 8, 24], sims=40, seed=1)["b"]
    assert curve[2] <= curve[8] <= curve[24] and curve[24] >= 0.9
    null = fit_mixed(_study({"a": 0.0, "b": 0.0}, people=8), "time_to_task_s", "a", period=False)
    assert null is not None
    flat = power(type(null)(**{**null.__dict__, "conditions": {}}), ["a", "b"], 6, [8], 60, seed=2)[
        "b"
    ]
    assert flat[8] < 0.2 and not math.isnan(flat[8])  # about alpha
