"""The certificates of a trial's layout, for the trial table.

A scene task's trial has one decision: the scene's goals in the trial's layout, from the EE
home. A task graph's trial has one per decision point with inference (a choice between two
or more candidates), each in the layout it runs in (a plan's layout for that decision, or
the trial's one layout); the trial's certificate is its weakest decision's: the smallest
slack ``J`` (method.md §4) and the largest commit objective ``K`` (§9, exact sum). Both for
section 2's user and, when the participant has an operator file, for that person (their
``certify_with`` model with the robot's clip, method.md §10).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import certify_commit
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.design.stage_plan import decision_targets
from legws_daemon.scene.scene import Layout
from legws_daemon.study.protocol import Task
from legws_daemon.task.decisions import decision_points
from legws_daemon.task.targets import goal_set


@dataclass(frozen=True, slots=True)
class TrialCertificates:
    """``J`` (smallest over the trial's decisions) and ``K`` (largest), for section 2's user
    and for the participant (``None`` without an operator model); ``decisions``: how many
    decisions with inference the trial has."""

    slack_j: float
    commit_k: float
    person_slack_j: float | None
    person_commit_k: float | None
    decisions: int


def _finite(x: float) -> float:
    return x if math.isfinite(x) else float("inf")


def decision_goal_sets(
    task: Task, layout_for: Callable[[str], Layout]
) -> list[tuple[str, GoalSet]]:
    """The goal set of every decision with inference of ``task`` (label, goals from home);
    ``layout_for(label)`` is the layout a decision runs in (a scene task's label: ``pick``)."""
    scene = task.scene
    if task.graph is None:
        return [("pick", scene.goal_set(layout_for("pick")))]
    out = []
    for point in decision_points(task.graph):
        if not point.inference:
            continue
        targets = decision_targets(scene, point, layout_for(point.label))
        out.append((point.label, goal_set(targets, scene.home)))
    return out


def trial_certificates(
    task: Task,
    layout_for: Callable[[str], Layout],
    params: Params,
    person: OperatorModel | None = None,
) -> TrialCertificates:
    """The certificates of a trial of ``task`` (see the module's text)."""
    js, ks, pjs, pks = [], [], [], []
    sets = decision_goal_sets(task, layout_for)
    for _, goals in sets:
        js.append(certify(goals, params).objective)
        ks.append(_finite(certify_commit(goals, params, form="sum").objective))
        if person is not None:
            user = person.motion(params, clip=True)
            pjs.append(certify(goals, params, person, user).objective)
            pks.append(_finite(certify_commit(goals, params, user, "sum", person).objective))
    if not sets:
        nan = float("nan")
        return TrialCertificates(nan, nan, None, None, 0)
    return TrialCertificates(
        min(js), max(ks), min(pjs) if pjs else None, max(pks) if pks else None, len(sets)
    )
