"""Monte Carlo check of the certificate (method.md section 4), vectorised over trials.

The simulated user of section 2 drives the end effector from ``x0`` toward the true goal
``g*`` with ``v = v_max pi_h(x, g*) + eps``, ``eps ~ N(0, sigma^2 I)``, orientation held,
for the certificate's horizon ``T(g*)``. The certificate's model does not clip the speed;
``clip_speed=True`` applies the robot's clip ``|v| <= v_max`` as well. At step ``T`` the
observer's argmax is compared with ``g*``; accuracy comes with a Clopper-Pearson interval.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import betaincinv

from legws_daemon.core.certificate import horizon_steps
from legws_daemon.core.costs import path_costs
from legws_daemon.core.geometry import FloatArray, IntArray, symmetric_angle
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
        active = (t < steps)[:, None]  # (M, 1)
        u = deflection(x, target, noise(rng, (m, trials), params.sigma, params.v_max))
        if clip_speed:
            u = clip_unit(u)
        dx = params.v_max * params.dt * u
        x += np.where(active[..., None], dx, 0.0)
        length += np.where(active, np.sqrt(np.einsum("mnk,mnk->mn", dx, dx)), 0.0)
    return HorizonStates(x, length, steps)


def horizon_correct(
    goals: GoalSet, params: Params, states: HorizonStates, cost: CostForm
) -> IntArray:
    """Number of trials per true goal whose observer argmax at the horizon is the true goal."""
    rot = params.rotation_weight * symmetric_angle(
        goals.x0.rotation, goals.rotations, goals.symmetry
    )
    d0 = np.linalg.norm(goals.positions - goals.x0.position, axis=1) + rot
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
