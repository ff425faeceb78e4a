"""Caps where cost grows, and parameter ranges whose ends keep the maths finite.

* goal sets hold at most ``MAX_GOALS`` goals, refused before anything quadratic is built;
* the commit certificate splits one large layout by its true goals, with the same result;
* the Monte Carlo keeps its arrays within a memory budget by chunks of whole random
  streams, with results that do not depend on the chunking, and refuses runs beyond its
  trial and work caps in one line;
* alpha, beta and sigma are refused outside ranges where every result is finite, and no
  computation at the ends of the ranges warns.
"""

from __future__ import annotations

import json
import math
import time
import tracemalloc
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import asdict
from typing import Any

import numpy as np
import pytest

from legws_daemon.core import commit as commit_mod
from legws_daemon.core import montecarlo as mc
from legws_daemon.core.certificate import certify, upper_quantile
from legws_daemon.core.commit import (
    certify_commit,
    clipped_user,
    commit_batch,
    commit_chance_batch,
    commit_time_batch,
    unclipped_user,
)
from legws_daemon.core.geometry import Pose
from legws_daemon.core.goals import MAX_GOALS, GoalSet
from legws_daemon.core.params import RANGES, Params
from legws_daemon.core.user_model import deflection, noise
from legws_daemon.errors import InputError

DOWN = [0.0, 1.0, 0.0, 0.0]
HOME = np.array([0.55, 0.0, 0.30])
X0 = Pose(HOME, np.array(DOWN))


