"""Fitting the operator model (method.md §10) to simulated reaches of known operators:
the intervals cover the truth, the estimates are close, the conservative ends are taken."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.core import operator_fit
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.operator_fit import fit_operator
from legws_daemon.core.params import Params
from legws_daemon.core.user_model import SimulatedUser
from legws_daemon.errors import InputError
from legws_daemon.sim.reaches import simulate_reaches

PARAMS = Params()


def _covers(fit_intervals: dict[str, tuple[float, float]], truth: OperatorModel) -> list[str]:
    """The numbers of ``truth`` outside their interval."""
    return [
        k
        for k, (lo, hi) in fit_intervals.items()
        if not lo - 1e-9 <= getattr(truth, k) <= hi + 1e-9
    ]


@pytest.mark.parametrize(
    "truth",
    [
        OperatorModel(0.6, 0.005, 0.5, 10.0, "free"),
        OperatorModel(0.7, 0.004, 0.8, -20.0, "axes"),
        OperatorModel(0.5, 0.006, 0.0, 0.0, "axes+diagonals"),
    ],
    ids=["free", "axes", "diagonals"],
)
def test_an_operator_who_never_reaches_the_rim_is_recovered(truth: OperatorModel) -> None:
    """Little noise: the deflection stays inside the unit ball, no clip to undo."""
    reaches = simulate_reaches(SimulatedUser(truth, clip=True), 20, np.random.default_rng(3))
    fit = fit_operator(reaches, PARAMS, resamples=400)
    assert fit.diagnostics["undid_clip"] is False
    assert fit.model.steering == truth.steering
    assert _covers(fit.intervals, truth) == []
    assert fit.model.speed == pytest.approx(truth.speed, abs=0.05)
    assert fit.model.sigma == pytest.approx(truth.sigma, rel=0.10)
    assert fit.model.rho == pytest.approx(truth.rho, abs=0.05)
    assert fit.model.bias_deg == pytest.approx(truth.bias_deg, abs=3.0)


def test_the_speed_is_not_lowered_by_correlated_noise_in_the_closed_loop() -> None:
    """With rho = 0.9 the aim at x_t has turned against the noise that moved the EE there: the
    plain mean of u . aim is low; the quasi-differenced estimate is not."""
    truth = OperatorModel(0.6, 0.012, 0.9, 0.0, "free")
    reaches = simulate_reaches(SimulatedUser(truth, clip=True), 20, np.random.default_rng(5))
    fit = fit_operator(reaches, PARAMS, resamples=0)
    plain = float(np.mean(np.concatenate([
        np.einsum("tk,tk->t", u, (g - e) / np.linalg.norm(g - e, axis=1, keepdims=True))
        for e, u, g in reaches
    ])))  # fmt: skip
    assert plain < truth.speed - 0.01
    assert fit.model.speed == pytest.approx(truth.speed, abs=0.03)


def test_certify_with_takes_the_conservative_end_of_every_interval() -> None:
    truth = OperatorModel(0.7, 0.01, 0.4, -8.0, "free")
    reaches = simulate_reaches(SimulatedUser(truth, clip=True), 12, np.random.default_rng(6))
    fit = fit_operator(reaches, PARAMS, resamples=300)
    c, iv = fit.certify_with, fit.intervals
    assert c.speed == pytest.approx(iv["speed"][0])
    assert c.sigma == pytest.approx(iv["sigma"][1])
    assert c.rho == pytest.approx(iv["rho"][1])
    assert abs(c.bias_deg) == pytest.approx(max(abs(iv["bias_deg"][0]), abs(iv["bias_deg"][1])))
    for key, (lo, hi) in iv.items():
        assert lo <= getattr(fit.model, key) <= hi


def test_the_same_seed_gives_the_same_fit() -> None:
    reaches = simulate_reaches(
        SimulatedUser(OperatorModel(sigma=0.01)), 6, np.random.default_rng(1)
    )
    a = fit_operator(reaches, PARAMS, resamples=200, seed=4)
    b = fit_operator(reaches, PARAMS, resamples=200, seed=4)
    assert a.model == b.model and a.intervals == b.intervals


def test_too_little_teleoperation_is_refused_naming_what_was_given() -> None:
    reaches = simulate_reaches(
        SimulatedUser(OperatorModel(sigma=0.01)), 2, np.random.default_rng(1)
    )
    with pytest.raises(InputError, match="a fit needs at least 2 segments"):
        fit_operator(reaches[:1], PARAMS)
    idle = [(e, np.zeros_like(u), g) for e, u, g in reaches]  # never steered
    with pytest.raises(InputError, match="0 usable segments"):
        fit_operator(idle, PARAMS)


@pytest.mark.slow
@pytest.mark.parametrize(
    "truth",
    [
        OperatorModel(1.0, 0.03, 0.0, 0.0, "free"),
        OperatorModel(0.6, 0.03, 0.8, 10.0, "free"),
        OperatorModel(1.0, 0.03, 0.5, -20.0, "axes"),
        OperatorModel(0.6, 0.03, 0.0, 0.0, "axes+diagonals"),
    ],
    ids=["paper", "slow-correlated-biased", "axes", "diagonals"],
)
def test_an_operator_at_the_rim_is_recovered_by_undoing_the_clip(truth: OperatorModel) -> None:
    """The family's noise (sigma / v_max = 0.6 per axis): most deflections sit at the rim;
    taken as they are the estimates describe the clipped signal (section 2's user: s 0.67,
    sigma 0.019), the fit recovers the model."""
    reaches = simulate_reaches(SimulatedUser(truth, clip=True), 20, np.random.default_rng(0))
    fit = fit_operator(reaches, PARAMS, resamples=400)
    assert fit.diagnostics["undid_clip"] is True
    assert fit.model.steering == truth.steering
    # a 95 % interval misses now and then: of the four numbers at most one, and only
    # narrowly (the point estimates are held to the tolerances below)
    assert len(_covers(fit.intervals, truth)) <= 1
    assert fit.model.speed == pytest.approx(truth.speed, abs=0.06)
    assert fit.model.sigma == pytest.approx(truth.sigma, rel=0.10)
    assert fit.model.rho == pytest.approx(truth.rho, abs=0.05)
    assert fit.model.bias_deg == pytest.approx(truth.bias_deg, abs=4.0)


@pytest.mark.slow
def test_a_keyboard_user_who_sees_the_arm_late_is_fitted_from_the_ticks_clear_of_a_boundary(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Along a diagonal a keyboard user alternates keys; where they saw the arm a moment ago
    decides which, so at the recorded EE the aim is the other key about half the time (over
    zenoh the status is 10 Hz and the arm lags). Here the user aims from where the EE was
    two ticks before: with the ticks within BOUNDARY_M of a boundary left out the model is
    recovered; taken over every tick the speed comes out near half."""
    truth = OperatorModel(1.0, 0.03, 0.5, -20.0, "axes")
    late = SimulatedUser(truth, clip=True, delay=2)
    reaches = simulate_reaches(late, 20, np.random.default_rng(0))
    fit = fit_operator(reaches, PARAMS, resamples=200)
    assert fit.model.steering == "axes"
    assert _covers(fit.intervals, truth) == []
    assert fit.model.speed == pytest.approx(1.0, abs=0.06)
    assert fit.model.rho == pytest.approx(0.5, abs=0.05)
    assert fit.model.bias_deg == pytest.approx(-20.0, abs=3.0)
    monkeypatch.setattr(operator_fit, "BOUNDARY_M", 0.0)  # every tick
    assert fit_operator(reaches, PARAMS, resamples=0).model.speed < 0.7


