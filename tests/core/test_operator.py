"""The operator model of method.md §10: the certificates under an operator against a literal,
step-by-step implementation of the section, section 2's user bit for bit against the code
before the model, and the model's own pieces (S_rho, Q, the nominal, the clip's moments)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm

from legws_daemon.core import commit as commit_mod
from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.commit import commit_batch
from legws_daemon.core.geometry import quat_to_matrix
from legws_daemon.core.operator import (
    AXIS_DIRECTIONS,
    GRID_DIRECTIONS,
    OperatorModel,
    UserMotion,
    aim,
    ar1_sum_variance,
    clipped_moments,
    nominal_path,
    nominal_steps,
    quantise,
)
from legws_daemon.core.params import Params
from legws_daemon.core.user_model import clip_unit
from legws_daemon.errors import InputError

DATA = Path(__file__).parent / "data" / "paper_certificates.json"
P0 = [0.55, 0.0, 0.30]
R0 = quat_to_matrix(np.array([0.0, 1.0, 0.0, 0.0]))

#: Operators of the family (method.md §10) the literal reference is compared on.
OPERATORS = [
    OperatorModel(0.6, 0.03, 0.5, 10.0, "free"),
    OperatorModel(1.0, 0.03, 0.8, 0.0, "axes"),
    OperatorModel(0.8, 0.02, 0.0, -20.0, "axes+diagonals"),
    OperatorModel(1.0, 0.03, 0.95, 20.0, "free"),
    OperatorModel(0.6, 0.03, 0.0, 0.0, "free"),
    OperatorModel(1.0, 0.015, 0.3, -10.0, "axes"),
]


def _layouts(rng: np.random.Generator, m: int, b: int = 1) -> tuple[np.ndarray, np.ndarray]:
    pos = np.stack([rng.uniform([0.3, -0.45, 0.0], [0.85, 0.45, 0.12], (m, 3)) for _ in range(b)])
    yaw = rng.uniform(-np.pi, np.pi, (b, m))
    return pos, yaw


def _rotations(yaw: np.ndarray) -> np.ndarray:
    zero = np.zeros_like(yaw)
    return quat_to_matrix(np.stack([zero, np.cos(yaw / 2), np.sin(yaw / 2), zero], axis=-1))


# --- section 2's user, bit for bit --------------------------------------------------------


def test_section_2s_user_reproduces_the_certificates_before_the_operator_model() -> None:
    """J, every slack and K (both commit forms) of section 2's user as the code computed
    them before the operator model (tests/core/data/paper_certificates.json, written by
    commit 2012c01 as float.hex): given as O_paper, bit for bit what the default gives; and
    both the stored numbers, bit for bit with the numpy they were written with and within
    1e-12 with any other (numpy 2.4 orders some sums differently: the last bits move)."""
    data = json.loads(DATA.read_text())

    def stored(values: list[str]) -> np.ndarray:
        return np.array([float.fromhex(h) for h in values])

    for case in data["sets"]:
        pos = np.array(case["positions"])
        rot = _rotations(np.array(case["yaw"]))
        sym = np.array(case["symmetry"])
        params = Params(cost=case["cost"])
        paper = OperatorModel.paper(params)
        default = certify_batch(data["p0"], R0, pos, rot, sym, params)
        given = certify_batch(data["p0"], R0, pos, rot, sym, params, operator=paper)
        assert [x.hex() for x in given.slack.reshape(-1)] == [
            x.hex() for x in default.slack.reshape(-1)
        ]
        slack = np.array([x for x in default.slack.reshape(-1) if np.isfinite(x)])
        np.testing.assert_allclose(default.objective, stored(case["J"]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(slack, stored(case["slack"]), rtol=0, atol=1e-12)
        for form in ("min", "sum"):
            k0 = commit_batch(data["p0"], R0, pos, rot, sym, params, form=form)
            k = commit_batch(data["p0"], R0, pos, rot, sym, params, form=form, operator=paper)
            assert [x.hex() for x in k.fraction.reshape(-1)] == [
                x.hex() for x in k0.fraction.reshape(-1)
            ]
            np.testing.assert_allclose(k.objective, stored(case["K"][form]), rtol=0, atol=1e-12)
            np.testing.assert_allclose(
                k.fraction.reshape(-1), stored(case["fraction"][form]), rtol=0, atol=1e-12
            )
            assert k.step.reshape(-1).tolist() == case["step"][form]


# --- the literal reference ----------------------------------------------------------------


def _ref_aim(x: list[float], g: list[float], op: OperatorModel) -> list[float]:
    d = [b - a for a, b in zip(x, g, strict=True)]
    n = math.sqrt(sum(v * v for v in d))
    if n <= 1e-12:
        return [0.0, 0.0, 0.0]
    u = [v / n for v in d]
    c, s = math.cos(math.radians(op.bias_deg)), math.sin(math.radians(op.bias_deg))
    u = [c * u[0] - s * u[1], s * u[0] + c * u[1], u[2]]
    if op.steering == "axes":
        k = max(range(3), key=lambda i: (abs(u[i]), -i))
        return [math.copysign(1.0, u[k]) if i == k else 0.0 for i in range(3)]
    if op.steering == "axes+diagonals":
        dirs = [
            (a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if a or b or c
        ]
        best = max(
            dirs, key=lambda e: sum(p * q for p, q in zip(u, e, strict=True)) / math.hypot(*e)
        )
        return [v / math.hypot(*best) for v in best]
    return u


def _ref_path(
    p0: list[float], g: list[float], op: OperatorModel, ell: float, step: float, at_least: int
) -> tuple[list[list[float]], int]:
    """The nominal's points, at least ``at_least`` of them and on until the first one closer
    than one full step (``v_max dt``) to the goal, whose step is the arrival ``T_a``."""
    points, x, t_a = [], list(p0), 0
    while len(points) < at_least or not t_a:
        a = _ref_aim(x, g, op)
        x = [xi + ell * ai for xi, ai in zip(x, a, strict=True)]
        points.append(x)
        if not t_a and math.dist(x, g) < step * (1 - 1e-9):
            t_a = len(points)
        assert len(points) < 20_000
    return points, t_a


def _ref_certificates(
    goals: list[list[float]], rot: list[float], op: OperatorModel, user: UserMotion, p: Params
) -> tuple[list[float], list[dict[str, float | int | bool | None]]]:
    """Sections 4 and 9 under the operator, written out literally: one true goal, one step,
    one alternative at a time. Returns each pair's slack (section 4) and each goal's commit
    certificate (section 9, exact-sum form)."""
    m = len(goals)
    step = p.v_max * p.dt
    ell = user.speed * step
    d0 = [math.dist(P0, g) + rot[j] for j, g in enumerate(goals)]
    D = sum(d0) / m
    straight = op.straight

    def cost(j: int, x: list[float], length: float) -> float:
        return (length + math.dist(x, goals[j]) + rot[j] - d0[j]) / D

    def grad(j: int, x: list[float]) -> list[float]:
        diff = [a - b for a, b in zip(x, goals[j], strict=True)]
        n = math.sqrt(sum(v * v for v in diff))
        return [0.0, 0.0, 0.0] if n <= 1e-12 else [v / n / D for v in diff]

    def S(t: int) -> float:  # noqa: N802 (the spec's name)
        r = user.rho
        return t if r == 0 else t * (1 + r) / (1 - r) - 2 * r * (1 - r**t) / (1 - r) ** 2

    def variance(a: list[float], way: list[float], t: int) -> float:
        a2 = sum(v * v for v in a)
        if user.along == user.across:
            spread = user.along**2 * a2
        elif straight:
            au = sum(x * y for x, y in zip(a, way, strict=True))
            spread = user.across**2 * a2 + (user.along**2 - user.across**2) * au**2
        else:
            spread = max(user.along, user.across) ** 2 * a2
        return p.beta**2 * step**2 * S(t) * spread

    guard = user != op.motion(p)  # an operator with the robot's clip: core.guard
    wid = max(user.along, user.across)
    if user.along == user.across:
        trace = 3 * user.along**2
    elif straight:
        trace = user.along**2 + 2 * user.across**2
    else:
        trace = 3 * wid**2

    def guarded(
        margin: float, sd: float, x: list[float], i: int, j: int, t: int
    ) -> tuple[float, float]:
        """core.guard, literally: Jensen's drop of the mean, Poincaré's spread, the bridge."""
        if not guard:
            return margin, sd
        r_i, r_j, d_i = math.dist(x, goals[i]), math.dist(x, goals[j]), math.dist(P0, goals[i])
        v = step**2 * S(t)
        bridged = v * min(r_i / d_i, 1.0)
        drop = p.beta / D * (math.sqrt(r_i**2 + bridged * trace) - r_i)
        c = (
            2
            * ((1 / r_i if r_i > 1e-12 else math.inf) + (1 / r_j if r_j > 1e-12 else math.inf))
            / D
        )
        extra = (
            p.beta * math.sqrt(bridged) * wid * c * math.sqrt(bridged * trace) if bridged else 0.0
        )
        cap = p.beta * math.sqrt(v) * wid * 2 / D
        return margin - drop, min(cap, math.sqrt(sd**2 + extra**2))

    z = norm.ppf(1 - p.alpha / (m - 1))
    odds = p.p_thresh / (1 - p.p_thresh)
    tau_c, tau_w = math.log((m - 1) * odds), math.log(odds)
    z_c = norm.ppf(1 - p.alpha / (2 * (m - 1)))
    slacks: list[float] = []
    commits = []
    for i, g in enumerate(goals):
        way = [(b - a) / math.dist(P0, g) for a, b in zip(P0, g, strict=True)]
        horizon = max(1, math.ceil(p.horizon_fraction * math.dist(P0, g) / ell - 1e-9))
        path, t_a = _ref_path(P0, g, op, ell, step, horizon)
        end = path[horizon - 1]
        for j in range(m):
            if j == i:
                continue
            margin = p.beta * (cost(j, end, horizon * ell) - cost(i, end, horizon * ell))
            a = [x - y for x, y in zip(grad(j, end), grad(i, end), strict=True)]
            margin, sd = guarded(margin, math.sqrt(variance(a, way, horizon)), end, i, j, horizon)
            slacks.append(margin - z * sd)
        margins, sds, c = [], [], []
        for t in range(1, t_a + 1):
            x = path[t - 1]
            ms, ss = [], []
            for j in range(m):
                if j == i:
                    continue
                margin = p.beta * (cost(j, x, t * ell) - cost(i, x, t * ell))
                a = [u - v for u, v in zip(grad(j, x), grad(i, x), strict=True)]
                margin, sd = guarded(margin, math.sqrt(variance(a, way, t)), x, i, j, t)
                ms.append(margin)
                ss.append(sd)
            margins.append(ms)
            sds.append(ss)
            lows = [mg - z_c * sd for mg, sd in zip(ms, ss, strict=True)]
            c.append(-tau_w - math.log(sum(math.exp(-v) for v in lows)))
        t_c = next((t for t in range(1, t_a + 1) if c[t - 1] >= 0), None)
        t_end = t_c if t_c is not None else t_a
        z_w = norm.ppf(1 - p.alpha / (2 * (m - 1) * t_end))
        w = min(
            mg + tau_w - z_w * sd
            for t in range(1, t_end + 1)
            for mg, sd in zip(margins[t - 1], sds[t - 1], strict=True)
        )
        certified = t_c is not None and w >= 0
        if certified:
            assert t_c is not None
            before = c[t_c - 2] if t_c > 1 else -tau_c
            kappa = ((t_c - 1) + (0 - before) / (c[t_c - 1] - before)) / t_a
        else:
            kappa = 1 + max(0.0, -c[t_a - 1]) + max(0.0, -w)
        commits.append(
            {"kappa": kappa, "t_c": t_c, "t_a": t_a, "c_arrival": c[t_a - 1], "w": w,
             "certified": certified}
        )  # fmt: skip
    return slacks, commits


@pytest.mark.parametrize("m", [2, 3, 5, 8])
@pytest.mark.parametrize("clip", [False, True])
def test_operator_certificates_match_a_literal_reference(m: int, clip: bool) -> None:
    rng = np.random.default_rng(100 + m)
    pos, yaw = _layouts(rng, m)
    rot = _rotations(yaw)
    params = Params()
    # rotation terms of the cost from the batched code (geometry is tested on its own)
    from legws_daemon.core.certificate import start_terms

    _, rot_term = start_terms(np.array(P0), R0, pos, rot, np.ones(m, dtype=int), params)
    for op in OPERATORS:
        user = op.motion(params, clip)
        slacks, commits = _ref_certificates(pos[0].tolist(), rot_term[0].tolist(), op, user, params)
        cert = certify_batch(P0, R0, pos, rot, np.ones(m), params, op, user)
        got = [float(x) for x in cert.slack.reshape(-1) if np.isfinite(x)]
        np.testing.assert_allclose(got, slacks, atol=1e-6, rtol=0)
        k = commit_batch(P0, R0, pos, rot, np.ones(m), params, user, "sum", op)
        for i, ref in enumerate(commits):
            assert k.arrival_steps[0, i] == ref["t_a"], (op, i)
            assert k.step[0, i] == (ref["t_c"] if ref["t_c"] is not None else -1), (op, i)
            assert bool(k.certified[0, i]) == ref["certified"], (op, i)
            assert k.fraction[0, i] == pytest.approx(ref["kappa"], abs=1e-6)
            assert k.slack_at_arrival[0, i] == pytest.approx(ref["c_arrival"], abs=1e-6)
            assert k.wrong_commit_slack[0, i] == pytest.approx(ref["w"], abs=1e-6)


@pytest.mark.parametrize("clip", [False, True])
def test_the_curved_computation_agrees_with_the_closed_form_on_a_straight_operator(
    clip: bool,
) -> None:
    """The path-based terms (for bias and quantised steering) applied to a straight operator
    give the straight closed form's margins and standard deviations (guarded with the
    clip)."""
    rng = np.random.default_rng(7)
    pos, yaw = _layouts(rng, 5, b=3)
    params = Params()
    op = OperatorModel(0.7, 0.02, 0.6, 0.0, "free")
    user = op.motion(params, clip) if clip else None
    if clip:  # the closed form's along/across spread is the curved one's widest when isotropic
        user = commit_mod.UserMotion(user.speed, user.widest, user.widest, user.rho)
    bt = commit_mod._Batch.of(P0, R0, pos, _rotations(yaw), np.ones(5), params, op, user)
    assert bt.guarded == clip
    t1, m1, s1 = commit_mod._terms(bt, params, slice(0, 5))
    t2, m2, s2 = commit_mod._path_terms(bt, params, slice(0, 5))
    np.testing.assert_array_equal(t1, t2)
    # used: the steps up to each row's arrival, against the other goals
    before = t1[None, None, :] <= bt.t_a[:, :, None]
    used = before[..., None] & ~np.eye(5, dtype=bool)[None, :, None, :]
    np.testing.assert_allclose(m2[used], m1[used], atol=1e-9)
    np.testing.assert_allclose(s2[used], s1[used], atol=1e-9)


def test_batches_split_into_pieces_give_the_unsplit_result(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    rng = np.random.default_rng(8)
    pos, yaw = _layouts(rng, 3, b=4)
    rot = _rotations(yaw)
    params = Params()
    op = OperatorModel(0.8, 0.03, 0.5, 15.0, "axes")
    whole = commit_batch(P0, R0, pos, rot, np.ones(3), params, None, "sum", op)
    monkeypatch.setattr(commit_mod, "CHUNK_ELEMENTS", 2000)  # below one layout: rows
    split = commit_batch(P0, R0, pos, rot, np.ones(3), params, None, "sum", op)
    np.testing.assert_array_equal(split.fraction, whole.fraction)
    np.testing.assert_array_equal(split.step, whole.step)


# --- what it certifies -------------------------------------------------------------------


def test_correlated_slow_and_biased_operators_are_certified_later_or_not_at_all() -> None:
    rng = np.random.default_rng(11)
    pos, yaw = _layouts(rng, 3, b=40)
    rot = _rotations(yaw)
    params = Params()
    paper = commit_batch(P0, R0, pos, rot, np.ones(3), params, form="sum")
    j_paper = certify_batch(P0, R0, pos, rot, np.ones(3), params).objective
    for op in (OperatorModel(rho=0.8), OperatorModel(speed=0.6), OperatorModel(rho=0.5)):
        k = commit_batch(P0, R0, pos, rot, np.ones(3), params, None, "sum", op)
        j = certify_batch(P0, R0, pos, rot, np.ones(3), params, op).objective
        assert np.all(j <= j_paper + 1e-12)
        assert np.all(k.count <= paper.count)
    # the certifying with sigma sqrt((1 + rho) / (1 - rho)) of the issue: at rho = 0.8 the
    # long-run variance is nine times the white one's
    assert ar1_sum_variance(10_000, 0.8) / 10_000 == pytest.approx(9.0, rel=1e-3)


def test_progress_is_the_path_length_at_the_certified_step_over_the_distance() -> None:
    rng = np.random.default_rng(12)
    pos, yaw = _layouts(rng, 2, b=20)
    params = Params()
    op = OperatorModel(0.6, 0.02, 0.0, 0.0, "free")
    k = commit_batch(P0, R0, pos, _rotations(yaw), np.ones(2), params, None, "sum", op)
    d = np.linalg.norm(pos - np.array(P0), axis=-1)
    ell = 0.6 * params.v_max * params.dt
    assert k.certified.any()
    np.testing.assert_allclose(k.progress[k.certified], (k.step * ell / d)[k.certified])
    assert np.all(np.isnan(k.progress[~k.certified]))


def orbiting(bias_deg: float = 80.0) -> OperatorModel:
    """An operator turned beyond the model's range (which stops at 45°, where every nominal
    arrives): its pursuit settles into an orbit of radius ``l / (2 cos b)`` around the goal,
    wider than a step, and never arrives. Built past the validation on purpose: the code must
    stay safe for a goal no nominal reaches."""
    op = OperatorModel(1.0, 0.01, 0.0, 0.0, "free")
    object.__setattr__(op, "bias_deg", bias_deg)
    return op


def test_a_goal_the_operator_cannot_reach_is_never_certified() -> None:
    """method.md §10: a nominal that does not arrive within 10^4 steps is not certified."""
    params = Params()
    op = orbiting()
    goals = np.array([[[0.85, 0.30, 0.30], [0.30, -0.40, 0.05]]])
    t_a, _ = nominal_steps(np.array(P0), goals, op, op.motion(params), params)
    assert np.all(t_a == 0)
    k = commit_batch(P0, R0, goals, _rotations(np.zeros((1, 2))), np.ones(2), params, None,
                     "sum", op)  # fmt: skip
    assert not k.reachable.any() and not k.certified.any()
    assert np.all(k.fraction == np.inf) and np.all(k.arrival_steps == 0)
    assert np.isinf(k.objective[0])
    # within the model's range every nominal arrives (45° is the worst it allows)
    edge = OperatorModel(1.0, 0.01, 0.0, 45.0, "axes")
    assert np.all(nominal_steps(np.array(P0), goals, edge, edge.motion(params), params)[0] > 0)


# --- the model's pieces -------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(rho=st.floats(0.0, 0.99), t=st.integers(1, 60))
def test_s_rho_is_the_variance_of_a_sum_of_ar1_terms(rho: float, t: int) -> None:
    brute = sum(rho ** abs(k - n) for k in range(t) for n in range(t))
    assert float(ar1_sum_variance(t, rho)) == pytest.approx(brute, rel=1e-9, abs=1e-9)


def test_s_rho_at_zero_is_t_exactly() -> None:
    t = np.arange(1, 500)
    assert np.array_equal(ar1_sum_variance(t, 0.0), t.astype(np.float64))


@settings(max_examples=80, deadline=None)
@given(
    v=st.tuples(*(st.floats(-1, 1) for _ in range(3))).filter(lambda v: np.linalg.norm(v) > 1e-3)
)
def test_quantise_picks_the_closest_direction_of_its_set(v: tuple[float, float, float]) -> None:
    u = np.array(v) / np.linalg.norm(v)
    for steering, dirs in (("axes", AXIS_DIRECTIONS), ("axes+diagonals", GRID_DIRECTIONS)):
        q = quantise(u, steering)
        assert np.linalg.norm(q) == pytest.approx(1.0)
        assert any(np.allclose(q, d) for d in dirs)
        assert q @ u >= np.max(dirs @ u) - 1e-12
    assert np.array_equal(quantise(u, "free"), u)
    assert np.array_equal(quantise(np.zeros(3), "axes+diagonals"), np.zeros(3))


def test_the_bias_turns_the_aim_anticlockwise_seen_from_above() -> None:
    op = OperatorModel(bias_deg=20.0)
    a = aim(np.zeros(3), np.array([1.0, 0.0, 0.0]), op)
    assert a == pytest.approx([math.cos(math.radians(20)), math.sin(math.radians(20)), 0.0])


def test_straight_path_closed_form_matches_the_loop() -> None:
    params = Params()
    goals = np.array([[0.8, 0.2, 0.05], [0.4, -0.3, 0.1]])
    op = OperatorModel(0.7)
    user = op.motion(params)
    closed = nominal_path(np.array(P0), goals, op, user, params, 50)
    here = np.array([P0, P0], dtype=float)
    for t in range(50):
        here = here + 0.7 * params.v_max * params.dt * aim(here, goals, op)
        np.testing.assert_allclose(closed[:, t], here, atol=1e-12)


@pytest.mark.parametrize("speed", [0.6, 1.0])
def test_clipped_moments_match_sampled_clipped_deflections(speed: float) -> None:
    rng = np.random.default_rng(0)
    u = clip_unit(np.array([speed, 0.0, 0.0]) + rng.standard_normal((400_000, 3)) * 0.6)
    mean, along, across = clipped_moments(speed, 0.6)
    assert mean == pytest.approx(u[:, 0].mean(), abs=3e-3)
    assert along == pytest.approx(u[:, 0].std(), abs=3e-3)
    assert across == pytest.approx(u[:, 1].std(), abs=3e-3)
    # a deflection that never reaches the rim is not clipped at all
    assert clipped_moments(0.3, 0.01) == pytest.approx((0.3, 0.01, 0.01), abs=1e-9)


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [("speed", {"speed": 0.0}), ("speed", {"speed": 1.2}), ("rho", {"rho": 1.0}),
     ("bias_deg", {"bias_deg": 60.0}), ("sigma", {"sigma": float("nan")}),
     ("steering", {"steering": "joystick"}), ("rho", {"rho": True})],
)  # fmt: skip
def test_a_model_out_of_range_names_its_field(field: str, kwargs: dict[str, object]) -> None:
    with pytest.raises(InputError) as err:
        OperatorModel(**kwargs)  # type: ignore[arg-type]
    assert err.value.field == field


# --- the Monte Carlo of the family ----------------------------------------------------------


def _goal_set(pos: np.ndarray):
    from legws_daemon.core.geometry import Pose
    from legws_daemon.core.goals import GoalSet

    x0 = Pose(np.array(P0), np.array([0.0, 1.0, 0.0, 0.0]))
    return GoalSet.build([f"g{i}" for i in range(len(pos))], pos, [[0, 1, 0, 0]] * len(pos), x0)


def test_the_monte_carlo_of_section_2s_user_is_the_same_given_as_an_operator() -> None:
    from legws_daemon.core.montecarlo import monte_carlo, simulate_commits
    from legws_daemon.core.user_model import SimulatedUser

    goals = _goal_set(np.array([[0.7, 0.2, 0.05], [0.7, -0.2, 0.05], [0.4, 0.3, 0.05]]))
    params = Params()
    for clip in (False, True):
        user = SimulatedUser.paper(params, clip)
        a = simulate_commits(goals, params, 200, np.random.default_rng(1), clip_speed=clip)
        b = simulate_commits(goals, params, 200, np.random.default_rng(1), user=user)
        for f in a:
            np.testing.assert_array_equal(a[f].step, b[f].step)
            np.testing.assert_array_equal(a[f].goal, b[f].goal)
    assert monte_carlo(goals, params, 300, 2) == monte_carlo(
        goals, params, 300, 2, user=SimulatedUser.paper(params)
    )


def test_operator_noise_has_the_models_correlation_and_variance() -> None:
    from legws_daemon.core.user_model import OperatorNoise

    rng = np.random.default_rng(0)
    noise = OperatorNoise(0.8)
    e = np.array([noise.step(rng.standard_normal((2000, 3))) for _ in range(60)])  # (T, N, 3)
    assert np.corrcoef(e[:-1].ravel(), e[1:].ravel())[0, 1] == pytest.approx(0.8, abs=0.01)
    assert e[-1].std() == pytest.approx(1.0, abs=0.03)  # stationary from the start
    assert e[0].std() == pytest.approx(1.0, abs=0.03)


@pytest.mark.parametrize("clip", [False, True])
def test_goals_certified_for_an_operator_keep_their_promise_under_that_operator(clip: bool) -> None:
    """The commit certificate (exact sum) of a correlated, slow, biased operator against a
    Monte Carlo of that operator: every certified goal's first commit is on it by its
    certified step in at least 95 % of the users (up to sampling error)."""
    from legws_daemon.core.commit import certify_commit
    from legws_daemon.core.montecarlo import monte_carlo_commit
    from legws_daemon.core.user_model import SimulatedUser

    op = OperatorModel(0.8, 0.02, 0.6, 10.0, "free")
    params = Params()
    rng = np.random.default_rng(21)
    checked = 0
    for _ in range(6):
        pos, _ = _layouts(rng, 3)
        goals = _goal_set(pos[0])
        cert = certify_commit(goals, params, op.motion(params, clip), "sum", op)
        steps = [cert.goals[n].step for n in goals.names]
        if not any(s is not None for s in steps):
            continue
        rates = monte_carlo_commit(
            goals, params, 300, np.random.default_rng(3), steps, user=SimulatedUser(op, clip)
        )
        for name, step in zip(goals.names, steps, strict=True):
            if step is not None:
                checked += 1
                assert rates[name].upper95 >= 1 - params.alpha, (name, rates[name])
    assert checked >= 3


def test_until_arrival_follows_a_slower_user_past_the_nominal_arrival() -> None:
    """An idle-on-20 %-of-ticks user is at 80 % of the way by the model's T_a; followed to
    its own arrival it makes the commits it would make, and those up to T_a are the same."""
    from legws_daemon.core.montecarlo import simulate_commits
    from legws_daemon.core.user_model import SimulatedUser

    goals = _goal_set(np.array([[0.75, 0.12, 0.05], [0.75, -0.12, 0.05]]))  # told apart late
    params = Params()
    user = SimulatedUser(OperatorModel(), idle=0.2)
    a = simulate_commits(goals, params, 300, np.random.default_rng(2), user=user)["dragan"]
    b = simulate_commits(goals, params, 300, np.random.default_rng(2), user=user,
                         until_arrival=True)["dragan"]  # fmt: skip
    early = a.step > 0
    np.testing.assert_array_equal(b.step[early], a.step[early])
    assert (b.step > 0).sum() >= early.sum()
    assert (b.step > a.arrival_steps[:, None]).any()  # commits after the model's arrival