@pytest.fixture(autouse=True)
def _warnings_are_errors() -> Iterator[None]:
    """No RuntimeWarning (overflow, invalid value) anywhere in these tests."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def table_goals(m: int, seed: int = 0, *, radius: float | None = None) -> GoalSet:
    """``m`` goals on the table (or on a sphere of ``radius`` around the start)."""
    rng = np.random.default_rng(seed)
    if radius is None:
        pos = np.c_[rng.uniform(0.3, 0.85, m), rng.uniform(-0.45, 0.45, m), rng.uniform(0, 0.1, m)]
    else:
        d = rng.normal(size=(m, 3))
        pos = HOME + radius * d / np.linalg.norm(d, axis=1)[:, None]
    return GoalSet.build([f"g{i}" for i in range(m)], pos, [DOWN] * m, X0)


# --- the number of goals ------------------------------------------------------------------


def test_more_goals_than_the_cap_are_refused_before_any_array() -> None:
    names = [f"g{i}" for i in range(20_000)]
    tracemalloc.start()
    start = time.perf_counter()
    with pytest.raises(InputError, match=rf"goals: expected at most {MAX_GOALS} goals, got 20000"):
        GoalSet(tuple(names), np.zeros((1, 3)), np.zeros((1, 4)), np.ones(1, np.int64), X0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert time.perf_counter() - start < 0.5
    assert peak < 2**20  # nothing of size M^2 (20,000 goals: 8.94 GiB) was allocated


def test_the_largest_goal_set_is_cheap() -> None:
    """At the cap, the certificate and the commit certificate take well under a second and
    stay within ~100 MiB (measured 0.3 s and 85 MiB)."""
    goals = table_goals(MAX_GOALS)
    tracemalloc.start()
    start = time.perf_counter()
    cert = certify(goals, Params())
    commit = certify_commit(goals, Params())
    seconds = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(cert.pairs) == MAX_GOALS * (MAX_GOALS - 1)
    assert len(commit.goals) == MAX_GOALS
    assert seconds < 10  # generous for a loaded CI machine
    assert peak < 200 * 2**20
    with pytest.raises(InputError, match="at most 64 goals, got 65"):
        table_goals(MAX_GOALS + 1)


# --- the commit certificate, split by true goals -----------------------------------------


def _commit_everything(goals: GoalSet, params: Params) -> list[np.ndarray]:
    pos, rot = goals.positions[None], goals.rotations[None]
    args = (HOME, X0.rotation, pos, rot, goals.symmetry, params)
    out: list[np.ndarray] = []
    for form in ("min", "sum"):
        for user in (unclipped_user(params), clipped_user(params)):
            b = commit_batch(*args, user, form)
            out += [b.fraction, b.step, b.slack_at_arrival, b.wrong_commit_slack, b.objective]
    out.append(commit_chance_batch(*args, clipped_user(params)))
    out.append(commit_time_batch(*args, clipped_user(params)))
    return out


@pytest.mark.parametrize("cost", ["dragan", "ratio"])
def test_commit_certificate_split_by_true_goals_is_identical(
    monkeypatch: pytest.MonkeyPatch, cost: str
) -> None:
    goals = table_goals(7, seed=3)
    params = Params(cost=cost)  # type: ignore[arg-type]
    whole = _commit_everything(goals, params)
    monkeypatch.setattr(commit_mod, "CHUNK_ELEMENTS", 500)  # below one layout: split by rows
    assert len(list(commit_mod._pieces(np.full((1, 7), 200)))) == 7
    split = _commit_everything(goals, params)
    for a, b in zip(whole, split, strict=True):
        np.testing.assert_array_equal(a, b)


# --- Monte Carlo: memory budget, streams, caps --------------------------------------------


def _asdicts(result: Mapping[Any, Any]) -> dict[str, Any]:
    return {k: _asdicts(v) if isinstance(v, dict) else asdict(v) for k, v in result.items()}


def test_up_to_one_stream_draws_like_one_loop_over_every_trial() -> None:
    """A run of at most STREAM_TRIALS trials draws its noise exactly as before the chunking:
    one (M, N, 3) draw per step from the generator passed in."""
    goals = table_goals(3, seed=1)
    params = Params()
    n = 300
    states = mc.simulate_user(goals, params, n, np.random.default_rng(11))
    rng = np.random.default_rng(11)
    steps = states.steps
    x = np.broadcast_to(HOME, (3, n, 3)).copy()
    for t in range(int(steps.max())):
        u = deflection(x, goals.positions[:, None, :], noise(rng, (3, n), params.sigma, 0.05))
        x += np.where((t < steps)[:, None, None], params.v_max * params.dt * u, 0.0)
    np.testing.assert_array_equal(states.positions, x)


def test_monte_carlo_does_not_depend_on_the_chunking(monkeypatch: pytest.MonkeyPatch) -> None:
    """Several random streams, simulated all at once or a stream at a time with the observer
    evaluated a few trials at a time: the same numbers for the same seed."""
    monkeypatch.setattr(mc, "STREAM_TRIALS", 64)
    goals = table_goals(4, seed=2, radius=0.06)
    params = Params()
    n = 64 * 3 + 5  # four streams, the last one short
    by_step: list[int | None] = [None, 5, None, 3]

    def run() -> tuple[Any, ...]:
        horizon = mc.monte_carlo(goals, params, n, seed=4, costs=("dragan", "ratio"))
        commits = mc.monte_carlo_commit(goals, params, n, np.random.default_rng(8), by_step)
        rolls = mc.simulate_commits(goals, params, n, np.random.default_rng(8))["dragan"]
        clipped = mc.monte_carlo(goals, params, n, seed=4, clip_speed=True)
        return _asdicts(horizon), _asdicts(commits), rolls, _asdicts(clipped)

    monkeypatch.setattr(mc, "MEMORY_BUDGET", 2**40)
    whole = run()
    assert len(list(mc._chunks(mc._streams(np.random.default_rng(0), n), 4))) == 1
    monkeypatch.setattr(mc, "MEMORY_BUDGET", 1)  # a stream per chunk, a trial per slice
    assert len(list(mc._chunks(mc._streams(np.random.default_rng(0), n), 4))) == 4
    split = run()
    assert whole[0] == split[0] and whole[1] == split[1] and whole[3] == split[3]
    for field in ("step", "goal", "progress", "arrival_steps"):
        np.testing.assert_array_equal(getattr(whole[2], field), getattr(split[2], field))
    # the streaming commit check counts exactly what the rollouts hold
    rates = mc.commit_rates(whole[2], by_step, goals.names)
    assert _asdicts(rates) == whole[1]
    # the streams after the first are other users, not copies of the first
    ends = mc.simulate_user(goals, params, 128, np.random.default_rng(8)).positions
    assert not np.allclose(ends[:, :64], ends[:, 64:])


def test_monte_carlo_memory_stays_within_the_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    budget = 16 * 2**20
    monkeypatch.setattr(mc, "MEMORY_BUDGET", budget)
    goals = table_goals(8, seed=5, radius=0.03)  # short horizons: a quick run
    n = 3 * mc.STREAM_TRIALS
    for run in (
        lambda: mc.monte_carlo(goals, Params(), n, seed=1, costs=("dragan", "ratio")),
        lambda: mc.monte_carlo_commit(goals, Params(), n, np.random.default_rng(1), [None] * 8),
    ):
        tracemalloc.start()
        run()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak < budget, f"{peak / 2**20:.1f} MiB"


def test_trials_beyond_the_cap_are_refused() -> None:
    goals = table_goals(2)
    with pytest.raises(InputError, match=r"trials: expected 1 to 1,000,000 trials, got 10,000,000"):
        mc.monte_carlo(goals, Params(), 10_000_000)
    with pytest.raises(InputError, match="trials"):
        mc.monte_carlo_commit(goals, Params(), 10_000_000, np.random.default_rng(0), [None] * 2)


@pytest.mark.parametrize("commit_forms", [0, 1])
def test_work_beyond_the_cap_is_refused_naming_the_largest_run(commit_forms: int) -> None:
    goals = table_goals(MAX_GOALS)
    with pytest.raises(InputError) as info:
        mc.check_trials(goals, Params(), 1_000_000, commit_forms=commit_forms, field="--n")
    text = str(info.value)
    assert text.startswith("--n: 1,000,000 trials of 64 goals are") and "\n" not in text
    largest = int(text.rsplit("accepted, ", 1)[1].split(" trials")[0].replace(",", ""))
    mc.check_trials(goals, Params(), largest, commit_forms=commit_forms)  # accepted
    with pytest.raises(InputError):
        mc.check_trials(goals, Params(), largest + 1, commit_forms=commit_forms)
    work = mc.monte_carlo_work(goals, Params(), largest, commit_forms=commit_forms)
    assert work <= mc.MAX_WORK


def test_the_largest_trial_count_is_allowed_for_a_small_close_goal_set() -> None:
    """The option's declared range is reachable: a two-goal set within 0.35 m."""
    goals = GoalSet.build(["a", "b"], [[0.62, 0.21, 0.07], [0.70, -0.18, 0.04]], [DOWN] * 2, X0)
    mc.check_trials(goals, Params(), mc.MAX_TRIALS)


