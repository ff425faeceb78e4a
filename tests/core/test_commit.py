"""The commit certificate (method.md §9) against an independent, step-by-step implementation
of the section, its invariants, and the Monte Carlo check of what it promises."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import norm

from legws_daemon.core import commit as commit_mod
from legws_daemon.core.commit import (
    arrival_steps,
    certify_commit,
    clipped_user,
    commit_batch,
    commit_chance_batch,
    commit_time_batch,
    thresholds,
)
from legws_daemon.core.geometry import Pose
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.montecarlo import commit_rates, simulate_commits
from legws_daemon.core.params import Params

DOWN = [0.0, 1.0, 0.0, 0.0]
X0 = Pose(np.array([0.55, 0.0, 0.30]), np.array(DOWN))


def _angle(q0: list[float], q: list[float], n: int) -> float:
    """Geodesic angle between two [w, x, y, z] rotations over the n-fold symmetric turns of
    the second about its own z axis (n = 0: any turn: the angle between the z axes)."""
    r0 = Rotation.from_quat([q0[1], q0[2], q0[3], q0[0]])
    r = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    if n == 0:
        z0, z = r0.apply([0, 0, 1]), r.apply([0, 0, 1])
        return math.acos(max(-1.0, min(1.0, float(np.dot(z0, z)))))
    return min(
        float((r0.inv() * r * Rotation.from_rotvec([0, 0, 2 * math.pi * k / n])).magnitude())
        for k in range(n)
    )


def reference(
    p0: list[float],
    q0: list[float],
    goals: list[tuple[list[float], list[float], int]],
    p: Params,
    form: str = "min",
) -> list[dict[str, float | int | bool | None]]:
    """Section 9 written out literally: one true goal, one step, one alternative at a time
    (``form="sum"``: the exact sum, ``ln((1-p)/p) - ln sum_j exp(-l_j)``)."""
    m = len(goals)
    step = p.v_max * p.dt
    rot = [p.rotation_weight * _angle(q0, q, n) for _, q, n in goals]
    d0 = [math.dist(p0, g) + rot[j] for j, (g, _, _) in enumerate(goals)]
    D = sum(d0) / m

    def cost(j: int, point: list[float], length: float) -> float:
        d = math.dist(point, goals[j][0]) + rot[j]
        return (length + d - d0[j]) / D if p.cost == "dragan" else (length + d) / d0[j]

    def grad(j: int, point: list[float]) -> list[float]:
        diff = [a - b for a, b in zip(point, goals[j][0], strict=True)]
        n = math.sqrt(sum(x * x for x in diff))
        s = D if p.cost == "dragan" else d0[j]
        return [0.0, 0.0, 0.0] if n <= 1e-12 else [x / n / s for x in diff]

    odds = p.p_thresh / (1 - p.p_thresh)
    tau_c, tau_w = math.log((m - 1) * odds), math.log(odds)
    z_c = norm.ppf(1 - p.alpha / (2 * (m - 1)))
    out = []
    for i, (gi, _, _) in enumerate(goals):
        r = math.dist(p0, gi)
        t_a = max(1, math.floor(r / step + 1e-9))
        u = [(a - b) / r for a, b in zip(gi, p0, strict=True)]
        margins: list[list[float]] = []
        sds: list[list[float]] = []
        c = []
        for t in range(1, t_a + 1):
            point = [a + t * step * b for a, b in zip(p0, u, strict=True)]
            ms, ss = [], []
            for j in range(m):
                if j == i:
                    continue
                ms.append(p.beta * (cost(j, point, t * step) - cost(i, point, t * step)))
                a = [x - y for x, y in zip(grad(j, point), grad(i, point), strict=True)]
                var = p.beta**2 * sum(x * x for x in a) * t * p.sigma**2 * p.dt**2
                ss.append(math.sqrt(var))
            margins.append(ms)
            sds.append(ss)
            lows = [mg - z_c * sd for mg, sd in zip(ms, ss, strict=True)]
            if form == "min":
                c.append(min(lows) - tau_c)
            else:
                c.append(-tau_w - math.log(sum(math.exp(-x) for x in lows)))
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
            t_hat = (t_c - 1) + (0 - before) / (c[t_c - 1] - before)
            kappa = t_hat / t_a
        else:
            kappa = 1 + max(0.0, -c[t_a - 1]) + max(0.0, -w)
        out.append(
            {
                "kappa": kappa,
                "t_c": t_c,
                "t_a": t_a,
                "c_arrival": c[t_a - 1],
                "w": w,
                "certified": certified,
            }
        )
    return out


def random_goals(rng: np.random.Generator, m: int) -> list[tuple[list[float], list[float], int]]:
    goals = []
    for _ in range(m):
        pos = [rng.uniform(0.3, 0.85), rng.uniform(-0.45, 0.45), rng.uniform(0.02, 0.12)]
        yaw = rng.uniform(-math.pi, math.pi)
        q = Rotation.from_euler("xz", [math.pi, yaw]).as_quat()  # gripper down, turned
        n = int(rng.choice([0, 1, 2, 4]))
        goals.append((pos, [q[3], q[0], q[1], q[2]], n))
    return goals


def goal_set(goals: list[tuple[list[float], list[float], int]]) -> GoalSet:
    return GoalSet.build(
        [f"g{i}" for i in range(len(goals))],
        [g[0] for g in goals],
        [g[1] for g in goals],
        X0,
        [g[2] for g in goals],
    )


@pytest.mark.parametrize("form", ["min", "sum"])
@pytest.mark.parametrize("cost", ["dragan", "ratio"])
@pytest.mark.parametrize("m", [2, 3, 5, 8])
def test_matches_an_independent_implementation(cost: str, m: int, form: str) -> None:
    rng = np.random.default_rng(100 + m)
    params = Params(cost=cost)  # type: ignore[arg-type]
    for _ in range(4):
        goals = random_goals(rng, m)
        got = certify_commit(goal_set(goals), params, form=form)
        want = reference(X0.position.tolist(), DOWN, goals, params, form)
        for i, ref in enumerate(want):
            g = got.goals[f"g{i}"]
            assert g.arrival_steps == ref["t_a"]
            assert g.crossing_step == ref["t_c"]
            assert g.certified == ref["certified"]
            assert g.step == (ref["t_c"] if ref["certified"] else None)
            assert g.slack_at_arrival == pytest.approx(ref["c_arrival"], abs=1e-6)
            assert g.wrong_commit_slack == pytest.approx(ref["w"], abs=1e-6)
            assert g.fraction == pytest.approx(ref["kappa"], abs=1e-6)
        assert got.objective == pytest.approx(max(float(r["kappa"]) for r in want), abs=1e-6)  # type: ignore[arg-type]
        assert got.certified == sum(bool(r["certified"]) for r in want)


def test_a_certified_two_goal_set_by_hand() -> None:
    # two goals far apart on either side: the commit is certified well before arrival
    goals = [([0.80, 0.35, 0.02], DOWN, 1), ([0.80, -0.35, 0.02], DOWN, 1)]
    cert = certify_commit(goal_set(goals), Params())
    ref = reference(X0.position.tolist(), DOWN, goals, Params())
    for i in range(2):
        g = cert.goals[f"g{i}"]
        assert g.certified and g.step is not None and g.step < g.arrival_steps
        assert 0 < g.fraction < 1
        assert g.fraction == pytest.approx(ref[i]["kappa"], abs=1e-9)
    assert cert.objective <= 1.0 and cert.certified == 2


def test_thresholds_and_arrival_steps() -> None:
    tau_c, tau_w = thresholds(2, 0.9)
    assert tau_c == pytest.approx(math.log(9)) and tau_w == pytest.approx(math.log(9))
    tau_c, _ = thresholds(8, 0.9)
    assert tau_c == pytest.approx(math.log(63))
    p = Params()
    # 0.3 m at 2.5 mm per step is exactly 120 steps; 0.3024 is 120.96 -> 120; tiny -> 1
    assert arrival_steps(np.array([0.3, 0.3024, 1e-4]), p).tolist() == [120, 120, 1]


def test_coincident_goals_are_never_certified() -> None:
    goals = [([0.8, 0.0, 0.02], DOWN, 1), ([0.8, 0.0, 0.02], DOWN, 1), ([0.5, 0.3, 0.02], DOWN, 1)]
    cert = certify_commit(goal_set(goals), Params())
    assert not cert.goals["g0"].certified and not cert.goals["g1"].certified
    assert cert.goals["g0"].fraction > 1 and cert.objective > 1


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(2, 6), chunk=st.integers(1, 5))
def test_batch_equals_one_at_a_time_and_chunks_do_not_matter(seed: int, m: int, chunk: int) -> None:
    rng = np.random.default_rng(seed)
    sets = [goal_set(random_goals(rng, m)) for _ in range(5)]
    pos = np.stack([g.positions for g in sets])
    rot = np.stack([g.rotations for g in sets])
    sym = np.stack([g.symmetry for g in sets])
    whole = commit_batch(X0.position, X0.rotation, pos, rot, sym, Params())
    old = commit_mod.CHUNK_ELEMENTS
    try:  # force chunks of about `chunk` layouts
        commit_mod.CHUNK_ELEMENTS = chunk * m * m * int(whole.arrival_steps.max())
        split = commit_batch(X0.position, X0.rotation, pos, rot, sym, Params())
    finally:
        commit_mod.CHUNK_ELEMENTS = old
    np.testing.assert_array_equal(whole.fraction, split.fraction)
    for b, g in enumerate(sets):
        one = certify_commit(g, Params())
        assert one.objective == pytest.approx(float(whole.objective[b]), abs=1e-12)
        # invariants: K <= 1 exactly when every goal is certified; kappa in (0, 1] then
        assert (one.objective <= 1.0) == (one.certified == m)
        for gc in one.goals.values():
            assert (0 < gc.fraction <= 1) if gc.certified else gc.fraction >= 1
            if gc.crossing_step is not None:
                assert 1 <= gc.crossing_step <= gc.arrival_steps


def test_a_lower_threshold_commits_no_later() -> None:
    goals = goal_set([([0.8, 0.3, 0.02], DOWN, 1), ([0.7, -0.3, 0.02], DOWN, 1)])
    strict = certify_commit(goals, Params(p_thresh=0.95))
    loose = certify_commit(goals, Params(p_thresh=0.8))
    for name in goals.names:
        assert loose.goals[name].fraction <= strict.goals[name].fraction


def test_monte_carlo_keeps_the_promise_on_a_certified_set() -> None:
    goals = goal_set(
        [
            ([0.80, 0.35, 0.02], DOWN, 1),
            ([0.80, -0.35, 0.02], DOWN, 1),
            ([0.35, 0.0, 0.02], DOWN, 1),
        ]
    )
    params = Params()
    cert = certify_commit(goals, params)
    assert cert.certified >= 2
    rollouts = simulate_commits(goals, params, 3000, np.random.default_rng(3))["dragan"]
    rates = commit_rates(rollouts, [cert.goals[n].step for n in goals.names], goals.names)
    for name in goals.names:
        r = rates[name]
        assert 0.0 <= r.wrong <= 1.0 - r.before_arrival + 1e-12
        assert r.rate_by_step <= r.before_arrival
        if cert.goals[name].certified:
            assert r.by_step == cert.goals[name].step
            assert r.upper95 >= 1 - params.alpha  # honest up to sampling error


def test_monte_carlo_first_commit_matches_a_plain_observer_loop() -> None:
    """The vectorised rollout's first commit equals a one-trial loop over the posterior."""
    from legws_daemon.core.costs import path_costs, posterior
    from legws_daemon.core.user_model import deflection, noise

    goals = goal_set([([0.75, 0.2, 0.02], DOWN, 1), ([0.7, -0.2, 0.05], DOWN, 2)])
    params = Params()
    trials = 7
    got = simulate_commits(goals, params, trials, np.random.default_rng(9))["dragan"]
    rng = np.random.default_rng(9)
    t_a = got.arrival_steps
    m = goals.m
    x = np.broadcast_to(goals.x0.position, (m, trials, 3)).copy()
    length = np.zeros((m, trials))
    first = np.full((m, trials), -1)
    step = np.zeros((m, trials), dtype=int)
    d0 = np.linalg.norm(goals.positions - goals.x0.position, axis=1)
    for t in range(1, int(t_a.max()) + 1):
        eps = noise(rng, (m, trials), params.sigma, params.v_max)
        for i in range(m):
            if t > t_a[i]:
                continue
            for n in range(trials):
                u = deflection(x[i, n], goals.positions[i], eps[i, n])
                dx = params.v_max * params.dt * u
                x[i, n] += dx
                length[i, n] += float(np.linalg.norm(dx))
                d = np.linalg.norm(goals.positions - x[i, n], axis=1)
                post = posterior(path_costs(length[i, n], d, d0, "dragan"), params.beta)
                if first[i, n] < 0 and post.max() >= params.p_thresh:
                    first[i, n], step[i, n] = int(post.argmax()), t
    np.testing.assert_array_equal(got.goal, first)
    np.testing.assert_array_equal(got.step, step)


