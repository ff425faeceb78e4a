"""Monte Carlo check of the certificate (method.md section 4), vectorised over trials.

The simulated user of section 2 drives the end effector from ``x0`` toward the true goal
``g*`` with ``v = v_max pi_h(x, g*) + eps``, ``eps ~ N(0, sigma^2 I)``, orientation held,
for the certificate's horizon ``T(g*)``. The certificate's model does not clip the speed;
``clip_speed=True`` applies the robot's clip ``|v| <= v_max`` as well. At step ``T`` the
observer's argmax is compared with ``g*``; accuracy comes with a Clopper-Pearson interval.

The commit certificate's check (method.md section 9): :func:`simulate_commits` rolls the
same users out to arrival and records each observer's first commit (step, goal, and how far
along the way); :func:`commit_rates` turns that into the promised rate by the certified
step, wrong commits and commits before arrival, per goal.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import betaincinv

from legws_daemon.core.certificate import horizon_steps, start_terms
from legws_daemon.core.commit import arrival_steps, clipped_user
from legws_daemon.core.costs import path_costs, posterior
from legws_daemon.core.geometry import FloatArray, IntArray, safe_unit
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import CostForm, Params
from legws_daemon.core.user_model import clip_unit, deflection, noise
from legws_daemon.errors import InputError

#: Confidence level of the reported Clopper-Pearson interval (two-sided).
CONFIDENCE = 0.95


@dataclass(frozen=True, slots=True)
class GoalAccuracy:
    """Accuracy at the horizon for one true goal."""

    accuracy: float
    lower95: float
    upper95: float
    correct: int
    trials: int


def clopper_pearson(
    correct: int, trials: int, confidence: float = CONFIDENCE
) -> tuple[float, float]:
    """Exact two-sided binomial confidence interval ``(lower, upper)``."""
    if trials <= 0 or not 0 <= correct <= trials:
        raise InputError(f"need 0 <= correct <= trials and trials > 0, got {correct}/{trials}")
    tail = (1.0 - confidence) / 2.0
    # quantiles of the Beta distributions of the exact interval
    lower = 0.0 if correct == 0 else float(betaincinv(correct, trials - correct + 1, tail))
    upper = 1.0 if correct == trials else float(betaincinv(correct + 1, trials - correct, 1 - tail))
    return lower, upper


@dataclass(frozen=True, slots=True)
class HorizonStates:
    """Simulated end states at each true goal's horizon.

    Attributes:
        positions: ``(M, N, 3)`` EE position at step ``T_i`` for true goal ``i``.
        lengths: ``(M, N)`` path length at that step.
        steps: ``(M,)`` the horizons ``T_i``.
    """

    positions: FloatArray
    lengths: FloatArray
    steps: IntArray


def _start_terms(goals: GoalSet, params: Params) -> tuple[FloatArray, FloatArray]:
    """Each goal's ``(|p_g - p0|, lambda_R angle)`` from the goal set's start, ``(M,)`` each."""
    x0 = goals.x0
    p0 = np.asarray(x0.position, dtype=np.float64)
    return start_terms(p0, x0.rotation, goals.positions, goals.rotations, goals.symmetry, params)


def _advance(
    x: FloatArray,
    length: FloatArray,
    target: FloatArray,
    active: np.ndarray,
    rng: np.random.Generator,
    params: Params,
    clip_speed: bool,
) -> None:
    """One control period of the noisy users ``x`` ``(M, N, 3)`` toward ``target``, in place;
    rows where ``active`` ``(M, 1)`` is false stay put. ``length`` accumulates the path."""
    m, trials = length.shape
    u = deflection(x, target, noise(rng, (m, trials), params.sigma, params.v_max))
    if clip_speed:
        u = clip_unit(u)
    dx = params.v_max * params.dt * u
    x += np.where(active[..., None], dx, 0.0)
    length += np.where(active, np.sqrt(np.einsum("mnk,mnk->mn", dx, dx)), 0.0)


def simulate_user(
    goals: GoalSet,
    params: Params,
    trials: int,
    rng: np.random.Generator,
    *,
    clip_speed: bool = False,
) -> HorizonStates:
    """Roll out ``trials`` noisy users per true goal up to that goal's horizon."""
    if trials < 1:
        raise InputError(f"expected at least 1 trial, got {trials}", field="trials")
    p0 = goals.x0.position
    target = goals.positions[:, None, :]  # (M, 1, 3)
    steps = horizon_steps(np.linalg.norm(goals.positions - p0, axis=1), params)
    m = goals.m
    x = np.broadcast_to(p0, (m, trials, 3)).copy()
    length = np.zeros((m, trials))
    for t in range(int(steps.max())):
        _advance(x, length, target, (t < steps)[:, None], rng, params, clip_speed)
    return HorizonStates(x, length, steps)