@pytest.mark.parametrize("steering", ["free", "axes", "axes+diagonals"])
def test_the_binding_functions_totals_are_the_sums_of_its_segments(steering: str) -> None:
    """The simulated segments' totals, taken over ``(T, K, 3)`` arrays at once, agree with
    :func:`_sums` of the segments one by one (with the ticks near a boundary left out)."""
    rng = np.random.default_rng(3)
    t, k, bias = 60, 9, 0.3
    xs = rng.uniform(-0.3, 0.3, size=(t, k, 3))
    us = rng.normal(size=(t, k, 3)) * 0.5
    goals = rng.uniform(-0.3, 0.3, size=(k, 3))
    lengths = rng.integers(0, t + 1, size=k)
    lengths[:2] = (1, t)  # one too short to count, one whole
    live = np.arange(t)[:, None] < lengths[None, :]
    total = operator_fit._simulated_totals(xs, us, live, goals, steering, bias)
    segments = [
        operator_fit.Reach(xs[:n, j], us[:n, j], goals[j], np.ones(n - 1, bool))
        for j, n in enumerate(lengths)
        if n >= 2
    ]
    per = operator_fit._sums(segments, steering, np.array([bias]), bias)
    for name in operator_fit._SUMS:
        expected = getattr(per, name)[:, 0].sum()
        assert getattr(total, name)[0] == pytest.approx(expected, rel=1e-12, abs=1e-12), name