def test_clipped_user_moments_match_sampled_clipped_deflections() -> None:
    from legws_daemon.core.commit import clipped_user
    from legws_daemon.core.user_model import clip_unit

    p = Params()
    user = clipped_user(p)
    rng = np.random.default_rng(0)
    u = clip_unit(np.array([1.0, 0.0, 0.0]) + rng.standard_normal((400_000, 3)) * 0.6)
    assert user.speed == pytest.approx(u[:, 0].mean(), abs=3e-3)
    assert user.along == pytest.approx(u[:, 0].std(), abs=3e-3)
    assert user.across == pytest.approx(u[:, 1].std(), abs=3e-3)
    assert user.speed < 1.0  # the clipped user is slower ...
    # ... and less noisy per metre along the way than the unclipped one
    assert user.across**2 / user.speed < (p.sigma / p.v_max) ** 2


def test_equal_moments_reduce_to_the_section_9_variance() -> None:
    from legws_daemon.core.commit import UserMotion, unclipped_user

    rng = np.random.default_rng(4)
    goals = goal_set(random_goals(rng, 4))
    p = Params()
    default = certify_commit(goals, p)
    s = p.sigma / p.v_max
    assert unclipped_user(p) == UserMotion(1.0, s, s)
    explicit = certify_commit(goals, p, UserMotion(1.0, s, s))
    assert explicit == default
    # more noise along the way than across it can only delay or lose the commit
    noisier = certify_commit(goals, p, UserMotion(1.0, 2 * s, s))
    for name in goals.names:
        assert noisier.goals[name].fraction >= default.goals[name].fraction - 1e-12


