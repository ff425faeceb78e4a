"""Scene files (``scenes/*.toml``): schema, validation and loading.

A scene file describes the table workspace, the end-effector home pose, the objects
(shape, size, colour, grasp kind, whether the layout may move them, and their default
pose: together the scene's shipped default layout), fixed target places (e.g. a mouth
pose) and which movable objects form the default set of candidate goals.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    field_validator,
    model_validator,
)

from legws_daemon.errors import InputError
from legws_daemon.formats.validation import (
    Angle,
    Coordinate,
    Finite,
    Name,
    NonNegative,
    Positive,
    Quat,
    Vec3,
    field_error,
    nonzero_quaternion,
    read_toml,
    validate,
)

GraspKind = Literal["top", "side"]
GRASP_KINDS: tuple[str, ...] = get_args(GraspKind)
Shape = Literal["box", "cylinder", "sphere"]
SHAPES: tuple[str, ...] = get_args(Shape)

SCHEMA_VERSION = 1
_SIZE_LEN = {"box": 3, "cylinder": 2, "sphere": 1}
_SIZE_HELP = {
    "box": "[x, y, z] full extents",
    "cylinder": "[radius, height]",
    "sphere": "[radius]",
}

Unit = Annotated[float, Strict(), Field(ge=0, le=1)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PoseSpec(_Model):
    position: Vec3
    quaternion: Quat

    _q = field_validator("quaternion")(nonzero_quaternion)


class WorkspaceSpec(_Model):
    """Table, bounds on object centres, clearances and the EE home pose (method.md §5)."""

    table_height: Finite = 0.0
    table_center: tuple[Finite, Finite] = (0.575, 0.0)
    table_size: tuple[Positive, Positive] = (0.75, 1.10)
    x_range: tuple[Finite, Finite] = (0.30, 0.85)
    y_range: tuple[Finite, Finite] = (-0.45, 0.45)
    min_clearance: NonNegative = 0.12
    min_home_distance: NonNegative = 0.15
    ee_home: PoseSpec = PoseSpec(position=(0.55, 0.0, 0.30), quaternion=(0.0, 1.0, 0.0, 0.0))

    @model_validator(mode="after")
    def _ranges(self) -> WorkspaceSpec:
        for field, (lo, hi) in (("x_range", self.x_range), ("y_range", self.y_range)):
            if not lo < hi:
                raise field_error((field,), f"must be [low, high] with low < high, got {[lo, hi]}")
        cx, cy = self.table_center
        sx, sy = self.table_size
        if not (
            cx - sx / 2 <= self.x_range[0]
            and self.x_range[1] <= cx + sx / 2
            and cy - sy / 2 <= self.y_range[0]
            and self.y_range[1] <= cy + sy / 2
        ):
            raise field_error(
                ("x_range",), "x_range and y_range must lie on the table (table_center, table_size)"
            )
        if self.ee_home.position[2] <= self.table_height:
            raise field_error(("ee_home", "position"), "ee_home must be above the table")
        return self


class ObjectSpec(_Model):
    name: Name
    label: str | None = None
    shape: Shape
    size: list[Positive]
    color: tuple[Unit, Unit, Unit] = (0.6, 0.6, 0.6)
    grasp: GraspKind = "top"
    symmetry: Annotated[int, Strict(), Field(ge=0, le=360)] | None = None
    movable: Annotated[bool, Strict()] = True
    x: Coordinate
    y: Coordinate
    yaw: Angle = 0.0

    @model_validator(mode="after")
    def _size(self) -> ObjectSpec:
        want = _SIZE_LEN[self.shape]
        if len(self.size) != want:
            raise field_error(
                ("size",),
                f"size of a {self.shape} must be {_SIZE_HELP[self.shape]} ({want} numbers), "
                f"got {len(self.size)}",
            )
        return self


class PlaceSpec(_Model):
    """A fixed target pose that is not an object (e.g. the user's mouth)."""

    name: Name
    label: str | None = None
    position: Vec3
    quaternion: Quat
    symmetry: Annotated[int, Strict(), Field(ge=0, le=360)] = 1

    _q = field_validator("quaternion")(nonzero_quaternion)


class SceneSpec(_Model):
    schema_version: Literal[1]
    name: Name
    tier: str | None = None
    description: str = ""
    workspace: WorkspaceSpec = WorkspaceSpec()
    objects: Annotated[list[ObjectSpec], Field(min_length=2)]
    places: list[PlaceSpec] = []
    goals: list[Name] | None = None

    @model_validator(mode="after")
    def _names(self) -> SceneSpec:
        seen: set[str] = set()
        named = [("objects", i, o.name) for i, o in enumerate(self.objects)]
        named += [("places", i, p.name) for i, p in enumerate(self.places)]
        for group, i, name in named:
            if name in seen:
                raise field_error((group, i, "name"), f"name '{name}' is used twice")
            seen.add(name)
        movable = [o.name for o in self.objects if o.movable]
        if self.goals is not None:
            for j, g in enumerate(self.goals):
                if g not in movable:
                    raise field_error(
                        ("goals", j),
                        f"goal '{g}' is not a movable object; movable: {', '.join(movable)}",
                    )
                if g in self.goals[:j]:
                    raise field_error(("goals", j), f"goal '{g}' is listed twice")
        candidates = self.goals if self.goals is not None else movable
        if len(candidates) < 2:
            raise field_error(
                ("goals",) if self.goals is not None else ("objects",),
                f"a scene needs at least 2 candidate goals (movable objects), "
                f"has {len(candidates)}",
            )
        return self


def load_scene_spec(path: Path) -> SceneSpec:
    """Read and validate a scene file; errors name the file and the field."""
    spec = validate(SceneSpec, read_toml(path), str(path))
    if spec.name != path.stem:
        raise InputError(
            f"expected '{path.stem}' (the file's name), got '{spec.name}'",
            source=str(path),
            field="name",
        )
    return spec
