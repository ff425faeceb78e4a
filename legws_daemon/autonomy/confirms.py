"""Which decisions of a task will need a confirm: the commit certificate, seen at start.

A person steering straight at a goal is helped only when the posterior reaches the commit
threshold before they arrive (method.md §9). A goal that is not *commit-certified* in the
layout its decision runs in may leave the posterior short of it — LEGO on the shipped
layout: a brick steered at straight plateaus at 0.893 and waits for the confirm button.
:func:`confirm_forecast` says so per decision before anyone steers, for the user every
certificate of the run is for (section 2's, or the operator's model, with the robot's
clip); the daemon warns with it at start (``confirms`` events).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

from legws_daemon.autonomy.decision import commit_for
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.task.decisions import decision_points
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.plan_file import decision_goals


@dataclass(frozen=True, slots=True)
class DecisionForecast:
    """One decision's commit certificate from home.

    Attributes:
        decision: its label (``a`` or ``a|b``).
        layout: ``plan`` (the plan's layout of the decision) or ``layout`` (the one the
            daemon started with: the scene's or ``--layout``'s).
        goals: its candidates; uncertified: those not commit-certified — steered at
            straight, the posterior may stay below the threshold: a confirm commits them.
        objective: ``K`` (``<= 1``: every goal certified).
    """

    decision: str
    layout: str
    goals: tuple[str, ...]
    uncertified: tuple[str, ...]
    objective: float

    @property
    def confirms(self) -> bool:
        """Whether some goal of the decision may need a confirm."""
        return bool(self.uncertified)


def confirm_forecast(
    graph: TaskGraph,
    scene: Scene,
    layout: Layout,
    plan: Plan | None,
    params: Params,
    operator: OperatorModel | None = None,
) -> list[DecisionForecast]:
    """The commit certificate of every decision with two or more candidates, in the order a
    run first reaches them, each in the layout it runs in: the plan's for the decision when
    the plan has it, else ``layout``."""
    out = []
    for point in decision_points(graph):
        if not point.inference:
            continue
        source, where = layout, "layout"
        if plan is not None:
            # (a decision the plan does not hold: the layout it starts from)
            with contextlib.suppress(InputError):
                source, where = plan.layout_for(point.label), "plan"
        cert = commit_for(decision_goals(scene, point, source), params, operator)
        names = tuple(cert.goals)
        missing = tuple(n for n in names if not cert.goals[n].certified)
        out.append(DecisionForecast(point.label, where, names, missing, cert.objective))
    return out