def test_the_clipped_certificate_is_honest_for_clipped_users() -> None:
    from legws_daemon.core.commit import clipped_user

    goals = goal_set(
        [
            ([0.80, 0.35, 0.02], DOWN, 1),
            ([0.80, -0.35, 0.02], DOWN, 1),
            ([0.35, 0.0, 0.02], DOWN, 1),
        ]
    )
    p = Params()
    plain, clipped = certify_commit(goals, p), certify_commit(goals, p, clipped_user(p))
    rolls = simulate_commits(goals, p, 2000, np.random.default_rng(5), clip_speed=True)["dragan"]
    rates = commit_rates(rolls, [clipped.goals[n].step for n in goals.names], goals.names)
    late = commit_rates(rolls, [plain.goals[n].step for n in goals.names], goals.names)
    for name in goals.names:
        c = clipped.goals[name]
        assert c.arrival_steps > plain.goals[name].arrival_steps  # slower: arrives later
        if c.certified:
            assert rates[name].upper95 >= 1 - p.alpha
            # the unclipped step comes too early for the clipped robot
            if plain.goals[name].certified:
                assert late[name].rate_by_step < rates[name].rate_by_step


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(2, 8))
def test_the_exact_sum_is_never_less_certain_than_the_even_split(seed: int, m: int) -> None:
    goals = goal_set(random_goals(np.random.default_rng(seed), m))
    even = certify_commit(goals, Params(), form="min")
    exact = certify_commit(goals, Params(), form="sum")
    assert exact.objective <= even.objective + 1e-12
    assert exact.certified >= even.certified
    for name in goals.names:
        a, b = even.goals[name], exact.goals[name]
        assert b.fraction <= a.fraction + 1e-12
        assert b.slack_at_arrival >= a.slack_at_arrival - 1e-12
        assert not a.certified or b.certified
        if m == 2:  # one alternative: the two forms are the same
            assert b == a


