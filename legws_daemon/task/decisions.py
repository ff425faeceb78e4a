"""Decision points of a task graph: the sets of stages a run may offer at once.

A run (:class:`~legws_daemon.task.runner.TaskRun`) offers the start stage, then after each
commit the committed stage's successors: one stage, or several alternatives (a *choice*,
labelled ``a|b``); the daemon infers over the union of their candidates, starting from
the EE home. A graph that repeats (``until_consumed``) offers the start stage again after
an end stage: the same decision point. Walking the graph from the start, each distinct
successor tuple is one decision point, in the order first reached.
"""

from __future__ import annotations

from dataclasses import dataclass

from legws_daemon.task.graph import Stage, TaskGraph


@dataclass(frozen=True, slots=True)
class DecisionPoint:
    """Stages offered together.

    Attributes:
        stages: the stages, in the order of the ``next`` list that offers them.
        parent: index of the decision point it is first reached from (``None``: the start).
    """

    stages: tuple[Stage, ...]
    parent: int | None

    @property
    def label(self) -> str:
        """``a`` or ``a|b`` (the label of :attr:`TaskRun.label`)."""
        return "|".join(s.name for s in self.stages)

    @property
    def candidates(self) -> tuple[str, ...]:
        """Every stage's candidates, in stage order (alternatives never share one)."""
        return tuple(c for s in self.stages for c in s.candidates)

    @property
    def actions(self) -> dict[str, str]:
        """The action carried out on each candidate."""
        return {c: s.action for s in self.stages for c in s.candidates}

    @property
    def stage_of(self) -> dict[str, str]:
        """The stage each candidate belongs to."""
        return {c: s.name for s in self.stages for c in s.candidates}

    @property
    def inference(self) -> bool:
        """Whether the daemon infers (two or more candidates) or commits at once."""
        return len(self.candidates) >= 2

    @property
    def is_choice(self) -> bool:
        return len(self.stages) > 1


def decision_points(graph: TaskGraph) -> list[DecisionPoint]:
    """The graph's decision points in the order first reached from the start."""
    start = (graph.start,)
    order: list[tuple[str, ...]] = [start]
    parents: dict[tuple[str, ...], int | None] = {start: None}
    i = 0
    while i < len(order):
        for name in order[i]:
            nxt = graph.stages[name].next
            if not nxt and graph.repeat == "until_consumed":
                nxt = start
            if nxt and nxt not in parents:
                parents[nxt] = i
                order.append(nxt)
        i += 1
    return [DecisionPoint(tuple(graph.stages[n] for n in d), parents[d]) for d in order]
