"""The paper's simulation protocol (method.md §8) for one layout, and its metrics.

Per layout: every grasp is checked for IK reachability and collisions; infeasible grasps
leave the candidate set but every episode that wants them counts as a failure. Pick
orders are all permutations of the goals (at most 120 sampled for M >= 5); after each
pick the object returns, the arm goes home and inference resets.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from legws_daemon.core.params import Params
from legws_daemon.robot.feasibility import GraspCheck, check_grasps
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.sim.episode import EpisodeResult, run_episode

#: Most pick orders per layout (the paper samples 120 for M >= 5).
MAX_ORDERS = 120


def pick_orders(names: Sequence[str], rng: np.random.Generator) -> list[tuple[str, ...]]:
    """All permutations when there are at most :data:`MAX_ORDERS`, else that many sampled."""
    if math.factorial(len(names)) <= MAX_ORDERS:
        return list(itertools.permutations(names))
    return [tuple(names[i] for i in rng.permutation(len(names))) for _ in range(MAX_ORDERS)]


@dataclass(frozen=True, slots=True)
class Pick:
    """One pick of an order: an episode, or a failure because the grasp is infeasible."""

    true_goal: str
    episode: EpisodeResult | None  # None when the true goal's grasp is infeasible

    @property
    def correct(self) -> bool:
        return self.episode is not None and self.episode.correct

    @property
    def committed(self) -> str | None:
        return self.episode.committed if self.episode is not None else None


@dataclass(frozen=True, slots=True)
class LayoutEvaluation:
    """Everything measured on one layout."""

    layout: Layout
    feasibility: dict[str, GraspCheck]
    picks: list[Pick] = field(repr=False)

    def metrics(self) -> dict[str, float | int | None]:
        return metrics(self.picks)


def metrics(picks: Sequence[Pick]) -> dict[str, float | int | None]:
    """Argmax accuracy, T_infer (mean ± sd over commits), commit / wrong / no-commit rates.

    ``accuracy`` counts a pick whose grasp is infeasible as a failure (the protocol);
    ``accuracy_feasible`` is the accuracy over the picks that ran an episode.
    """
    n = len(picks)
    feasible = [p for p in picks if p.episode is not None]
    times = [
        p.episode.commit_time for p in picks if p.episode and p.episode.commit_time is not None
    ]
    committed = [p for p in picks if p.committed is not None]
    wrong = [p for p in committed if p.committed != p.true_goal]
    return {
        "episodes": n,
        "accuracy": sum(p.correct for p in picks) / n if n else None,
        "accuracy_feasible": (
            sum(p.correct for p in feasible) / len(feasible) if feasible else None
        ),
        "t_infer_mean": float(np.mean(times)) if times else None,
        "t_infer_sd": float(np.std(times, ddof=1)) if len(times) > 1 else None,
        "commit_rate": len(committed) / n if n else None,
        "wrong_commit_rate": len(wrong) / n if n else None,
        "no_commit_rate": (n - len(committed)) / n if n else None,
        "infeasible_picks": sum(p.episode is None for p in picks),
    }


class Evaluator:
    """Runs the protocol on layouts of one scene; keeps one compiled world."""

    def __init__(self, scene: Scene, params: Params | None = None) -> None:
        self.scene = scene
        self.params = params or Params()
        self.world = World(scene)
        self.q_home = home_configuration(self.world, scene.home.position, scene.home.rotation).q

    def evaluate(self, layout: Layout, seed: int | Sequence[int]) -> LayoutEvaluation:
        rng = np.random.default_rng(seed)
        sc = self.scene
        self.world.set_layout(sc.poses(layout))
        goals_all = sc.goal_set(layout)
        checks = check_grasps(self.world, goals_all, self.q_home)
        feasible = [n for n in goals_all.names if checks[n].feasible]
        picks: list[Pick] = []
        orders = pick_orders(list(goals_all.names), rng)
        if len(feasible) >= 2:
            goals = sc.goal_set(layout, goals=feasible)
        for order in orders:
            for name in order:
                if name not in feasible:
                    picks.append(Pick(name, None))
                elif len(feasible) == 1:
                    # a single candidate needs no inference: the robot takes it at once
                    picks.append(Pick(name, EpisodeResult(name, name, None, name, False, 0.0)))
                else:
                    ep = run_episode(self.world, goals, name, self.q_home, rng, self.params)
                    picks.append(Pick(name, ep))
        return LayoutEvaluation(dict(layout), checks, picks)
