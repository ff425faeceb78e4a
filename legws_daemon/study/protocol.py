"""Study protocol files (``studies/*.toml``): what a within-subject user study runs.

```toml
schema_version = 1
name = "layouts_tea"                  # the file's stem
title = "Random vs optimised layouts on the tea task"
seed = 0                              # the schedule's draws (row assignment, layouts, targets)

[design]
counterbalance = "williams"           # latin | williams | fixed
trials_per_condition = 6
practice_trials = 2                   # at the start, after calibration
practice_per_condition = 1            # before each condition's trials
break_every = 1                       # a break after every N conditions (0: none)
break_s = 120                         # the break's suggested length, shown to the participant
calibrate = true                      # method.md §10's calibration first

[tasks.tea]
taskgraph = "tea"                     # or scene = "breakfast"

[[conditions]]
name = "random"
task = "tea"
layout = "random"                     # shipped | random | optimised | optimised_for_operator
objective = "slack"                   # for optimised layouts: legws optimize's objective
iterations = 1000                     # and its search iterations
assist = "commit"                     # commit | blend | hindsight | none

[questionnaires]
nasa_tlx = true                       # raw NASA-TLX after each condition
likert_points = 7
likert = ["I felt in control of the robot.", "..."]
```

Structure is checked by the schema; meaning here: every condition's task exists (its scene
or task graph loads), condition names are unique, the design has rows for that many
conditions. Every error names the file, the line and the field.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict, model_validator

from legws_daemon.errors import InputError
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.validation import (
    ManyInputsError,
    Name,
    combine,
    did_you_mean,
    error_lines,
    in_line_order,
    located,
    parse_toml,
    read_text,
    resolve_named,
    validate,
)
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.study.counterbalance import Design
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

LayoutSource = Literal["shipped", "random", "optimised", "optimised_for_operator"]
Assist = Literal["commit", "blend", "hindsight", "none"]
Objective = Literal["slack", "commit", "rate", "time"]

#: The six subscales of the NASA Task Load Index (Hart & Staveland 1988), raw (unweighted)
#: TLX: each 0-100 in steps of 5; ``performance`` runs from good (0) to poor (100).
NASA_TLX = (
    ("mental", "Mental demand: how mentally demanding was the task?"),
    ("physical", "Physical demand: how physically demanding was the task?"),
    ("temporal", "Temporal demand: how hurried or rushed was the pace of the task?"),
    ("performance", "Performance: how successful were you in doing what you were asked?"),
    ("effort", "Effort: how hard did you have to work to reach your level of performance?"),
    ("frustration", "Frustration: how insecure, discouraged, irritated or stressed were you?"),
)

Count = Annotated[int, Strict(), Field(ge=0, le=1000)]
Text = Annotated[str, Field(min_length=1, max_length=400)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DesignSpec(_Model):
    counterbalance: Design = "williams"
    trials_per_condition: Annotated[int, Strict(), Field(ge=1, le=1000)]
    practice_trials: Count = 0
    practice_per_condition: Count = 0
    break_every: Count = 1
    break_s: Annotated[int, Strict(), Field(ge=0, le=3600)] = 120
    calibrate: Annotated[bool, Strict()] = True


#: A scene or task graph: a shipped name, or a ``.toml`` path (relative to the protocol).
TaskSource = Annotated[str, Field(min_length=1, max_length=1024)]


class TaskSpec(_Model):
    scene: TaskSource | None = None
    taskgraph: TaskSource | None = None

    @model_validator(mode="after")
    def _one(self) -> TaskSpec:
        if (self.scene is None) == (self.taskgraph is None):
            raise ValueError("expected exactly one of 'scene' or 'taskgraph'")
        return self


class ConditionSpec(_Model):
    name: Name
    task: Name
    layout: LayoutSource
    assist: Assist = "commit"
    objective: Objective = "slack"
    #: search iterations of an optimised layout (per decision of a task graph)
    iterations: Annotated[int, Strict(), Field(ge=1, le=1_000_000)] = 1000
    description: str = ""


class QuestionnaireSpec(_Model):
    nasa_tlx: Annotated[bool, Strict()] = True
    likert_points: Annotated[int, Strict(), Field(ge=3, le=11)] = 7
    likert: Annotated[list[Text], Field(max_length=40)] = []


class ProtocolSpec(_Model):
    schema_version: Literal[1]
    name: Name
    title: Text
    description: str = ""
    seed: Annotated[int, Strict(), Field(ge=0, le=2**63 - 1)] = 0
    design: DesignSpec
    tasks: Annotated[dict[Name, TaskSpec], Field(min_length=1, max_length=16)]
    conditions: Annotated[list[ConditionSpec], Field(min_length=1, max_length=16)]
    questionnaires: QuestionnaireSpec = QuestionnaireSpec()


@dataclass(frozen=True, slots=True)
class Task:
    """A task of the study: a scene (one pick per trial) or a task graph (the whole graph
    per trial).

    Attributes:
        name: its name in the protocol.
        scene: the scene it runs in.
        graph: the task graph, or ``None`` for a scene task.
        argument: what ``legws daemon --scene``/``--taskgraph`` takes for it: the shipped
            name, or the file's path (resolved beside the protocol).
    """

    name: str
    scene: Scene
    graph: TaskGraph | None
    argument: str = ""

    @property
    def kind(self) -> Literal["scene", "taskgraph"]:
        return "scene" if self.graph is None else "taskgraph"

    @property
    def source(self) -> str:
        """The scene's or task graph's name, as ``legws daemon`` takes it."""
        return self.scene.name if self.graph is None else self.graph.name


@dataclass(frozen=True, slots=True)
class Protocol:
    """A validated study protocol.

    Attributes:
        spec: the file's fields.
        tasks: the tasks by name, loaded.
        source: the file it was read from.
        sha256: the hash of its text (recorded with every schedule and trial table: data
            say which protocol made them).
    """

    spec: ProtocolSpec
    tasks: dict[str, Task]
    source: str
    sha256: str

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def condition_names(self) -> list[str]:
        return [c.name for c in self.spec.conditions]

    def condition(self, name: str) -> ConditionSpec:
        for c in self.spec.conditions:
            if c.name == name:
                return c
        raise InputError(f"unknown condition '{name}'", source=self.source, field="conditions")


def studies_dir() -> Path:
    return Path(__file__).resolve().parents[2] / "studies"


def resolve_protocol(name_or_path: str) -> Path:
    """``layouts_tea`` -> ``studies/layouts_tea.toml``; a path is used as is."""
    return resolve_named(name_or_path, studies_dir(), "study protocol", "protocol")


def _beside(protocol: Path, name_or_path: str) -> str:
    """A shipped name as it is; a path relative to the protocol's folder."""
    if name_or_path.endswith(".toml") or "/" in name_or_path:
        return str(protocol.parent / name_or_path)  # an absolute path stays itself
    return name_or_path


