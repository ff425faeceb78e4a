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
``commit``: -K, ``rate``: R; absent means ``slack``).
Errors name the file and the field, e.g. ``plan.json: decisions[1].layout.grape.x: ...``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, model_validator

from legws_daemon.errors import InputError
from legws_daemon.formats.validation import (
    Angle,
    Coordinate,
    Finite,
    Name,
    field_error,
    read_json,
    validate,
)
from legws_daemon.scene.layout_file import dump_json, layout_to_data
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.task.plan import SCHEMA, Plan, PlannedDecision, image_name

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


def plan_from_data(data: Any, source: str, scene: Scene | None = None) -> Plan:
    """Validate parsed JSON of a plan file; with ``scene``, its layouts must fit it."""
    doc = validate(PlanSchema, data, source)
    if scene is not None:
        _check_scene(doc, scene, source)
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
    return replace(plan_from_data(read_json(path), str(path), scene), directory=path.parent)
