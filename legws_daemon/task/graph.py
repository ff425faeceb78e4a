"""Task graphs: stages, their candidate goals, the action after a commit, transitions.

A stage lists candidate goals (objects or places of the scene) and the action the robot
carries out on the committed one. ``next`` lists the stages that may follow: one is a
plain sequence; several are a *choice* that the user makes by moving — the daemon infers
over the union of their candidates and the committed goal picks the branch (so
alternatives must not share candidates). An optional step is a choice between the step and
what follows it. The graph has no cycles; ``repeat = "until_consumed"`` runs it again from
the start while the first stage still has candidates (objects picked are consumed), as in
LEGO sorting. A stage with a single candidate needs no inference.

Holding: ``pick`` needs an empty gripper and fills it; ``place``, ``feed`` and ``return``
(put the held object back where it was picked up) need a held object and empty the
gripper; ``dip`` needs one and keeps it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

Action = Literal["pick", "place", "dip", "feed", "return"]
ACTIONS: tuple[str, ...] = get_args(Action)
Repeat = Literal["once", "until_consumed"]


@dataclass(frozen=True, slots=True)
class Stage:
    name: str
    candidates: tuple[str, ...]
    action: Action
    next: tuple[str, ...] = ()
    prompt: str = ""


@dataclass(frozen=True, slots=True)
class TaskGraph:
    """A validated task graph (see :func:`legws_daemon.task.taskgraph_file.load_taskgraph`).

    Attributes:
        name: the graph's name (its file's stem).
        scene: the scene it runs in.
        stages: by name, in file order; the first is the start.
        repeat: ``once`` or ``until_consumed``.
        fixed: objects that stay where they are in every stage's layout.
        source: the file it came from.
    """

    name: str
    scene: str
    stages: dict[str, Stage]
    repeat: Repeat = "once"
    fixed: tuple[str, ...] = ()
    description: str = ""
    source: str = ""

    @property
    def start(self) -> str:
        return next(iter(self.stages))

    def successors(self, stage: str) -> tuple[Stage, ...]:
        return tuple(self.stages[n] for n in self.stages[stage].next)

    def order(self) -> list[str]:
        """Every stage, each before its successors (see :func:`topological_order`)."""
        return topological_order(self.stages)

    def path_count(self) -> int:
        """How many paths lead from the start to an end stage: counted, not listed.

        One sum over the successors per stage, in reverse topological order (linear in
        stages and transitions); exact however large (a Python int: 64 stages allow up to
        2^62 paths, one per subset of the stages between a first and a last).
        """
        count: dict[str, int] = {}
        for name in reversed(self.order()):
            nxt = self.stages[name].next
            count[name] = sum(count[n] for n in nxt) if nxt else 1
        return count[self.start]


def find_cycle(stages: dict[str, Stage]) -> list[str] | None:
    """A cycle of stage names (first repeated at the end), or ``None``."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in stages[n].next:
            if state.get(m) == 1:
                return [*stack[stack.index(m) :], m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        state[n] = 2
        stack.pop()
        return None

    for n in stages:
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def topological_order(stages: dict[str, Stage]) -> list[str]:
    """The stages' names, each before all its successors (Kahn's algorithm: linear in
    stages and transitions; the same order every time).

    Raises:
        ValueError: the transitions have a cycle (see :func:`find_cycle`).
    """
    indegree = dict.fromkeys(stages, 0)
    for s in stages.values():
        for n in s.next:
            indegree[n] += 1
    ready = [n for n in reversed(stages) if indegree[n] == 0]  # a stack, file order on top
    order: list[str] = []
    while ready:
        name = ready.pop()
        order.append(name)
        for n in reversed(stages[name].next):
            indegree[n] -= 1
            if indegree[n] == 0:
                ready.append(n)
    if len(order) != len(stages):
        raise ValueError(f"the stages have a cycle: {find_cycle(stages)}")
    return order


def reachable(stages: dict[str, Stage], start: str) -> set[str]:
    seen = {start}
    todo = [start]
    while todo:
        for m in stages[todo.pop()].next:
            if m not in seen:
                seen.add(m)
                todo.append(m)
    return seen