def _condition_errors(spec: ProtocolSpec, source: str, where: SourceText) -> list[InputError]:
    """Conditions named twice, and conditions whose task the protocol does not have."""
    out: list[InputError] = []

    def error(loc: tuple[int | str, ...], message: str) -> None:
        field = f"conditions[{loc[1]}].{loc[2]}"
        out.append(InputError(message, source=where.at(source, loc), field=field))

    seen: set[str] = set()
    for i, c in enumerate(spec.conditions):
        if c.name in seen:
            error(("conditions", i, "name"), f"condition '{c.name}' is named twice")
        seen.add(c.name)
        if c.task not in spec.tasks:
            guess = did_you_mean(c.task, spec.tasks)
            hint = f"; did you mean '{guess}'?" if guess else ""
            known = ", ".join(spec.tasks)
            error(
                ("conditions", i, "task"),
                f"unknown task '{c.task}'{hint} (the protocol's tasks: {known})",
            )
    return out


def _of_task(err: InputError, source: str, field: str) -> InputError:
    """An error of a task's scene or task graph as an error of the protocol's field: an
    unknown name (no file of its own) is the field's; an error inside the scene's or the task
    graph's file keeps naming that file."""
    lines = [
        line.removeprefix(f"{e.field}: ") if e.source is None and e.field else line
        for e, line in zip(_each(err), error_lines(err), strict=True)
    ]
    return combine([InputError(line, source=source, field=field) for line in lines])


def _each(err: InputError) -> tuple[InputError, ...]:
    return err.errors if isinstance(err, ManyInputsError) else (err,)


def load_protocol(name_or_path: str | Path) -> Protocol:
    """Read and validate a study protocol and load its tasks; every error names the file,
    the line and the field."""
    path = resolve_protocol(str(name_or_path))
    text = read_text(path, "study protocol")
    where = SourceText(text, "toml")
    source = str(path)
    spec = validate(ProtocolSpec, parse_toml(text, source), source, where)
    errors: list[InputError] = []
    if spec.name != path.stem:
        errors.append(
            InputError(
                f"expected '{path.stem}' (the file's name), got '{spec.name}'",
                source=where.at(source, ("name",)),
                field="name",
            )
        )
    errors += _condition_errors(spec, source, where)
    tasks: dict[str, Task] = {}
    for name, task in spec.tasks.items():
        try:
            if task.taskgraph is not None:
                where_task = _beside(path, task.taskgraph)
                graph, scene = load_taskgraph(resolve_taskgraph(where_task))
                tasks[name] = Task(name, scene, graph, where_task)
            else:
                assert task.scene is not None
                where_task = _beside(path, task.scene)
                tasks[name] = Task(name, load_scene(where_task), None, where_task)
        except InputError as err:
            key = "taskgraph" if task.taskgraph is not None else "scene"
            loc = ("tasks", name, key)
            errors.append(_of_task(err, where.at(source, loc), f"tasks.{name}.{key}"))
    used = {c.task for c in spec.conditions}
    # a task no condition uses (unless a condition names one that is not there: a typo,
    # said once)
    for name in spec.tasks if used <= set(spec.tasks) else ():
        if name not in used:
            errors.append(
                located(
                    InputError(
                        f"task '{name}' is used by no condition",
                        source=source,
                        field=f"tasks.{name}",
                    ),
                    where,
                )
            )
    if errors:
        raise in_line_order(errors)
    digest = hashlib.sha256(text.encode()).hexdigest()
    return Protocol(spec, tasks, source, digest)
