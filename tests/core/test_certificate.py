"""The certificate against hand computation, finite differences and its own invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm

from legws_daemon.core.certificate import certify, certify_batch, horizon_steps, nominal_terms
from legws_daemon.core.costs import path_costs
from legws_daemon.core.geometry import Pose, quat_to_matrix
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import Params

IDENTITY_Q = [1.0, 0.0, 0.0, 0.0]
ORIGIN = Pose(np.zeros(3), np.array(IDENTITY_Q))
STEP_VAR = (0.03 * 0.05) ** 2  # sigma^2 dt^2


def two_goals() -> GoalSet:
    # |g1 - x0| = 0.301 -> T = ceil(90.3) = 91, L = 0.2275; |g2 - x0| = 0.402 -> T = 121.
    return GoalSet.build(
        ["g1", "g2"], [[0.301, 0, 0], [0, 0.402, 0]], [IDENTITY_Q, IDENTITY_Q], ORIGIN
    )


def test_horizon_steps_match_hand_values() -> None:
    p = Params()
    assert horizon_steps(np.array([0.301, 0.402]), p).tolist() == [91, 121]
    # exactly 90 steps must not round up to 91 through floating-point noise
    assert horizon_steps(np.array([0.3]), p).tolist() == [90]


def test_two_goals_dragan_by_hand() -> None:
    cert = certify(two_goals(), Params(cost="dragan"))
    pair = next(p for p in cert.pairs if p.true == "g1")
    D = (0.301 + 0.402) / 2
    h = math.hypot(0.2275, 0.402)  # |pbar_1 - g2|
    margin = 5 * ((0.2275 + h - 0.402) / D - (0.2275 + 0.0735 - 0.301) / D)
    ax, ay = (0.2275 / h + 1) / D, (-0.402 / h) / D
    variance = 25 * 91 * STEP_VAR * (ax * ax + ay * ay)
    slack = margin - norm.ppf(0.95) * math.sqrt(variance)
    assert pair.steps == 91
    assert pair.margin == pytest.approx(margin, rel=1e-12)
    assert pair.variance == pytest.approx(variance, rel=1e-12)
    assert pair.slack == pytest.approx(slack, rel=1e-12)
    # the same numbers worked out on paper
    assert (pair.margin, pair.variance, pair.slack) == pytest.approx(
        (4.0883, 0.12367, 3.5099), abs=1e-4
    )


def test_two_goals_ratio_by_hand() -> None:
    cert = certify(two_goals(), Params(cost="ratio"))
    pair = next(p for p in cert.pairs if p.true == "g1")
    h = math.hypot(0.2275, 0.402)
    margin = 5 * ((0.2275 + h) / 0.402 - (0.2275 + 0.0735) / 0.301)
    ax, ay = (0.2275 / h) / 0.402 + 1 / 0.301, (-0.402 / h) / 0.402
    variance = 25 * 91 * STEP_VAR * (ax * ax + ay * ay)
    assert pair.margin == pytest.approx(margin, rel=1e-12)
    assert pair.variance == pytest.approx(variance, rel=1e-12)
    assert (pair.margin, pair.variance, pair.slack) == pytest.approx(
        (3.5747, 0.12984, 2.9820), abs=1e-4
    )


@pytest.mark.parametrize("cost", ["dragan", "ratio"])
def test_three_goals_with_rotation_by_hand(cost: str) -> None:
    # g3 is turned 90 degrees about z relative to x0: d(., g3) gains lambda_R * pi / 2.
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    goals = GoalSet.build(
        ["g1", "g2", "g3"],
        [[0.301, 0, 0], [0, 0.402, 0], [0.25, 0.25, 0.05]],
        [IDENTITY_Q, IDENTITY_Q, [c, 0, 0, s]],
        ORIGIN,
    )
    params = Params(cost=cost)  # type: ignore[arg-type]
    cert = certify(goals, params)
    rot3 = 0.04 * math.pi / 2
    p = {n: np.array(v) for n, v in zip(goals.names, goals.positions.tolist(), strict=True)}
    d0 = {n: float(np.linalg.norm(p[n])) + (rot3 if n == "g3" else 0.0) for n in p}
    D = sum(d0.values()) / 3
    z = norm.ppf(1 - 0.05 / 2)
    for true in p:
        T = math.ceil(0.75 * np.linalg.norm(p[true]) / 0.0025 - 1e-9)
        L = T * 0.0025
        pbar = L * p[true] / np.linalg.norm(p[true])

        def cost_of(n: str, pbar: np.ndarray = pbar, L: float = L) -> float:
            dn = float(np.linalg.norm(pbar - p[n])) + (rot3 if n == "g3" else 0.0)
            return (L + dn - d0[n]) / D if cost == "dragan" else (L + dn) / d0[n]

        def grad(n: str, pbar: np.ndarray = pbar) -> np.ndarray:
            u = (pbar - p[n]) / np.linalg.norm(pbar - p[n])
            return u / D if cost == "dragan" else u / d0[n]

        for other in p:
            if other == true:
                continue
            pair = next(q for q in cert.pairs if q.true == true and q.other == other)
            m = 5 * (cost_of(other) - cost_of(true))
            a = grad(other) - grad(true)
            v = 25 * T * STEP_VAR * float(a @ a)
            assert pair.steps == T
            assert pair.margin == pytest.approx(m, rel=1e-10)
            assert pair.variance == pytest.approx(v, rel=1e-10)
            assert pair.slack == pytest.approx(m - z * math.sqrt(v), rel=1e-10)
    assert cert.objective == min(q.slack for q in cert.pairs)
    assert len(cert.pairs) == 6


def random_layouts(rng: np.random.Generator, b: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    pos = np.column_stack(
        [
            rng.uniform(0.3, 0.85, b * m),
            rng.uniform(-0.45, 0.45, b * m),
            rng.uniform(0, 0.15, b * m),
        ]
    ).reshape(b, m, 3)
    q = rng.normal(size=(b, m, 4))
    return pos, quat_to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))


@pytest.mark.parametrize("cost", ["dragan", "ratio"])
def test_sensitivity_matches_finite_differences(cost: str) -> None:
    rng = np.random.default_rng(7)
    p0, R0 = np.array([0.55, 0.0, 0.3]), quat_to_matrix([0, 1, 0, 0])
    pos, rot = random_layouts(rng, 20, 4)
    sym = np.array([0, 1, 2, 4])
    params = Params(cost=cost)  # type: ignore[arg-type]
    t = nominal_terms(p0, R0, pos, rot, sym, params)
    h = 1e-6
    for b in range(pos.shape[0]):
        for i in range(4):
            for k in range(3):
                e = np.zeros(3)
                e[k] = h

                def diff(point: np.ndarray, b: int = b, i: int = i) -> np.ndarray:
                    dn = np.linalg.norm(point - pos[b], axis=1) + t.rot_term[b]
                    c = path_costs(t.length[b, i], dn, t.dist_start[b], params.cost)
                    return c - c[i]

                fd = (diff(t.endpoint[b, i] + e) - diff(t.endpoint[b, i] - e)) / (2 * h)
                np.testing.assert_allclose(t.sensitivity[b, i, :, k], fd, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 8), st.sampled_from(["dragan", "ratio"]))
def test_batch_equals_one_at_a_time(seed: int, m: int, cost: str) -> None:
    rng = np.random.default_rng(seed)
    x0 = Pose(np.array([0.55, 0.0, 0.3]), np.array([0.0, 1.0, 0.0, 0.0]))
    pos, rot = random_layouts(rng, 5, m)
    sym = rng.integers(0, 5, size=m)
    params = Params(cost=cost)  # type: ignore[arg-type]
    batch = certify_batch(x0.position, x0.rotation, pos, rot, sym, params)
    from legws_daemon.core.geometry import matrix_to_quat

    for b in range(5):
        goals = GoalSet.build([f"g{i}" for i in range(m)], pos[b], matrix_to_quat(rot[b]), x0, sym)
        one = certify(goals, params)
        assert one.objective == pytest.approx(batch.objective[b], rel=1e-9, abs=1e-12)
        slacks = batch.slack[b][~np.eye(m, dtype=bool)]
        assert sorted(q.slack for q in one.pairs) == pytest.approx(sorted(slacks), rel=1e-9)


def test_objective_is_translation_invariant_and_order_equivariant() -> None:
    rng = np.random.default_rng(3)
    pos, rot = random_layouts(rng, 1, 5)
    x0 = Pose(np.array([0.55, 0.0, 0.3]), np.array([0.0, 1.0, 0.0, 0.0]))
    from legws_daemon.core.geometry import matrix_to_quat

    names = ["a", "b", "c", "d", "e"]
    goals = GoalSet.build(names, pos[0], matrix_to_quat(rot[0]), x0)
    shift = np.array([0.3, -0.2, 0.1])
    moved = GoalSet.build(
        names, pos[0] + shift, matrix_to_quat(rot[0]), Pose(x0.position + shift, x0.quaternion)
    )
    perm = [3, 0, 4, 1, 2]
    shuffled = GoalSet.build(
        [names[i] for i in perm], pos[0][perm], matrix_to_quat(rot[0])[perm], x0
    )
    for cost in ("dragan", "ratio"):
        p = Params(cost=cost)  # type: ignore[arg-type]
        base = {(q.true, q.other): q.slack for q in certify(goals, p).pairs}
        for other in (moved, shuffled):
            again = {(q.true, q.other): q.slack for q in certify(other, p).pairs}
            assert again == pytest.approx(base, rel=1e-9)


def test_more_separation_more_slack() -> None:
    """Pushing two goals apart (same distance from x0) raises the objective."""
    x0 = Pose(np.array([0.0, 0.0, 0.3]), np.array([0.0, 1.0, 0.0, 0.0]))
    objectives = []
    for angle in (0.2, 0.5, 1.0, 2.0):
        a = angle / 2
        pts = [
            [0.3 * math.cos(a), 0.3 * math.sin(a), 0],
            [0.3 * math.cos(a), -0.3 * math.sin(a), 0],
        ]
        goals = GoalSet.build(["l", "r"], pts, [[0, 1, 0, 0]] * 2, x0)
        objectives.append(certify(goals, Params()).objective)
    assert objectives == sorted(objectives)
    assert objectives[0] < 0 < objectives[-1]