def test_unknown_commit_form_is_an_input_error() -> None:
    from legws_daemon.errors import InputError

    with pytest.raises(InputError, match="known: min, sum"):
        certify_commit(goal_set(random_goals(np.random.default_rng(0), 3)), Params(), form="max")


def test_the_exact_sum_keeps_its_promise_on_a_set_where_it_certifies_more() -> None:
    """Five goals where the exact sum certifies goals that the even split does not; the
    simulated users still commit on them by the (earlier) certified step."""
    rng = np.random.default_rng(11)
    p = Params()
    for _ in range(200):  # find such a set among random ones
        goals = goal_set(random_goals(rng, 5))
        even, exact = certify_commit(goals, p), certify_commit(goals, p, form="sum")
        if exact.certified > even.certified:
            break
    else:
        pytest.fail("no goal set where the exact sum certifies more")
    rolls = simulate_commits(goals, p, 2000, np.random.default_rng(12))["dragan"]
    rates = commit_rates(rolls, [exact.goals[n].step for n in goals.names], goals.names)
    for name in goals.names:
        if exact.goals[name].certified:
            assert rates[name].upper95 >= 1 - p.alpha


def _chance(goals: list[tuple[list[float], list[float], int]], params: Params) -> np.ndarray:
    gs = goal_set(goals)
    chance = commit_chance_batch(
        gs.x0.position, gs.x0.rotation, gs.positions[None], gs.rotations[None], gs.symmetry,
        params, clipped_user(params),
    )  # fmt: skip
    return np.asarray(chance[0])


