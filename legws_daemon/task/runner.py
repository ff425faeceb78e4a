"""A run through a task graph: which stages may come next, what is held, what is used up."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.task.actions import action
from legws_daemon.task.graph import Stage, TaskGraph
from legws_daemon.task.targets import Target


def scene_graph(scene: Scene, goals: Sequence[str] | None = None) -> TaskGraph:
    """The one-stage graph of a plain scene: pick one of its candidate goals (or of
    ``goals``)."""
    names = tuple(scene.goal_names if goals is None else goals)
    stage = Stage("pick", names, "pick", (), "Which object?")
    return TaskGraph(f"{scene.name}_pick", scene.name, {"pick": stage}, source=scene.source)


class TaskRun:
    """The state of one run: the options for the next stage, the held object, progress.

    Args:
        graph: the task graph.
        scene: its scene.
    """

    def __init__(self, graph: TaskGraph, scene: Scene) -> None:
        self.graph = graph
        self.scene = scene
        self.options: tuple[Stage, ...] = (graph.stages[graph.start],)
        self.held: str | None = None
        self.consumed: set[str] = set()
        self.picked_from: dict[str, ObjectPose] = {}
        self.history: list[tuple[str, str]] = []  # (stage, goal) in order
        self.rounds = 1
        self._skip_empty()

    @property
    def finished(self) -> bool:
        return not self.options

    @property
    def label(self) -> str:
        """The stage name, or ``a|b`` while the user chooses between stages."""
        return "|".join(s.name for s in self.options) if self.options else "done"

    def candidates(self) -> list[tuple[str, Stage]]:
        """``(goal, stage)`` for every goal the user may go for now."""
        out: list[tuple[str, Stage]] = []
        for s in self.options:
            for c in s.candidates:
                if action(s.action).available(c, self):
                    out.append((c, s))
        return out

    def targets(self, layout: Mapping[str, ObjectPose]) -> list[Target]:
        return [
            action(s.action).target(self.scene, layout, s.name, c, self.held, self.picked_from)
            for c, s in self.candidates()
        ]

    def stage_of(self, goal: str) -> Stage:
        for c, s in self.candidates():
            if c == goal:
                return s
        raise KeyError(goal)

    def advance(self, goal: str, layout: Layout) -> Stage:
        """The committed ``goal``'s stage is done: update what is held, move on."""
        stage = self.stage_of(goal)
        self.history.append((stage.name, goal))
        action(stage.action).apply(self, goal, layout)
        nxt = self.graph.successors(stage.name)
        again = not nxt and self.graph.repeat == "until_consumed"
        if again:
            nxt = (self.graph.stages[self.graph.start],)
        self.options = nxt
        self._skip_empty()
        if again and self.options:
            self.rounds += 1
        return stage

    def _skip_empty(self) -> None:
        """No candidate left (everything consumed): the run is over."""
        if self.options and not self.candidates():
            self.options = ()
