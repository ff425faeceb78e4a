"""Plan files (``plan.json``): stage-specific layouts of a task graph, one per decision point.

Written by ``legws plan`` (:func:`legws_daemon.design.stage_plan.plan_taskgraph`)::

    {"schema": 1, "taskgraph": "feeding", "scene": "feeding", "key": "<hash>",
     "settings": {"method": "cma-me", "iterations": 150, "seed": 0, "params": {...},
                  "version": "0.1.0"},
     "seconds": 12.3,
     "decisions": [
       {"label": "dip|feed", "stages": ["dip", "feed"],
        "candidates": ["chocolate_bowl", "sprinkles_bowl", "mouth"],
        "actions": {"chocolate_bowl": "dip", "sprinkles_bowl": "dip", "mouth": "feed"},
        "inference": true, "optimised": [],
        "layout": {"strawberry": {"x": 0.7, "y": 0.1, "yaw": 0.0}, ...},
        "certificate": 1.23, "certificate_start": 1.23, "feasible": true,
        "image": "dip+feed.png", "note": "certified, not optimised: ...",
        "commit_objective": 0.8, "commit_certified": 3, "commit_rate_estimate": 0.93}]}

``layout`` holds every movable object of the scene; ``certificate`` and
``certificate_start`` are ``null`` exactly when ``inference`` is false (one candidate).
``commit_objective`` (K, method.md §9), ``commit_certified`` and ``commit_rate_estimate``
(R, in [0, 1]) are optional (plans written before them have none) and ``null`` without
inference; ``settings.objective`` says what the search maximised (``slack``: J,
``commit``: -K, ``rate``: R, ``time``: -T; absent means ``slack``). ``settings.operators``
(``legws plan --operator|--operators``) lists the people the layouts were designed for,
each ``{"name", "model"}`` (the ``certify_with`` model of their operator file), and
``settings.design_for`` says so in words (``"alice"``, ``"worst of alice, bob"``); absent
means section 2's user. The certificates a plan records are section 2's user's either way.
Errors name the file, the line and the field, every one of them, e.g.
``plan.json:41: decisions[1].layout.grape.x: ...``.

:func:`load_plan` checks the file; :func:`check_plan` checks a plan against its task graph
and scene before it is used (``--plan``, the plan cache): each stage layout as a
``--layout`` file, and each recorded certificate against its recomputation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, model_validator

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import CommitCertificate, certify_commit, commit_rate_estimate
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.goalset import ParamsSchema
from legws_daemon.formats.operator_file import ModelSchema, OperatorName
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.validation import (
    Angle,
    Coordinate,
    Finite,
    Name,
    field_error,
    located,
    read_json_with_lines,
    validate,
)
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.layout_file import dump_json, layout_to_data
from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.task.actions import action, target
from legws_daemon.task.decisions import DecisionPoint, decision_points
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import SCHEMA, Plan, PlannedDecision, image_name
from legws_daemon.task.targets import goal_set

Label = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*(\|[a-z][a-z0-9_]*)*$", max_length=400)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class _Pose(_Model):
    x: Coordinate
    y: Coordinate
    yaw: Angle


class DecisionSchema(_Model):
    label: Label
    stages: Annotated[list[Name], Field(min_length=1)]
    candidates: Annotated[list[Name], Field(min_length=1)]
    actions: dict[Name, Literal["pick", "place", "dip", "feed", "return"]]
    inference: StrictBool
    optimised: list[Name]
    layout: dict[Name, _Pose]
    certificate: Finite | None
    certificate_start: Finite | None
    feasible: StrictBool
    image: Annotated[str, Field(pattern=r"^[a-z0-9_+]+\.png$")] | None
    note: str = ""
    commit_objective: Finite | None = None
    commit_certified: Annotated[int, Field(ge=0, strict=True)] | None = None
    commit_rate_estimate: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> DecisionSchema:
        if self.label != "|".join(self.stages):
            raise field_error(("label",), f"expected '{'|'.join(self.stages)}' (the stages)")
        if len(set(self.candidates)) != len(self.candidates):
            raise field_error(("candidates",), "a candidate is listed twice")
        if set(self.actions) != set(self.candidates):
            raise field_error(("actions",), "expected one action per candidate")
        for i, n in enumerate(self.optimised):
            if n not in self.candidates:
                raise field_error(("optimised", i), f"'{n}' is not a candidate")
            if n not in self.layout:
                raise field_error(("optimised", i), f"'{n}' has no pose in the layout")
        if self.inference != (len(self.candidates) >= 2):
            raise field_error(("inference",), "expected true exactly with 2 or more candidates")
        for name in ("certificate", "certificate_start"):
            if (getattr(self, name) is None) == self.inference:
                want = "a number" if self.inference else "null (no inference)"
                raise field_error((name,), f"expected {want}")
        if not self.inference:
            for name in ("commit_objective", "commit_certified", "commit_rate_estimate"):
                if getattr(self, name) is not None:
                    raise field_error((name,), "expected null (no inference)")
        if self.commit_certified is not None and self.commit_certified > len(self.candidates):
            raise field_error(("commit_certified",), "expected at most one per candidate")
        if self.image is not None and self.image != image_name(self.label):
            raise field_error(("image",), f"expected '{image_name(self.label)}' or null")
        return self


class PlanSchema(_Model):
    schema_: Literal[1] = Field(alias="schema")
    taskgraph: Name
    scene: Name
    key: Annotated[str, Field(pattern=r"^[0-9a-f]{8,64}$")]
    settings: dict[str, Any]
    seconds: Annotated[float, Field(ge=0)] = 0.0
    decisions: Annotated[list[DecisionSchema], Field(min_length=1)]

    @model_validator(mode="after")
    def _unique(self) -> PlanSchema:
        seen: set[str] = set()
        for i, d in enumerate(self.decisions):
            if d.label in seen:
                raise field_error(("decisions", i, "label"), f"'{d.label}' appears twice")
            seen.add(d.label)
        return self


def plan_to_data(plan: Plan) -> dict[str, Any]:
    """The JSON object of ``plan.json``."""
    return {
        "schema": SCHEMA,
        "taskgraph": plan.taskgraph,
        "scene": plan.scene,
        "key": plan.key,
        "settings": plan.settings,
        "seconds": plan.seconds,
        "decisions": [
            {
                "label": d.label,
                "stages": list(d.stages),
                "candidates": list(d.candidates),
                "actions": dict(d.actions),
                "inference": d.inference,
                "optimised": list(d.optimised),
                "layout": layout_to_data(d.layout),
                "certificate": d.certificate,
                "certificate_start": d.certificate_start,
                "feasible": d.feasible,
                "image": d.image,
                "note": d.note,
                "commit_objective": d.commit_objective,
                "commit_certified": d.commit_certified,
                "commit_rate_estimate": d.commit_rate_estimate,
            }
            for d in plan.decisions
        ],
    }


def dump_plan(plan: Plan) -> bytes:
    """``plan.json`` as bytes (indented, NaN rejected)."""
    return dump_json(plan_to_data(plan)).encode()


def plan_from_data(
    data: Any, source: str, scene: Scene | None = None, where: SourceText | None = None
) -> Plan:
    """Validate parsed JSON of a plan file; with ``scene``, its layouts must fit it
    (``where``: the file's text, for the line of each error)."""
    doc = validate(PlanSchema, data, source, where)
    if scene is not None:
        try:
            _check_scene(doc, scene, source)
        except InputError as err:
            raise located(err, where) from None
    decisions = tuple(
        PlannedDecision(
            label=d.label,
            stages=tuple(d.stages),
            candidates=tuple(d.candidates),
            actions=dict(d.actions),
            inference=d.inference,
            optimised=tuple(d.optimised),
            layout={n: ObjectPose(p.x, p.y, p.yaw) for n, p in d.layout.items()},
            certificate=d.certificate,
            certificate_start=d.certificate_start,
            feasible=d.feasible,
            image=d.image,
            note=d.note,
            commit_objective=d.commit_objective,
            commit_certified=d.commit_certified,
            commit_rate_estimate=d.commit_rate_estimate,
        )
        for d in doc.decisions
    )
    return Plan(doc.taskgraph, doc.scene, doc.key, dict(doc.settings), decisions, doc.seconds)


def _check_scene(doc: PlanSchema, scene: Scene, source: str) -> None:
    if doc.scene != scene.name:
        raise InputError(
            f"expected scene '{scene.name}', got '{doc.scene}'", source=source, field="scene"
        )
    for i, d in enumerate(doc.decisions):
        for n in d.layout:
            if n not in scene.movable:
                raise InputError(
                    f"'{n}' is not a movable object of scene '{scene.name}'; movable: "
                    f"{', '.join(scene.movable)}",
                    source=source,
                    field=f"decisions[{i}].layout.{n}",
                )


def load_plan(path: Path, scene: Scene | None = None) -> Plan:
    """Read and validate ``plan.json``; its folder becomes :attr:`Plan.directory`."""
    return load_plan_with_lines(path, scene)[0]


def load_plan_with_lines(path: Path, scene: Scene | None = None) -> tuple[Plan, SourceText]:
    """:func:`load_plan`, and the file's text: :func:`check_plan` names the line of its
    error in it."""
    data, where = read_json_with_lines(path, "plan")
    plan = plan_from_data(data, str(path), scene, where)
    return replace(plan, directory=path.parent), where


# --- validation against the task graph and the scene ------------------------------------------
#: A certificate a plan records (``certificate``, ``certificate_start``, ``commit_objective``,
#: ``commit_rate_estimate``) must equal its recomputation from the layout within this much:
#: absolute up to 1, relative above. The computation is closed-form and the layout is stored
#: exactly, so a plan ``legws plan`` wrote matches to the last bit.
TOLERANCE = 1e-6


class _DesignedFor(_Model):
    name: OperatorName
    model: ModelSchema


class _Settings(BaseModel):
    model_config = ConfigDict(extra="allow")

    params: ParamsSchema = ParamsSchema()
    operators: Annotated[list[_DesignedFor], Field(min_length=1, max_length=64)] | None = None
    design_for: Annotated[str, Field(max_length=4000)] | None = None

    @model_validator(mode="after")
    def _named(self) -> _Settings:
        if (self.operators is None) != (self.design_for is None):
            raise field_error(("design_for",), "expected with settings.operators, and only then")
        if self.operators is not None:
            names = [o.name for o in self.operators]
            if len(set(names)) != len(names):
                raise field_error(("operators",), "an operator is listed twice")
            said = names[0] if len(names) == 1 else "worst of " + ", ".join(names)
            if self.design_for != said:
                raise field_error(("design_for",), f"expected {said!r} (the operators)")
        return self


class _SettingsOf(BaseModel):
    settings: _Settings


def plan_operators(
    plan: Plan, source: str, where: SourceText | None = None
) -> list[tuple[str, OperatorModel]]:
    """The people the plan was designed for (``settings.operators``: name and model; empty:
    section 2's user), each model checked as an operator file's (``where``: the plan
    file's text, for the line of each error)."""
    doc = validate(_SettingsOf, {"settings": plan.settings}, source, where)
    out = []
    for i, o in enumerate(doc.settings.operators or []):
        m = o.model
        try:
            out.append((o.name, OperatorModel(m.speed, m.sigma, m.rho, m.bias_deg, m.steering)))
        except InputError as err:
            message = str(err).removeprefix(f"{err.field}: ")
            raise InputError(
                message, source=source, field=f"settings.operators[{i}].model.{err.field}"
            ) from None
    return out


def plan_params(plan: Plan, source: str, where: SourceText | None = None) -> Params:
    """The model parameters the plan's certificates were computed with (``settings.params``;
    absent: the method's defaults; ``where``: the plan file's text, for the line of each
    error)."""
    doc = validate(_SettingsOf, {"settings": plan.settings}, source, where)
    values = {k: v for k, v in doc.settings.params.model_dump().items() if v is not None}
    try:
        return Params(**values)
    except InputError as err:
        message = str(err).removeprefix(f"{err.field}: ")
        raise InputError(message, source=source, field=f"settings.params.{err.field}") from None


def decision_goals(scene: Scene, point: DecisionPoint, layout: Layout) -> GoalSet:
    """The targets of a decision's candidates in ``layout`` as a goal set from the EE home:
    what ``legws plan`` certifies (two or more candidates)."""
    stage = point.stage_of
    targets = [target(scene, layout, stage[c], a, c) for c, a in point.actions.items()]
    return goal_set(targets, scene.home)


def check_plan(
    plan: Plan, graph: TaskGraph, scene: Scene, source: str, where: SourceText | None = None
) -> Plan:
    """``plan`` when it is a plan of ``graph`` that the daemon may use, else an
    :class:`InputError` naming ``source`` (and the line, from ``where``: the text of the
    plan file, :func:`load_plan_with_lines`), the decision's field, the stage and the first
    failing check.

    Every stage layout is held to the rule of ``--layout`` (:func:`require_feasible
    <legws_daemon.scene.constraints.require_feasible>`: bounds, clearances, distance from
    the EE home), and what the plan records must be what its layouts give:

    * the plan is of ``graph`` and ``scene``, with one decision per decision point, each
      with the graph's stages, candidates and actions;
    * each layout names every movable object; only the decision's ``optimised`` objects
      (movable, not fixed by the graph, placed by their action) differ from where the
      decision starts (the layout of the decision it is reached from, or the scene file's):
      the daemon moves exactly those when the decision begins;
    * every recorded certificate (``certificate``, ``certificate_start``, and K, the
      commit-certified count and R when recorded) equals its recomputation with the plan's
      ``settings.params`` within :data:`TOLERANCE`.

    A certificate is not required to be positive: ``--layout`` takes a feasible layout
    whatever its certificate (``legws plan`` records what it could reach).
    """
    try:
        return _check_plan(plan, graph, scene, source, where)
    except InputError as err:
        raise located(err, where) from None


def _check_plan(
    plan: Plan, graph: TaskGraph, scene: Scene, source: str, text: SourceText | None
) -> Plan:
    if plan.taskgraph != graph.name:
        raise InputError(
            f"the plan is for task graph '{plan.taskgraph}', not '{graph.name}'",
            source=source,
            field="taskgraph",
        )
    if plan.scene != scene.name:
        raise InputError(
            f"expected scene '{scene.name}', got '{plan.scene}'", source=source, field="scene"
        )
    params = plan_params(plan, source, text)
    plan_operators(plan, source, text)  # for whom it was designed: valid models (or none)
    points = decision_points(graph)
    index = _match(plan, points, graph, source)
    constraints = LayoutConstraints.of(scene)
    for k, point in enumerate(points):
        i = index[k]
        if point.parent is None:
            base, where = scene.default_layout(), "the scene file"
        else:
            parent = plan.decisions[index[point.parent]]
            base, where = parent.layout, f"after stage '{parent.label}'"
        problem = _decision_problem(
            plan.decisions[i], point, graph, scene, constraints, params, base, where
        )
        if problem is not None:
            field, message = problem
            raise InputError(
                f"stage '{plan.decisions[i].label}': {message}",
                source=source,
                field=f"decisions[{i}]{field}",
            )
    return plan


def _match(plan: Plan, points: list[DecisionPoint], graph: TaskGraph, source: str) -> list[int]:
    """For each decision point, the index of its decision in the plan."""
    index: dict[int, int] = {}
    for i, d in enumerate(plan.decisions):
        same = [k for k, p in enumerate(points) if p.label == d.label] or [
            k for k, p in enumerate(points) if {s.name for s in p.stages} == set(d.stages)
        ]
        k = same[0] if same else None
        if k is None:
            raise InputError(
                f"stage '{d.label}' is not a decision point of task graph '{graph.name}'; its "
                f"decision points: {', '.join(p.label for p in points)}",
                source=source,
                field=f"decisions[{i}].label",
            )
        if k in index:
            raise InputError(
                f"stage '{d.label}' is planned twice (decisions[{index[k]}] too)",
                source=source,
                field=f"decisions[{i}].label",
            )
        p = points[k]
        if set(d.candidates) != set(p.candidates) or dict(d.actions) != p.actions:
            want = ", ".join(f"{c} ({a})" for c, a in p.actions.items())
            raise InputError(
                f"stage '{d.label}': expected the task graph's candidates {want}",
                source=source,
                field=f"decisions[{i}].actions",
            )
        index[k] = i
    missing = [p.label for k, p in enumerate(points) if k not in index]
    if missing:
        raise InputError(
            f"no layout for stage {', '.join(repr(m) for m in missing)} of task graph "
            f"'{graph.name}'",
            source=source,
            field="decisions",
        )
    return [index[k] for k in range(len(points))]


def _decision_problem(
    d: PlannedDecision,
    point: DecisionPoint,
    graph: TaskGraph,
    scene: Scene,
    constraints: LayoutConstraints,
    params: Params,
    base: Layout,
    where: str,
) -> tuple[str, str] | None:
    """The field (after ``decisions[i]``) and what is wrong, or ``None``."""
    missing = [n for n in scene.movable if n not in d.layout]
    unknown = [n for n in d.layout if n not in scene.movable]
    if unknown:
        return f".layout.{unknown[0]}", f"'{unknown[0]}' is not a movable object of the scene"
    if missing:
        return ".layout", f"no pose of the movable object(s) {', '.join(missing)}"
    problems = constraints.problems(scene.poses(d.layout))
    if problems:
        return ".layout", f"infeasible layout: {problems[0]}"
    for n in d.optimised:
        if n in graph.fixed:
            return ".optimised", f"'{n}' is fixed by the task graph and may not be placed"
        if not action(point.actions[n]).follows_layout:
            return ".optimised", f"'{n}' ({point.actions[n]}) is not placed by its action"
    for n in scene.movable:
        if n not in d.optimised and d.layout[n] != base[n]:
            return f".layout.{n}", (
                f"'{n}' is not placed at this stage, yet it moved from {_pose(base[n])} "
                f"({where}) to {_pose(d.layout[n])}"
            )
    if not point.inference:
        return None
    goals = decision_goals(scene, point, d.layout)
    start = decision_goals(scene, point, base)
    # (field, recorded value, its recomputation, whether it is a count: exact)
    recorded: list[tuple[str, float | None, Callable[[], float], bool]] = [
        ("certificate", d.certificate, lambda: certify(goals, params).objective, False),
        ("certificate_start", d.certificate_start, lambda: certify(start, params).objective,
         False),
        ("commit_objective", d.commit_objective, lambda: commit().objective, False),
        ("commit_certified", d.commit_certified, lambda: commit().certified, True),
        ("commit_rate_estimate", d.commit_rate_estimate,
         lambda: commit_rate_estimate(goals, params), False),
    ]  # fmt: skip
    commits: list[CommitCertificate] = []

    def commit() -> CommitCertificate:
        if not commits:
            commits.append(certify_commit(goals, params))
        return commits[0]

    for field, stored, recompute, exact in recorded:
        if stored is None:
            continue  # not recorded: a plan written before the commit fields
        value = recompute()
        if (stored != value) if exact else not _close(stored, value):
            return f".{field}", (
                f"{field} is recorded as {stored:.6g} but the layout gives {value:.6g}"
                + ("" if exact else f" (tolerance {TOLERANCE:g})")
            )
    return None


def _close(stored: float, value: float) -> bool:
    return abs(stored - value) <= TOLERANCE * max(1.0, abs(value))


def _pose(p: ObjectPose) -> str:
    return f"({p.x:.3f}, {p.y:.3f}, yaw {p.yaw:.3f})"
