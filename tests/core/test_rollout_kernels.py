"""The compiled rollouts give the numpy rollouts' numbers: the same noise, the same users."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.core.geometry import Pose
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.montecarlo import monte_carlo, monte_carlo_commit, simulate_commits
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.core.user_model import SimulatedUser

DOWN = [0.0, 1.0, 0.0, 0.0]
X0 = Pose(np.array([0.55, 0.0, 0.30]), np.array(DOWN))
#: Five goals close enough that some users commit late or wrong, one of them straight
#: below (an aim on an axis).
GOALS = GoalSet.build(
    ["a", "b", "c", "d", "e"],
    [[0.70, 0.05, 0.02], [0.70, 0.025, 0.03], [0.62, 0.12, 0.05], [0.55, 0.0, 0.05],
     [0.45, -0.15, 0.02]],
    [DOWN] * 5,
    X0,
)  # fmt: skip
#: Every way a simulated user can steer: the operator family and the departures from it.
USERS = {
    "paper": SimulatedUser(OperatorModel()),
    "paper clipped": SimulatedUser(OperatorModel(), clip=True),
    "correlated biased": SimulatedUser(OperatorModel(1.0, 0.03, 0.5, 10.0), clip=True),
    "slow axes": SimulatedUser(OperatorModel(0.6, 0.03, 0.8, -20.0, "axes"), clip=True),
    "diagonals": SimulatedUser(OperatorModel(1.0, 0.03, 0.0, 20.0, "axes+diagonals"), clip=True),
    "idle": SimulatedUser(OperatorModel(), idle=0.2),
    "delayed": SimulatedUser(OperatorModel(), delay=5),
    "heavy tails": SimulatedUser(OperatorModel(), tails=3.0),
}


@pytest.mark.parametrize("name", list(USERS))
@pytest.mark.parametrize("until_arrival", [False, True])
def test_first_commits_are_the_numpy_rollouts(name: str, until_arrival: bool) -> None:
    user = USERS[name]
    runs = [
        simulate_commits(
            GOALS,
            Params(),
            96,
            np.random.default_rng(3),
            costs=("dragan", "ratio"),
            user=user,
            until_arrival=until_arrival,
            compiled=compiled,
        )
        for compiled in (False, True)
    ]
    for form in ("dragan", "ratio"):
        ref, fast = runs[0][form], runs[1][form]
        assert (ref.goal >= 0).sum() > 0  # something to compare
        np.testing.assert_array_equal(fast.step, ref.step)
        np.testing.assert_array_equal(fast.goal, ref.goal)
        np.testing.assert_allclose(fast.progress, ref.progress, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(fast.arrival_steps, ref.arrival_steps)


@pytest.mark.parametrize("name", list(USERS))
def test_end_states_at_the_horizon_are_the_numpy_rollouts(name: str) -> None:
    user = USERS[name]
    ref, fast = (
        monte_carlo(
            GOALS,
            Params(),
            200,
            7,
            user=user,
            costs=("dragan", "ratio"),
            compiled=compiled,
            true_goals=[0, 1, 3],
        )
        for compiled in (False, True)
    )
    assert fast == ref
    assert any(a.correct < a.trials for f in ref.values() for a in f.values())  # not trivial


def test_counts_agree_over_many_streams_and_with_a_certified_step() -> None:
    # more trials than one random stream draws for: the chunks of streams are followed too
    user = USERS["correlated biased"]
    by_step = [40, None, 60, 30, None]
    ref, fast = (
        monte_carlo_commit(
            GOALS, Params(), 4100, np.random.default_rng(1), by_step, user=user, compiled=compiled
        )
        for compiled in (False, True)
    )
    assert fast == ref
