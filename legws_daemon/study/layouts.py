"""The layout each trial runs in, from its condition's layout source.

- ``shipped``: the scene file's layout;
- ``random``: a random layout meeting the scene's constraints in which every target of
  every decision passes the motion planner's check (drawn from the step's ``layout_seed``,
  :func:`~legws_daemon.design.stage_plan.random_feasible_layout`), the same for every
  participant;
- ``optimised``: ``legws optimize``'s best verified elite for a scene task (its
  ``objective``, ``iterations``, seed 0), ``legws plan``'s plan for a task graph (a layout
  per decision) — both cached, so a study reuses what the lab planned;
- ``optimised_for_operator``: the same designed for the participant, their operator file's
  ``certify_with`` model (method.md §10), which the session's calibration wrote.

A task graph's trial with a plan runs each decision in its planned layout (the daemon's
``--plan DIR``); every other trial runs in one layout (``--layout FILE``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from legws_daemon.errors import InputError
from legws_daemon.formats.operator_file import OperatorFile
from legws_daemon.scene.scene import Layout
from legws_daemon.study.protocol import ConditionSpec, Task
from legws_daemon.task.plan import Plan
from legws_daemon.task.runner import scene_graph


@dataclass(frozen=True)
class TrialLayout:
    """Where a trial's objects are.

    Attributes:
        source: the condition's layout source.
        layout: the layout the trial starts in (its first decision's).
        plan: a task graph's plan (a layout per decision), or ``None``: one layout.
        origin: where it came from (a seed, a run folder, a plan's key), for the table.
    """

    source: str
    layout: Layout
    plan: Plan | None = None
    origin: str = ""

    def layout_for(self, label: str) -> Layout:
        """The layout of decision ``label``."""
        return self.plan.layout_for(label) if self.plan is not None else dict(self.layout)

    def as_data(self) -> dict[str, Any]:
        """The starting layout as ``{"object": [x, y, yaw]}`` (rounded to 0.1 mm, 1 mrad)."""
        return {n: [round(p.x, 4), round(p.y, 4), round(p.yaw, 3)] for n, p in self.layout.items()}


class Layouts:
    """Makes the trials' layouts and keeps the optimised ones (one search per condition and
    person).

    Args:
        folder: where the optimisation runs of scene tasks are written.
        arm: the arm the layouts are for.
        progress: progress bars for the searches.
    """

    def __init__(self, folder: Path, arm: str = "sawyer", progress: bool = False) -> None:
        self.folder = folder
        self.arm = arm
        self.progress = progress
        self._kept: dict[tuple[str, str, str, int, str], TrialLayout] = {}

    def for_trial(
        self,
        task: Task,
        condition: ConditionSpec | None,
        seed: int,
        person: OperatorFile | None = None,
    ) -> TrialLayout:
        """The layout of a trial of ``task`` in ``condition`` (``None``: a first practice
        trial, on the shipped layout) with layout seed ``seed``; ``person``: the participant's
        operator file (needed by ``optimised_for_operator``)."""
        from legws_daemon.design.stage_plan import random_feasible_layout

        source = condition.layout if condition is not None else "shipped"
        scene = task.scene
        graph = task.graph if task.graph is not None else scene_graph(scene)
        if source == "shipped":
            return TrialLayout(source, scene.default_layout(), origin="the scene file")
        if source == "random":
            layout = random_feasible_layout(graph, scene, seed, arm=self.arm)
            return TrialLayout(source, layout, origin=f"seed {seed}")
        assert condition is not None
        people: tuple[OperatorFile, ...] = ()
        if source == "optimised_for_operator":
            if person is None:
                raise InputError(
                    f"condition '{condition.name}' designs for the participant, who has no "
                    "operator file yet (calibrate first)",
                    field="layout",
                )
            people = (person,)
        key = (
            task.name,
            condition.objective,
            source,
            condition.iterations,
            person.name if people and person is not None else "",
        )
        if key not in self._kept:
            self._kept[key] = self._optimised(task, condition, people)
        return self._kept[key]

    def _optimised(
        self, task: Task, condition: ConditionSpec, people: tuple[OperatorFile, ...]
    ) -> TrialLayout:
        from legws_daemon.design.optimize import optimize
        from legws_daemon.design.stage_plan import plan_taskgraph
        from legws_daemon.scene.layout_file import load_layout

        source = condition.layout
        if task.graph is None:
            whom = people[0].name if people else "user2"
            out = self.folder / f"{task.name}-{condition.objective}-{whom}"
            progress: Callable[[int, float, float], None] | None = None
            summary = optimize(
                task.scene, out, iterations=condition.iterations, seed=0,
                objective=condition.objective, operators=people, arm=self.arm,
                render=False, progress=progress,
            )  # fmt: skip
            layout = load_layout(out / "best_layout.json", task.scene)
            return TrialLayout(source, layout, origin=f"optimize {summary.get('key', '')}")
        plan = plan_taskgraph(
            task.graph, task.scene, iterations=condition.iterations, seed=0,
            objective=condition.objective, operators=people, arm=self.arm,
            progress=self.progress, render=False,
        )  # fmt: skip
        first = plan.decisions[0].label
        return TrialLayout(source, plan.layout_for(first), plan, origin=f"plan {plan.key}")
