"""The search's compiled objectives (design/fast_objectives.py) against the numpy reference of
the core (certify_batch, commit_batch, commit_chance_batch, commit_time_batch): J, K, R and T
per goal to 1e-9, with the same commit-certified flags and crossing steps, for every cost
form, both commit forms and the operators of the brief, on random layouts and on scenes."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.commit import (
    commit_batch,
    commit_chance_batch,
    commit_time_batch,
)
from legws_daemon.core.geometry import quat_to_matrix
from legws_daemon.core.operator import OperatorModel, UserMotion
from legws_daemon.core.params import Params
from legws_daemon.design.fast_objectives import Objectives
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.scene.catalog import load_scene
from tests.core.test_operator import orbiting

TOLERANCE = 1e-9
P0 = np.array([0.55, 0.0, 0.30])
R0 = quat_to_matrix(np.array([0.0, 1.0, 0.0, 0.0]))
#: Who steers: section 2's user as written and with the robot's clip; a slow, correlated
#: operator (straight, every variance S_rho); biased operators with quantised steering
#: (curved nominals, with the clip as the design uses them).
WHO: dict[str, tuple[OperatorModel | None, bool]] = {
    "section 2": (None, False),
    "section 2 clipped": (OperatorModel(), True),
    "slow rho 0.8": (OperatorModel(0.6, 0.03, 0.8, 0.0, "free"), True),
    "bias 20 axes": (OperatorModel(1.0, 0.03, 0.0, 20.0, "axes"), True),
    "bias -10 diagonals": (OperatorModel(1.0, 0.03, 0.0, -10.0, "axes+diagonals"), True),
}


def _batch(m: int, seed: int, b: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    pos = rng.uniform([0.3, -0.45, 0.0], [0.85, 0.45, 0.12], (b, m, 3))
    yaw = rng.uniform(-np.pi, np.pi, (b, m))
    zero = np.zeros_like(yaw)
    rot = quat_to_matrix(np.stack([zero, np.cos(yaw / 2), np.sin(yaw / 2), zero], axis=-1))
    return pos, rot, rng.integers(0, 3, m)


def _who(name: str, params: Params) -> tuple[OperatorModel | None, UserMotion | None]:
    op, clip = WHO[name]
    if op is None:
        return None, None
    return op, op.motion(params, clip=clip)


def _close(fast: np.ndarray, ref: np.ndarray) -> None:
    """Equal to TOLERANCE where finite, the same infinities elsewhere."""
    assert np.array_equal(np.isinf(fast), np.isinf(ref))
    finite = np.isfinite(ref)
    np.testing.assert_allclose(fast[finite], ref[finite], rtol=0, atol=TOLERANCE)


@pytest.mark.parametrize("who", list(WHO))
@pytest.mark.parametrize("cost", ["dragan", "ratio"])
@pytest.mark.parametrize("m", [2, 3, 5, 8])
def test_every_objective_matches_the_numpy_reference(who: str, cost: str, m: int) -> None:
    params = Params(cost=cost)  # type: ignore[arg-type]
    pos, rot, sym = _batch(m, seed=m * 7 + len(who) + len(cost))
    op, user = _who(who, params)
    fast = Objectives(P0, R0, pos, rot, sym, params)
    ref_j = certify_batch(P0, R0, pos, rot, sym, params, op, user)
    slack = fast.slack(op, user)
    reference_slack = np.where(np.eye(m, dtype=bool), np.inf, ref_j.slack).min(axis=2)
    _close(slack, reference_slack)
    _close(slack.min(axis=1), ref_j.objective)
    for form in ("min", "sum"):
        ref = commit_batch(P0, R0, pos, rot, sym, params, user, form, op)
        got = fast.commit(user, form, op)
        _close(got.fraction, ref.fraction)
        _close(got.objective, ref.objective)
        assert np.array_equal(got.step, ref.step)
        assert np.array_equal(got.certified, ref.certified)
        assert np.array_equal(got.arrival_steps, ref.arrival_steps)
        lost = ~ref.reachable
        _close(got.slack_at_arrival[~lost], ref.slack_at_arrival[~lost])
        # w is exact where negative (there kappa and the flag depend on it), else >= 0
        negative = ref.wrong_commit_slack < 0
        _close(got.wrong_commit_slack[negative], ref.wrong_commit_slack[negative])
        assert np.all(got.wrong_commit_slack[~negative & ~lost] >= 0)
        j_pass, kappa, arrived = fast.scores("commit", op, user, form)
        _close(j_pass, slack)
        _close(kappa, ref.fraction)
        assert np.array_equal(arrived, ref.arrival_steps)
    ref_r = commit_chance_batch(P0, R0, pos, rot, sym, params, user, op)
    ref_t = commit_time_batch(P0, R0, pos, rot, sym, params, user, op)
    _close(fast.chance(user, op), ref_r)
    _close(fast.time(user, op), ref_t)
    _close(fast.scores("rate", op, user)[1], ref_r)
    _close(fast.scores("time", op, user)[1], ref_t)


def test_a_goal_the_operator_never_reaches_is_handled_as_the_reference() -> None:
    """An operator whose nominal never arrives (T_a = 0, kappa and T infinite, R 0), as in
    tests/core/test_operator.py."""
    params = Params()
    op = orbiting()
    goals = np.array([[[0.85, 0.30, 0.30], [0.30, -0.40, 0.05]]])
    rot = quat_to_matrix(np.tile([0.0, 1.0, 0.0, 0.0], (1, 2, 1)))
    sym = np.ones(2, dtype=np.int64)
    fast = Objectives(P0, R0, goals, rot, sym, params)
    for user in (op.motion(params), op.motion(params, clip=True)):
        ref = commit_batch(P0, R0, goals, rot, sym, params, user, "sum", op)
        assert not ref.reachable.all()
        got = fast.commit(user, "sum", op)
        _close(got.fraction, ref.fraction)
        assert np.array_equal(got.arrival_steps, ref.arrival_steps)
        assert np.array_equal(got.certified, ref.certified)
        _close(fast.chance(user, op), commit_chance_batch(P0, R0, goals, rot, sym, params,
                                                          user, op))  # fmt: skip
        _close(fast.time(user, op), commit_time_batch(P0, R0, goals, rot, sym, params, user, op))
        _close(fast.slack(op, user).min(axis=1),
               certify_batch(P0, R0, goals, rot, sym, params, op, user).objective)  # fmt: skip


@pytest.mark.parametrize("scene", ["breakfast_easy", "meal_assembly", "cluttered"])
def test_the_scenes_searched_layouts_match(scene: str) -> None:
    """The layouts a search proposes (uniform in the decision space, feasible or not) of
    three tiers, for section 2's clipped user and the benchmark's operator."""
    sc = load_scene(scene)
    problem = LayoutProblem(sc)
    x = np.random.default_rng(3).uniform(size=(30, problem.dim))
    g = problem.goals.poses(problem.decode(x))
    home = sc.home
    params = Params()
    args = (home.position, home.rotation, g.positions, g.rotations, g.symmetry, params)
    fast = Objectives(*args)
    for op in (OperatorModel(), OperatorModel(0.8, 0.03, 0.5, 20.0, "axes")):
        user = op.motion(params, clip=True)
        _close(fast.commit(user, "sum", op).objective,
               commit_batch(*args, user, "sum", op).objective)  # fmt: skip
        _close(fast.chance(user, op), commit_chance_batch(*args, user, op))
        _close(fast.time(user, op), commit_time_batch(*args, user, op))
