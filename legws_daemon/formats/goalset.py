"""The goal-set file (``shared/spec/interfaces.md``): input of ``legws certify``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, Strict, field_validator

from legws_daemon.core.geometry import Pose
from legws_daemon.core.goals import MAX_GOALS, GoalSet, too_many_goals
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.scene_file import CellPosition
from legws_daemon.formats.validation import (
    Finite,
    Quat,
    located,
    nonzero_quaternion,
    printable,
    read_json_with_lines,
    validate,
)


class PoseSchema(BaseModel):
    """A pose in the robot cell: the position within the bounds of a scene's (|x|, |y| <= 3 m,
    -1 <= z <= 3 m, base frame), which also bounds every horizon at a given step length."""

    model_config = ConfigDict(extra="allow")

    position: CellPosition
    quaternion: Quat

    _q = field_validator("quaternion")(nonzero_quaternion)


class GoalSchema(PoseSchema):
    name: Annotated[str, Field(min_length=1, max_length=64)]
    symmetry: Annotated[int, Strict(), Field(ge=0, le=360)] = 1


class ParamsSchema(BaseModel):
    """Every field optional; unknown keys are rejected (a typo must not fall back silently)."""

    model_config = ConfigDict(extra="forbid")

    beta: Finite | None = None
    rotation_weight: Finite | None = None
    sigma: Finite | None = None
    v_max: Finite | None = None
    dt: Finite | None = None
    alpha: Finite | None = None
    horizon_fraction: Finite | None = None
    cost: str | None = None
    p_thresh: Finite | None = None


class GoalSetFile(BaseModel):
    model_config = ConfigDict(extra="allow")

    x0: PoseSchema
    goals: Annotated[list[GoalSchema], Field(min_length=2, max_length=MAX_GOALS)]
    params: ParamsSchema = ParamsSchema()


def params_from_schema(schema: ParamsSchema, source: str, base: Params | None = None) -> Params:
    values = {k: v for k, v in schema.model_dump().items() if v is not None}
    try:
        return Params(**{**(base.as_dict() if base else {}), **values})
    except InputError as err:
        raise InputError(_strip(err), source=source, field=f"params.{err.field}") from None


def _strip(err: InputError) -> str:
    text = str(err)
    text = text.split(": ", 1)[1] if err.field and text.startswith(err.field) else text
    return printable(text)  # goal names are free text: a line break stays escaped


def goalset_from_data(
    data: Any, source: str, where: SourceText | None = None
) -> tuple[GoalSet, Params]:
    """Validate parsed JSON of a goal-set file (``where``: its text, for the line of each
    error).

    More than :data:`~legws_daemon.core.goals.MAX_GOALS` goals are refused before any goal
    is validated (the certificates' cost grows with the square of their number)."""
    goals = data.get("goals") if isinstance(data, dict) else None
    if isinstance(goals, list) and len(goals) > MAX_GOALS:
        error = InputError(too_many_goals(len(goals)), source=source, field="goals")
        raise located(error, where)
    doc = validate(GoalSetFile, data, source, where)
    try:
        params = params_from_schema(doc.params, source)
    except InputError as err:
        raise located(err, where) from None
    x0 = Pose(np.array(doc.x0.position), np.array(doc.x0.quaternion))
    try:
        goals = GoalSet.build(
            [g.name for g in doc.goals],
            [g.position for g in doc.goals],
            [g.quaternion for g in doc.goals],
            x0,
            [g.symmetry for g in doc.goals],
        )
    except InputError as err:
        raise located(InputError(_strip(err), source=source, field=err.field), where) from None
    return goals, params


def load_goalset(path: Path) -> tuple[GoalSet, Params]:
    """Read and validate a goal-set file; every error is a line naming file, line and field."""
    data, where = read_json_with_lines(path, "goal set")
    return goalset_from_data(data, str(path), where)


def goalset_to_data(goals: GoalSet, params: Params) -> dict[str, Any]:
    """The goal-set file contents for ``goals`` (round-trips through :func:`goalset_from_data`)."""
    return {
        "x0": {
            "position": [float(v) for v in goals.x0.position],
            "quaternion": [float(v) for v in goals.x0.quaternion],
        },
        "goals": [
            {
                "name": name,
                "position": [float(v) for v in goals.positions[i]],
                "quaternion": [float(v) for v in goals.quaternions[i]],
                "symmetry": int(goals.symmetry[i]),
            }
            for i, name in enumerate(goals.names)
        ],
        "params": params.as_dict(),
    }
