"""Monte Carlo check: seeded, correct statistics, agrees with the certificate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binomtest

from legws_daemon.core.certificate import certify
from legws_daemon.core.geometry import Pose
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.montecarlo import clopper_pearson, monte_carlo, simulate_user
from legws_daemon.core.params import Params

DOWN = [0.0, 1.0, 0.0, 0.0]
X0 = Pose(np.array([0.55, 0.0, 0.30]), np.array(DOWN))


def goals_at(*points: list[float]) -> GoalSet:
    return GoalSet.build(
        [f"g{i}" for i in range(len(points))], list(points), [DOWN] * len(points), X0
    )


def test_same_seed_same_result_and_seed_matters() -> None:
    g = goals_at([0.7, 0.01, 0.02], [0.7, -0.01, 0.02], [0.4, 0.2, 0.02])
    a = monte_carlo(g, Params(), 400, seed=5)
    b = monte_carlo(g, Params(), 400, seed=5)
    c = monte_carlo(g, Params(), 400, seed=6)
    assert a == b
    assert a != c


def test_clopper_pearson_known_values() -> None:
    lo, hi = clopper_pearson(2000, 2000)
    assert hi == 1.0 and lo == pytest.approx(0.025 ** (1 / 2000))
    lo, hi = clopper_pearson(0, 50)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 50))
    ci = binomtest(37, 50).proportion_ci(0.95, method="exact")
    assert clopper_pearson(37, 50) == pytest.approx((ci.low, ci.high))


def test_far_apart_goals_are_always_right_coincident_goals_are_a_coin_flip() -> None:
    far = monte_carlo(goals_at([0.8, 0.35, 0.02], [0.8, -0.35, 0.02]), Params(), 1000, seed=1)
    assert all(acc.accuracy == 1.0 for acc in far["dragan"].values())
    near = monte_carlo(goals_at([0.8, 0.0001, 0.02], [0.8, -0.0001, 0.02]), Params(), 4000, seed=1)
    total = sum(acc.correct for acc in near["dragan"].values())
    assert total / 8000 == pytest.approx(0.5, abs=0.03)


def test_speed_clip_bounds_the_path_and_noise_lengthens_it() -> None:
    g = goals_at([0.8, 0.3, 0.02], [0.8, -0.3, 0.02])
    p = Params()
    rng = np.random.default_rng(0)
    free = simulate_user(g, p, 500, rng)
    clipped = simulate_user(g, p, 500, np.random.default_rng(0), clip_speed=True)
    bound = free.steps[:, None] * p.v_max * p.dt
    assert np.all(clipped.lengths <= bound + 1e-12)
    assert np.mean(free.lengths > bound) > 0.9  # noise makes the unclipped path longer


def test_unclipped_end_state_matches_the_certificate_model() -> None:
    """Mean and spread of x_T agree with the linear-Gaussian model far from the goal."""
    g = goals_at([0.85, 0.4, 0.02], [0.3, -0.4, 0.02])
    p = Params(horizon_fraction=0.5)
    states = simulate_user(g, p, 4000, np.random.default_rng(2))
    T = states.steps[0]
    u = (g.positions[0] - X0.position) / np.linalg.norm(g.positions[0] - X0.position)
    mean = states.positions[0].mean(axis=0)
    np.testing.assert_allclose(mean, X0.position + T * p.v_max * p.dt * u, atol=2e-3)
    lateral = states.positions[0] - mean
    lateral -= np.outer(lateral @ u, u)
    # closed-loop pi_h pulls lateral errors back, so the spread is at most the open-loop one
    assert np.sqrt((lateral**2).sum(axis=1).mean() / 2) <= np.sqrt(T) * p.sigma * p.dt * 1.05


@pytest.mark.parametrize("cost", ["dragan", "ratio"])
def test_certified_layout_meets_one_minus_alpha(cost: str) -> None:
    g = goals_at([0.75, 0.3, 0.02], [0.75, -0.3, 0.02], [0.35, 0.0, 0.02])
    p = Params(cost=cost)  # type: ignore[arg-type]
    assert certify(g, p).objective > 0
    mc = monte_carlo(g, p, 2000, seed=0)[p.cost]
    assert all(acc.lower95 >= 1 - p.alpha for acc in mc.values())


def test_both_forms_share_trajectories() -> None:
    g = goals_at([0.7, 0.06, 0.02], [0.7, -0.06, 0.02], [0.45, 0.2, 0.02])
    both = monte_carlo(g, Params(), 300, seed=9, costs=("dragan", "ratio"))
    only = monte_carlo(g, Params(cost="ratio"), 300, seed=9)
    assert both["ratio"] == only["ratio"]
