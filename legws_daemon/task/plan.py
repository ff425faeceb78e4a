"""A stage-specific layout plan of a task graph: one layout per decision point.

Produced by :func:`legws_daemon.design.stage_plan.plan_taskgraph`, written as
``plan.json`` and read back by :func:`legws_daemon.task.plan_file.load_plan`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from legws_daemon.errors import InputError
from legws_daemon.scene.scene import Layout

#: Version of the ``plan.json`` format.
SCHEMA = 1
#: Search iterations per optimised decision of ``legws plan`` (as ``legws optimize``).
#: Measured on 2 cores, cold cache: ``legws plan tea`` 12.9 s, ``lego`` 12.0 s, ``feeding``
#: 10.1 s wall, of which ~5 s is the one-off JIT compilation of pyribs' kernels.
DEFAULT_ITERATIONS = 1000


def image_name(label: str) -> str:
    """The picture of a decision: ``dip|feed`` -> ``dip+feed.png``."""
    return label.replace("|", "+") + ".png"


@dataclass(frozen=True, slots=True)
class PlannedDecision:
    """The layout planned for one decision point.

    Attributes:
        label: ``a`` or ``a|b`` (as :attr:`TaskRun.label <legws_daemon.task.runner.TaskRun>`).
        stages: the stages offered together.
        candidates: the union of their candidates (goals and places).
        actions: the action carried out on each candidate.
        inference: whether the daemon infers (two or more candidates).
        optimised: the candidates whose poses were optimised here.
        layout: poses of every movable object of the scene at this decision.
        certificate: ``J`` of the candidates' targets from the EE home in ``layout``
            (``None`` without inference).
        certificate_start: ``J`` in the layout the decision started from (``None``
            without inference).
        feasible: every target passed the IK and collision check in ``layout`` (and the
            placed objects meet the layout constraints).
        image: file name of the top-view picture next to ``plan.json`` (``None``: not
            rendered).
        note: what was done, or why the layout is not feasible.
        commit_objective: ``K`` of the candidates' targets in ``layout`` (method.md §9;
            ``None`` without inference).
        commit_certified: how many of them are commit-certified (``None`` without
            inference).
        commit_rate_estimate: ``R``, their estimated commit rate before arrival
            (``core.commit.commit_rate_estimate``; ``None`` without inference).
    """

    label: str
    stages: tuple[str, ...]
    candidates: tuple[str, ...]
    actions: dict[str, str]
    inference: bool
    optimised: tuple[str, ...]
    layout: Layout
    certificate: float | None
    certificate_start: float | None
    feasible: bool
    image: str | None
    note: str = ""
    commit_objective: float | None = None
    commit_certified: int | None = None
    commit_rate_estimate: float | None = None


@dataclass(frozen=True)
class Plan:
    """Layouts of every decision point of a task graph, in the order a run meets them.

    Attributes:
        taskgraph: the graph's name.
        scene: the scene's name.
        key: the cache key (hash of the graph file, the scene file and the settings).
        settings: method, iterations, seed, params and legws version.
        decisions: one per decision point.
        seconds: wall time of the planning run.
        directory: folder holding ``plan.json`` and the pictures (not in the file).
        cached: loaded from the cache rather than computed (not in the file).
    """

    taskgraph: str
    scene: str
    key: str
    settings: dict[str, Any]
    decisions: tuple[PlannedDecision, ...]
    seconds: float = 0.0
    directory: Path | None = field(default=None, compare=False)
    cached: bool = field(default=False, compare=False)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(d.label for d in self.decisions)

    def decision(self, label: str) -> PlannedDecision:
        """The decision ``label`` (``a|b``; the alternatives may come in any order)."""
        for d in self.decisions:
            if d.label == label:
                return d
        wanted = set(label.split("|"))
        for d in self.decisions:
            if set(d.stages) == wanted:
                return d
        raise InputError(
            f"no decision '{label}' in the plan of '{self.taskgraph}'; "
            f"decisions: {', '.join(self.labels)}",
            field="decision",
        )

    def layout_for(self, label: str) -> Layout:
        """The layout of every movable object at decision ``label`` (a copy)."""
        return dict(self.decision(label).layout)

    def image_path(self, label: str) -> Path | None:
        """The picture of decision ``label``, when rendered and the plan has a folder."""
        image = self.decision(label).image
        if image is None or self.directory is None:
            return None
        return self.directory / image