def horizon_correct(
    goals: GoalSet, params: Params, states: HorizonStates, cost: CostForm
) -> IntArray:
    """Number of trials per true goal whose observer argmax at the horizon is the true goal."""
    trans0, rot = _start_terms(goals, params)
    d0 = trans0 + rot
    diff = states.positions[:, :, None, :] - goals.positions[None, None, :, :]
    dist_now = np.sqrt(np.einsum("mngk,mngk->mng", diff, diff)) + rot
    costs = path_costs(states.lengths, dist_now, d0, cost)  # (M, N, M)
    best = np.argmin(costs, axis=-1)
    return np.asarray((best == np.arange(goals.m)[:, None]).sum(axis=1), dtype=np.int64)


def monte_carlo(
    goals: GoalSet,
    params: Params,
    trials: int,
    seed: int = 0,
    *,
    clip_speed: bool = False,
    costs: Sequence[CostForm] | None = None,
) -> dict[CostForm, dict[str, GoalAccuracy]]:
    """Accuracy at the horizon per true goal, for each requested cost form.

    The same simulated trajectories serve every cost form (common random numbers), so the
    forms are compared on identical user behaviour. Same seed, same result.
    """
    forms: Sequence[CostForm] = costs if costs is not None else (params.cost,)
    rng = np.random.default_rng(seed)
    states = simulate_user(goals, params, trials, rng, clip_speed=clip_speed)
    out: dict[CostForm, dict[str, GoalAccuracy]] = {}
    for form in forms:
        correct = horizon_correct(goals, params, states, form)
        per_goal: dict[str, GoalAccuracy] = {}
        for name, k in zip(goals.names, correct, strict=True):
            lo, hi = clopper_pearson(int(k), trials)
            per_goal[name] = GoalAccuracy(int(k) / trials, lo, hi, int(k), trials)
        out[form] = per_goal
    return out


@dataclass(frozen=True, slots=True)
class CommitRollouts:
    """First commits of simulated users, per true goal and trial.

    Attributes:
        step: ``(M, N)`` the step of the first commit (``max_g P >= p_thresh``), ``0`` when
            none before arrival.
        goal: ``(M, N)`` the goal committed to, ``-1`` when none.
        progress: ``(M, N)`` how far along the way to the true goal the user had come by
            the first commit (the largest projection on the straight way so far), m;
            ``inf`` when none.
        arrival_steps: ``(M,)`` ``T_a`` of each true goal (method.md §9).
        step_length: ``v_max dt``, m.
    """

    step: IntArray
    goal: IntArray
    progress: FloatArray
    arrival_steps: IntArray
    step_length: float


