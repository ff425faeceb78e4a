"""Designing for people (method.md §10): ``legws optimize|plan --operator FILE`` designs for
one person's operator model, ``--operators A,B,...`` for the worst of a group.

The search (:class:`~legws_daemon.design.problem.LayoutProblem` with ``operators``) scores
every layout for each person's ``certify_with`` model with the robot's clip and searches
the worst: J the smallest, K the largest, R the smallest, T the largest. What a run
reports for each person is computed here with the numpy reference, on the written goal set.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import certify_commit, commit_rate_estimate, commit_time_estimate
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.formats.operator_file import OperatorFile

#: ``design_for`` of a run without operators.
PAPER_USER = "section 2's user"


def design_for(names: Sequence[str]) -> str:
    """``"section 2's user"``, ``"NAME"`` or ``"worst of A, B"``."""
    if not names:
        return PAPER_USER
    return names[0] if len(names) == 1 else "worst of " + ", ".join(names)


def operator_settings(files: Sequence[OperatorFile]) -> list[dict[str, Any]]:
    """What a run's cache key and its settings record of the people designed for: each
    one's ``name`` and ``model`` (``certify_with``)."""
    return [{"name": f.name, "model": f.certify_with.as_dict()} for f in files]


def finite_or_none(value: float) -> float | None:
    """``value``, or ``None`` when it is not finite (JSON has no infinity: K and T of a goal
    set with a goal the operator's nominal never reaches)."""
    return value if math.isfinite(value) else None


def operator_report(goals: GoalSet, params: Params, file: OperatorFile) -> dict[str, Any]:
    """One person's certificates of ``goals`` (numpy, the robot's clip on): ``name``,
    ``model``, ``objective`` (J), ``commit_objective`` (K, exact sum; ``None`` when a goal is
    not reached), ``commit_certified``, ``commit_rate_estimate`` (R) and
    ``commit_time_estimate`` (T, s; ``None`` when a goal is not reached)."""
    op = file.certify_with
    user = op.motion(params, clip=True)
    commit = certify_commit(goals, params, user, "sum", op)
    return {
        "name": file.name,
        "model": op.as_dict(),
        "objective": certify(goals, params, op, user).objective,
        "commit_objective": finite_or_none(commit.objective),
        "commit_certified": commit.certified,
        "commit_rate_estimate": commit_rate_estimate(goals, params, op),
        "commit_time_estimate": finite_or_none(commit_time_estimate(goals, params, op)),
    }


def worst_score(
    objective: str, goals: GoalSet, params: Params, models: Sequence[OperatorModel], form: str
) -> float:
    """What the search maximises for ``models`` (numpy): the worst over them of J, -K (of
    ``form``), R or -T, each with the robot's clip (``-inf`` where K or T is infinite)."""
    scores = []
    for op in models:
        user = op.motion(params, clip=True)
        if objective == "commit":
            scores.append(-certify_commit(goals, params, user, form, op).objective)
        elif objective == "rate":
            scores.append(commit_rate_estimate(goals, params, op))
        elif objective == "time":
            scores.append(-commit_time_estimate(goals, params, op))
        else:
            scores.append(certify(goals, params, op, user).objective)
    return min(scores)