def test_commit_chance_follows_the_monte_carlo_rate_it_estimates() -> None:
    # the search surrogate of the rate a person sees: per goal, close to the Monte Carlo
    # rate of first commits on the true goal before arrival (the robot's clipped user)
    rng = np.random.default_rng(7)
    params = Params()
    est: list[float] = []
    got: list[float] = []
    for m in (3, 5, 8):
        for _ in range(4):
            goals = random_goals(rng, m)
            rolls = simulate_commits(goal_set(goals), params, 200, rng, clip_speed=True)
            rates = commit_rates(rolls[params.cost], [None] * m, [f"g{i}" for i in range(m)])
            est.extend(_chance(goals, params).tolist())
            got.extend(r.before_arrival for r in rates.values())
    e, g = np.array(est), np.array(got)
    assert np.all((e >= 0) & (e <= 1))
    assert np.corrcoef(e, g)[0, 1] > 0.9
    assert np.mean(np.abs(e - g)) < 0.08
    assert abs(e.mean() - g.mean()) < 0.05


def test_commit_chance_without_noise_is_the_noise_free_commit() -> None:
    # sigma -> 0: the chance is 1 exactly for the goals whose noise-free posterior reaches
    # p before arrival, which is the exact-sum commit certificate's crossing without noise
    rng = np.random.default_rng(11)
    params = Params(sigma=1e-9)
    for m in (2, 3, 5, 8):
        for _ in range(3):
            goals = random_goals(rng, m)
            chance = _chance(goals, params)
            cert = commit_batch(
                X0.position, X0.rotation, goal_set(goals).positions[None],
                goal_set(goals).rotations[None], goal_set(goals).symmetry, params,
                clipped_user(params), form="sum",
            )  # fmt: skip
            crossed = cert.step[0] > 0
            assert np.array_equal(chance > 0.5, crossed)
            assert np.all((chance < 1e-6) | (chance > 1 - 1e-6))


def test_commit_chance_grows_as_goals_move_apart() -> None:
    params = Params()
    near = [([0.80, 0.06, 0.02], DOWN, 1), ([0.80, -0.06, 0.02], DOWN, 1)]
    far = [([0.80, 0.30, 0.02], DOWN, 1), ([0.80, -0.30, 0.02], DOWN, 1)]
    assert np.all(_chance(far, params) > _chance(near, params))
    assert np.all(_chance(far, params) > 0.99)


def test_commit_time_without_noise_is_the_noise_free_crossing() -> None:
    # the time surrogate is the crossing of the noise-free posterior slack: with sigma -> 0
    # it is the exact-sum commit certificate's interpolated crossing, in seconds
    rng = np.random.default_rng(12)
    params = Params(sigma=1e-9)
    user = clipped_user(params)
    for m in (2, 3, 5):
        for _ in range(3):
            gs = goal_set(random_goals(rng, m))
            args = (gs.x0.position, gs.x0.rotation, gs.positions[None], gs.rotations[None],
                    gs.symmetry, params, user)  # fmt: skip
            times = commit_time_batch(*args)[0]
            cert = commit_batch(*args, form="sum")
            for i in range(m):
                t_a = int(cert.arrival_steps[0, i])
                if cert.certified[0, i]:
                    want = cert.fraction[0, i] * t_a * params.dt
                    assert times[i] == pytest.approx(want, rel=1e-6)  # sigma 1e-9, not 0
                else:
                    assert times[i] >= t_a * params.dt - 1e-12


def test_commit_time_follows_the_monte_carlo_commit_time() -> None:
    # for goals that (nearly) always commit, the surrogate is the median first-commit time
    rng = np.random.default_rng(5)
    params = Params()
    user = clipped_user(params)
    est: list[float] = []
    got: list[float] = []
    for m in (2, 3):
        for _ in range(6):
            goals = random_goals(rng, m)
            gs = goal_set(goals)
            times = commit_time_batch(gs.x0.position, gs.x0.rotation, gs.positions[None],
                                      gs.rotations[None], gs.symmetry, params, user)[0]  # fmt: skip
            roll = simulate_commits(gs, params, 200, rng, clip_speed=True)[params.cost]
            for i in range(m):
                on_true = roll.goal[i] == i
                if on_true.mean() > 0.95:
                    est.append(float(times[i]))
                    got.append(float(np.median(roll.step[i][on_true])) * params.dt)
    assert len(est) >= 8
    e, g = np.array(est), np.array(got)
    assert np.corrcoef(e, g)[0, 1] > 0.9
    assert np.median(np.abs(e - g) / g) < 0.1