def simulate_commits(
    goals: GoalSet,
    params: Params,
    trials: int,
    rng: np.random.Generator,
    *,
    clip_speed: bool = False,
    costs: Sequence[CostForm] | None = None,
    true_goals: Sequence[int] | None = None,
) -> dict[CostForm, CommitRollouts]:
    """Roll out ``trials`` noisy users per true goal for ``T_a`` steps and record each
    observer's first commit, for each cost form on the same trajectories. With
    ``clip_speed`` the users are the robot's (speed clipped to ``v_max``) and ``T_a`` is
    that slower motion's (:func:`~legws_daemon.core.commit.clipped_user`). ``true_goals``
    limits the rollouts to those true goals (the other rows stay without a commit)."""
    if trials < 1:
        raise InputError(f"expected at least 1 trial, got {trials}", field="trials")
    forms: Sequence[CostForm] = costs if costs is not None else (params.cost,)
    p0 = goals.x0.position
    rows = np.arange(goals.m) if true_goals is None else np.asarray(true_goals, dtype=np.int64)
    m = len(rows)
    target = goals.positions[rows, None, :]
    # the clipped user is slower: it arrives after the clipped motion's T_a
    speed = clipped_user(params).speed if clip_speed else 1.0
    trans0, rot = _start_terms(goals, params)
    t_a_all = arrival_steps(trans0, params, speed)
    t_a = t_a_all[rows]
    d0 = trans0 + rot
    way = safe_unit(goals.positions[rows] - p0)[:, None, :]  # (m, 1, 3)
    x = np.broadcast_to(p0, (m, trials, 3)).copy()
    length = np.zeros((m, trials))
    furthest = np.zeros((m, trials))
    first_step = {f: np.zeros((m, trials), dtype=np.int64) for f in forms}
    first_goal = {f: np.full((m, trials), -1, dtype=np.int64) for f in forms}
    first_progress = {f: np.full((m, trials), np.inf) for f in forms}
    for t in range(1, int(t_a.max(initial=0)) + 1):
        active = (t <= t_a)[:, None]  # (M, 1)
        _advance(x, length, target, active, rng, params, clip_speed)
        furthest = np.maximum(furthest, np.einsum("mnk,mnk->mn", x - p0, way))
        diff = x[:, :, None, :] - goals.positions[None, None, :, :]
        dist_now = np.sqrt(np.einsum("mngk,mngk->mng", diff, diff)) + rot
        for form in forms:
            post = posterior(path_costs(length, dist_now, d0, form), params.beta)
            best = np.argmax(post, axis=-1)
            hit = (np.max(post, axis=-1) >= params.p_thresh) & active & (first_goal[form] < 0)
            first_step[form] = np.where(hit, t, first_step[form])
            first_goal[form] = np.where(hit, best, first_goal[form])
            first_progress[form] = np.where(hit, furthest, first_progress[form])
    step = params.v_max * params.dt
    out: dict[CostForm, CommitRollouts] = {}
    for f in forms:
        steps = np.zeros((goals.m, trials), dtype=np.int64)
        chosen = np.full((goals.m, trials), -1, dtype=np.int64)
        progress = np.full((goals.m, trials), np.inf)
        steps[rows], chosen[rows], progress[rows] = first_step[f], first_goal[f], first_progress[f]
        out[f] = CommitRollouts(steps, chosen, progress, t_a_all, step)
    return out


@dataclass(frozen=True, slots=True)
class GoalCommitRate:
    """Monte Carlo of one true goal's first commit (interfaces.md ``monte_carlo_commit``).

    Attributes:
        rate_by_step: fraction whose first commit is on the true goal at or before
            ``by_step`` (the certified commit step, or ``T_a`` when the goal has none).
        lower95, upper95: its Clopper-Pearson interval.
        rate_by_progress: fraction whose first commit is on the true goal before they
            first came further along the way than ``by_step`` nominal steps (``by_step v_max
            dt``): the promise in distance rather than time, which is what a slower
            (speed-clipped) user gets.
        progress_upper95: the Clopper-Pearson upper bound of ``rate_by_progress``.
        wrong: fraction whose first commit (before arrival) is on another goal.
        before_arrival: fraction whose first commit is on the true goal before arrival.
        by_step: the step ``rate_by_step`` is counted at.
        trials: simulated users.
    """

    rate_by_step: float
    lower95: float
    upper95: float
    rate_by_progress: float
    progress_upper95: float
    wrong: float
    before_arrival: float
    by_step: int
    trials: int


def commit_rates(
    rollouts: CommitRollouts, by_step: Sequence[int | None], names: Sequence[str]
) -> dict[str, GoalCommitRate]:
    """Per-goal commit statistics; ``by_step[i]`` is goal ``i``'s certified step (``None``:
    count up to arrival)."""
    out: dict[str, GoalCommitRate] = {}
    trials = rollouts.step.shape[1]
    for i, name in enumerate(names):
        step = by_step[i]
        limit = int(rollouts.arrival_steps[i]) if step is None else int(step)
        on_true = rollouts.goal[i] == i
        timely = int(np.sum(on_true & (rollouts.step[i] <= limit)))
        lo, hi = clopper_pearson(timely, trials)
        early = int(
            np.sum(on_true & (rollouts.progress[i] <= limit * rollouts.step_length + 1e-12))
        )
        out[name] = GoalCommitRate(
            rate_by_step=timely / trials,
            lower95=lo,
            upper95=hi,
            rate_by_progress=early / trials,
            progress_upper95=clopper_pearson(early, trials)[1],
            wrong=float(np.mean((rollouts.goal[i] >= 0) & ~on_true)),
            before_arrival=float(np.mean(on_true)),
            by_step=limit,
            trials=trials,
        )
    return out
