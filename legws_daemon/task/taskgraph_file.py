"""Task-graph files (``taskgraphs/*.toml``): read, validate, explain what is wrong.

Structure is checked by the schema; meaning by :func:`check_graph` against the scene:
every candidate an object or place of the scene, no cycle, every stage reachable from the
first, no empty candidate set, alternatives of a choice with disjoint candidates, and
actions that fit what the gripper holds on every path (checked without listing the
paths: :func:`held_problem`). Errors name the file, the line of the field (or of its
stage) and the field, e.g.
``taskgraphs/tea.toml:14: stages[1].candidates[0]: unknown object 'mug'; ...``; a file
that does not fit the schema gets every error, one per field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from legws_daemon.errors import InputError
from legws_daemon.formats.positions import Loc, SourceText
from legws_daemon.formats.validation import (
    Name,
    field_path,
    parse_toml,
    read_text,
    resolve_named,
    validate,
    within,
)
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.task.actions import action
from legws_daemon.task.graph import Stage, TaskGraph, find_cycle, reachable


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StageSpec(_Model):
    name: Name
    prompt: str = ""
    candidates: Annotated[list[Name], Field(min_length=1, max_length=32)]
    action: Literal["pick", "place", "dip", "feed", "return"]
    next: list[Name] = []


class TaskGraphSpec(_Model):
    schema_version: Literal[1]
    name: Name
    scene: Name
    description: str = ""
    repeat: Literal["once", "until_consumed"] = "once"
    fixed: list[Name] = []
    stages: Annotated[list[StageSpec], Field(min_length=1, max_length=64)]


def check_graph(
    spec: TaskGraphSpec, scene: Scene, where: SourceText | None, source: str
) -> TaskGraph:
    """Semantic checks; returns the graph or raises one :class:`InputError` (naming the
    line of the field when ``where`` holds the file's text)."""

    def fail(stage: int | None, loc: Loc, message: str) -> InputError:
        full: Loc = ("stages", stage, *loc) if stage is not None else loc
        src = where.at(source, full) if where is not None else source
        return InputError(message, source=src, field=field_path(full))

    index = {s.name: i for i, s in enumerate(spec.stages)}
    for i, s in enumerate(spec.stages):
        if index[s.name] != i:
            raise fail(i, ("name",), f"stage name '{s.name}' is used twice")
    objects = set(scene.objects)
    places = {p.name for p in scene.spec.places}
    known = ", ".join([*scene.objects, *sorted(places)])
    for i, s in enumerate(spec.stages):
        for j, c in enumerate(s.candidates):
            if c not in objects and c not in places:
                raise fail(
                    i, ("candidates", j), f"unknown object or place '{c}' in scene "
                    f"'{scene.name}'; known: {known}"
                )  # fmt: skip
            if c in s.candidates[:j]:
                raise fail(i, ("candidates", j), f"'{c}' is listed twice")
            if c in places and not action(s.action).at_places:
                raise fail(
                    i, ("candidates", j), f"'{c}' is a place: it can be fed or placed at, "
                    f"not used by '{s.action}'"
                )  # fmt: skip
            if action(s.action).takes_object and c in objects and c not in scene.movable:
                raise fail(
                    i, ("candidates", j), f"'{c}' is fixed in the scene: it cannot be picked"
                )
        for j, n in enumerate(s.next):
            if n not in index:
                raise fail(i, ("next", j), f"unknown stage '{n}'; stages: {', '.join(index)}")
    for j, f in enumerate(spec.fixed):
        if f not in objects:
            raise fail(None, ("fixed", j), f"unknown object '{f}'; objects: {', '.join(objects)}")
    stages = {
        s.name: Stage(s.name, tuple(s.candidates), s.action, tuple(s.next), s.prompt)
        for s in spec.stages
    }
    cycle = find_cycle(stages)
    if cycle:
        raise fail(
            index[cycle[-2]], ("next",), f"cycle {' -> '.join(cycle)}; use repeat = "
            f"\"until_consumed\" to run a graph again"
        )  # fmt: skip
    start = spec.stages[0].name
    seen = reachable(stages, start)
    for i, s in enumerate(spec.stages):
        if s.name not in seen:
            raise fail(i, ("name",), f"stage '{s.name}' cannot be reached from '{start}'")
    for i, s in enumerate(spec.stages):
        owner: dict[str, str] = {}
        for n in s.next:
            for c in stages[n].candidates:
                if c in owner:
                    raise fail(
                        i, ("next",), f"alternatives '{owner[c]}' and '{n}' share candidate "
                        f"'{c}': the commit could not tell which branch the user took"
                    )  # fmt: skip
                owner[c] = n
    graph = TaskGraph(
        spec.name, spec.scene, stages, spec.repeat, tuple(spec.fixed), spec.description, source
    )
    problem = held_problem(graph)
    if problem is not None:
        last = problem.path[-1]
        if problem.ends_held:
            raise fail(
                index[last], ("action",), "the graph repeats but ends holding an object (after "
                f"{' -> '.join(problem.path)})"
            )  # fmt: skip
        act = stages[last].action
        what = "already holds an object" if problem.held else "holds nothing"
        before = " -> ".join(problem.path[:-1]) or "the start"
        raise fail(index[last], ("action",), f"'{act}' after {before}: the gripper {what} there")
    if spec.repeat == "until_consumed" and not action(spec.stages[0].action).takes_object:
        raise fail(0, ("action",), "a repeated graph must start with 'pick' (what it consumes)")
    return graph


@dataclass(frozen=True, slots=True)
class HeldProblem:
    """A path on which an action does not fit what the gripper holds.

    Attributes:
        path: stage names from the start to the stage at fault (inclusive).
        held: whether the gripper holds an object when that stage starts (``ends_held``:
            after it).
        ends_held: the stage's action fits, but it is an end stage of a repeated graph
            and the gripper still holds an object after it.
    """

    path: tuple[str, ...]
    held: bool
    ends_held: bool = False


def held_problem(graph: TaskGraph) -> HeldProblem | None:
    """The first path (in the order of the ``next`` lists) on which an action does not fit
    what the gripper holds, up to its first stage at fault; ``None``: every path fits.

    No path is listed (a graph of 64 stages may have 2^62): a dynamic programme over the
    pairs (stage, held on arrival), in reverse topological order, marks the pairs from
    which some continuation goes wrong — the stage's action does not fit, or a repeated
    graph ends holding an object. Following the first marked successor from (start, empty
    gripper) gives the example path a walk of every path would have met first. Linear in
    stages and transitions.
    """
    repeat = graph.repeat == "until_consumed"
    bad: dict[tuple[str, bool], bool] = {}
    for name in reversed(graph.order()):
        stage = graph.stages[name]
        act = action(stage.action)
        for held in (False, True):
            if act.needs_held != held:
                bad[name, held] = True
                continue
            out = held if act.holds_after is None else act.holds_after
            bad[name, held] = any(bad[n, out] for n in stage.next) if stage.next else repeat and out
    name, held = graph.start, False
    if not bad[name, held]:
        return None
    path = [name]
    while True:
        stage = graph.stages[name]
        act = action(stage.action)
        if act.needs_held != held:
            return HeldProblem(tuple(path), held)
        held = held if act.holds_after is None else act.holds_after
        if not stage.next:
            return HeldProblem(tuple(path), held, ends_held=True)
        name = next(n for n in stage.next if bad[n, held])
        path.append(name)


def load_taskgraph(path: Path, scene: Scene | None = None) -> tuple[TaskGraph, Scene]:
    """Read and validate a task graph and its scene; errors name file, line and field."""
    where = SourceText(read_text(path, "task graph"), "toml")  # read once
    spec = validate(TaskGraphSpec, parse_toml(where.text, str(path)), str(path), where)
    if spec.name != path.stem:
        raise InputError(
            f"expected '{path.stem}' (the file's name), got '{spec.name}'",
            source=where.at(str(path), ("name",)),
            field="name",
        )
    if scene is None:
        try:
            scene = load_scene(spec.scene)
        except InputError as err:
            raise within(err, where.at(str(path), ("scene",)), "scene") from None
    return check_graph(spec, scene, where, str(path)), scene


def taskgraphs_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "taskgraphs"


def resolve_taskgraph(name_or_path: str) -> Path:
    """``tea`` -> ``taskgraphs/tea.toml``; a path is used as is."""
    return resolve_named(name_or_path, taskgraphs_dir(), "task graph", "taskgraph")