# --- alpha, beta, sigma: finite at every end of their ranges ------------------------------


@pytest.mark.parametrize(
    ("value", "why"),
    [
        (1e-17, "below 1e-9"),
        (0.0, ""),
        (-0.05, ""),
        (0.6, "above 0.5"),
        (1.0, "above 0.5"),
        (float("nan"), ""),
    ],
)
def test_alpha_outside_its_range_is_refused_with_the_reason(value: float, why: str) -> None:
    with pytest.raises(InputError, match=r"^alpha: expected a number in \[1e-09, 0.5\]") as info:
        Params(alpha=value)
    assert why in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("name", "value"), [("beta", 0.0), ("beta", 1e4), ("sigma", 0.0), ("sigma", 11.0)]
)
def test_beta_and_sigma_outside_their_ranges_are_refused(name: str, value: float) -> None:
    with pytest.raises(InputError, match=rf"^{name}: expected a number in"):
        Params(**{name: value})  # type: ignore[arg-type]


def test_upper_quantile_is_exact_for_tiny_tails() -> None:
    """``Phi^-1(1 - a)`` computed as ``-Phi^-1(a)``: finite and right where ``1 - a``
    rounds to 1 (the cause of ``J = -inf`` at alpha = 1e-17)."""
    assert upper_quantile(0.05) == pytest.approx(1.6448536269514722, rel=1e-14)
    assert upper_quantile(1e-20) == pytest.approx(9.262340089798408, rel=1e-12)
    tails = upper_quantile(np.array([1e-9, 1e-17, 1e-300]))
    assert np.all(np.isfinite(tails)) and np.all(np.diff(tails) > 0)


def _ends() -> list[dict[str, float]]:
    out: list[dict[str, float]] = [{}]
    for name in ("alpha", "beta", "sigma"):
        lo, hi = RANGES[name]
        out += [{name: lo}, {name: hi}]
    lo_a, hi_a = RANGES["alpha"]
    out += [
        {"alpha": lo_a, "beta": RANGES["beta"][1], "sigma": RANGES["sigma"][0]},
        {"alpha": hi_a, "beta": RANGES["beta"][0], "sigma": RANGES["sigma"][1]},
        {"p_thresh": 1 - 1e-15},
        {"p_thresh": 1e-9},
        {"horizon_fraction": 1e-9},
    ]
    return out


def _finite(value: Any) -> bool:
    try:
        json.dumps(value, allow_nan=False)
    except ValueError:
        return False
    return True


@pytest.mark.parametrize("cost", ["dragan", "ratio"])
@pytest.mark.parametrize(
    "ends", _ends(), ids=lambda e: ",".join(f"{k}={v:g}" for k, v in e.items())
)
def test_every_end_of_the_ranges_gives_finite_results_without_warnings(
    ends: dict[str, float], cost: str
) -> None:
    params = Params(cost=cost, **ends)  # type: ignore[arg-type]
    near = GoalSet.build(
        ["a", "b", "c"], [[0.551, 0.0, 0.3], [0.55, 0.001, 0.3005], [0.9, 0.3, 0.0]], [DOWN] * 3, X0
    )
    for goals in (table_goals(5, seed=9), near):
        cert = certify(goals, params)
        assert math.isfinite(cert.objective) and math.isfinite(cert.quantile)
        assert _finite([asdict(p) for p in cert.pairs])
        for user in (unclipped_user(params), clipped_user(params)):
            for form in ("min", "sum"):
                try:
                    c = certify_commit(goals, params, user, form)
                except InputError as err:  # a clipped user drowned in noise never arrives
                    refused = str(err)
                    c = None
                if c is None:
                    assert "steps" in refused
                    continue
                assert _finite([c.objective, *c.thresholds, c.quantile])
                assert _finite({k: asdict(g) for k, g in c.goals.items()})
        horizon = mc.monte_carlo(goals, params, 20, seed=1, clip_speed=True)
        assert _finite(_asdicts(horizon))
