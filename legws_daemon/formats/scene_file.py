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
    AllowInfNan,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    field_validator,
    model_validator,
)

from legws_daemon.core.goals import MAX_GOALS
from legws_daemon.errors import InputError
from legws_daemon.formats.validation import (
    Angle,
    Name,
    Positive,
    Quat,
    field_error,
    field_path,
    nonzero_quaternion,
    read_toml_with_lines,
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

# --- physical bounds of a Sawyer cell (robot base frame, metres) ---------------------------
#: Half the width of the cell around the robot base: the arm reaches 1.26 m, and a table of a
#: few metres around it (the shipped one is 0.75 x 1.10 m) fits in |x|, |y| <= 3 m.
CELL_XY = 3.0
#: Heights in the cell: from the floor below a base on a pedestal or table (-1 m) to the
#: ceiling (3 m).
CELL_Z = (-1.0, 3.0)
#: An object's extents (box sides, cylinder and sphere diameters, heights): from 1 mm (a
#: washer; below it contact and clearance are degenerate) to 0.5 m (the arm carries 4 kg
#: with a parallel gripper; a larger object covers most of a 0.75 m deep table). The shipped
#: objects measure 8 mm to 0.28 m.
MIN_EXTENT = 0.001
MAX_EXTENT = 0.5
#: Most objects and fixed places of one scene: twice :data:`MAX_GOALS`, and more than fit on
#: any table of the cell (its constraints and collision checks cost the square of it).
MAX_OBJECTS = 2 * MAX_GOALS

CellXY = Annotated[float, Strict(), AllowInfNan(False), Field(ge=-CELL_XY, le=CELL_XY)]
CellZ = Annotated[float, Strict(), AllowInfNan(False), Field(ge=CELL_Z[0], le=CELL_Z[1])]
#: A position inside the cell.
CellPosition = tuple[CellXY, CellXY, CellZ]
#: A length within the cell's width (a clearance), >= 0.
CellLength = Annotated[float, Strict(), AllowInfNan(False), Field(ge=0, le=2 * CELL_XY)]
#: A table side, > 0 and at most the cell's width.
TableSide = Annotated[float, Strict(), AllowInfNan(False), Field(gt=0, le=2 * CELL_XY)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PoseSpec(_Model):
    position: CellPosition
    quaternion: Quat

    _q = field_validator("quaternion")(nonzero_quaternion)


class WorkspaceSpec(_Model):
    """Table, bounds on object centres, clearances and the EE home pose (method.md §5)."""

    table_height: CellZ = 0.0
    table_center: tuple[CellXY, CellXY] = (0.575, 0.0)
    table_size: tuple[TableSide, TableSide] = (0.75, 1.10)
    x_range: tuple[CellXY, CellXY] = (0.30, 0.85)
    y_range: tuple[CellXY, CellXY] = (-0.45, 0.45)
    min_clearance: CellLength = 0.12
    min_home_distance: CellLength = 0.15
    ee_home: PoseSpec = PoseSpec(position=(0.55, 0.0, 0.30), quaternion=(0.0, 1.0, 0.0, 0.0))

    @model_validator(mode="after")
    def _ranges(self) -> WorkspaceSpec:
        for field, (lo, hi) in (("x_range", self.x_range), ("y_range", self.y_range)):
            if not lo < hi:
                raise field_error((field,), f"must be [low, high] with low < high, got {[lo, hi]}")
        cx, cy = self.table_center
        sx, sy = self.table_size
        if abs(cx) + sx / 2 > CELL_XY or abs(cy) + sy / 2 > CELL_XY:
            raise field_error(
                ("table_size",),
                f"the table must lie within |x|, |y| <= {CELL_XY:g} m of the robot base (the "
                f"cell), got centre {[cx, cy]} and size {[sx, sy]}",
            )
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


#: Fiducial dictionaries of OpenCV's ``cv2.aruco`` a scene's markers may come from
#: (``DICT_`` left off), and how many markers each holds.
MARKER_DICTIONARIES: dict[str, int] = {
    "4X4_50": 50,
    "4X4_100": 100,
    "5X5_100": 100,
    "6X6_250": 250,
    "APRILTAG_36h11": 587,
}
MarkerDictionary = Literal["4X4_50", "4X4_100", "5X5_100", "6X6_250", "APRILTAG_36h11"]
#: A marker's printed side (its black square, without the white margin around it): from
#: 1 cm (about 7 pixels at 1.4 mm per pixel: the smallest a 640 x 480 camera over the table
#: still reads) to 30 cm.
MarkerSide = Annotated[float, Strict(), AllowInfNan(False), Field(ge=0.01, le=0.3)]
MarkerId = Annotated[int, Strict(), Field(ge=0, le=999)]


class MarkerSpec(_Model):
    """The fiducial marker stuck on an object: centred on its top face, the marker's image
    x axis (its top edge, left to right) along the object's x axis."""

    id: MarkerId
    size: MarkerSide


class TableMarkerSpec(_Model):
    """A fiducial marker lying on the table at a known pose (the camera's extrinsics come
    from these): centre ``x``, ``y`` (robot base frame) and ``yaw`` of its image x axis."""

    id: MarkerId
    size: MarkerSide
    x: CellXY
    y: CellXY
    yaw: Angle = 0.0


class MarkersSpec(_Model):
    """Which fiducial markers a camera tracker finds (``legws track``)."""

    dictionary: MarkerDictionary = "4X4_50"
    table: Annotated[list[TableMarkerSpec], Field(min_length=1, max_length=16)]


class ObjectSpec(_Model):
    name: Name
    label: str | None = None
    shape: Shape
    size: list[Positive]
    color: tuple[Unit, Unit, Unit] = (0.6, 0.6, 0.6)
    grasp: GraspKind = "top"
    symmetry: Annotated[int, Strict(), Field(ge=0, le=360)] | None = None
    movable: Annotated[bool, Strict()] = True
    x: CellXY
    y: CellXY
    yaw: Angle = 0.0
    marker: MarkerSpec | None = None

    @model_validator(mode="after")
    def _size(self) -> ObjectSpec:
        want = _SIZE_LEN[self.shape]
        if len(self.size) != want:
            raise field_error(
                ("size",),
                f"size of a {self.shape} must be {_SIZE_HELP[self.shape]} ({want} numbers), "
                f"got {len(self.size)}",
            )
        for i, (what, extent) in enumerate(_extents(self.shape, self.size)):
            if not MIN_EXTENT <= extent <= MAX_EXTENT:
                raise field_error(
                    ("size", i),
                    f"the {self.shape}'s {what} is {extent:.4g} m; objects measure "
                    f"{MIN_EXTENT:g} to {MAX_EXTENT:g} m",
                )
        if self.marker is not None:
            room = marker_room(self.shape, self.size)
            if room is None:
                raise field_error(("marker",), "a sphere has no flat top to carry a marker")
            if self.marker.size > room + 1e-9:
                raise field_error(
                    ("marker", "size"),
                    f"a marker of {self.marker.size:g} m does not fit on the {self.shape}'s "
                    f"top face (at most {room:.4g} m)",
                )
        return self


def marker_room(shape: str, size: list[float] | tuple[float, ...]) -> float | None:
    """The largest marker side that fits on an object's top face (``None``: no flat top)."""
    if shape == "box":
        return min(size[0], size[1])
    if shape == "cylinder":
        return size[0] * 2**0.5  # a square inscribed in the top disc
    return None


def _extents(shape: str, size: list[float]) -> list[tuple[str, float]]:
    """The named extents of an object's ``size`` numbers, one per number."""
    if shape == "box":
        return [(f"{axis} side", v) for axis, v in zip("xyz", size, strict=True)]
    if shape == "cylinder":
        return [("diameter", 2 * size[0]), ("height", size[1])]
    return [("diameter", 2 * size[0])]


class PlaceSpec(_Model):
    """A fixed target pose that is not an object (e.g. the user's mouth)."""

    name: Name
    label: str | None = None
    position: CellPosition
    quaternion: Quat
    symmetry: Annotated[int, Strict(), Field(ge=0, le=360)] = 1

    _q = field_validator("quaternion")(nonzero_quaternion)


class SceneSpec(_Model):
    schema_version: Literal[1]
    name: Name
    tier: str | None = None
    description: str = ""
    workspace: WorkspaceSpec = WorkspaceSpec()
    objects: Annotated[list[ObjectSpec], Field(min_length=2, max_length=MAX_OBJECTS)]
    places: Annotated[list[PlaceSpec], Field(max_length=MAX_OBJECTS)] = []
    goals: list[Name] | None = None
    markers: MarkersSpec | None = None

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
        if len(candidates) > MAX_GOALS:
            raise field_error(
                ("goals",) if self.goals is not None else ("objects",),
                f"a scene has at most {MAX_GOALS} candidate goals (movable objects, or the "
                f"list goals), has {len(candidates)}",
            )
        self._check_markers()
        return self

    def _check_markers(self) -> None:
        """Marker ids unique and in the dictionary; objects carry markers only with a
        ``[markers]`` table; table markers lie on the table."""
        with_marker = [(i, o) for i, o in enumerate(self.objects) if o.marker is not None]
        if self.markers is None:
            if with_marker:
                i, _ = with_marker[0]
                raise field_error(
                    ("objects", i, "marker"),
                    "objects carry markers but the scene has no [markers] table (the "
                    "dictionary and the markers on the table)",
                )
            return
        count = MARKER_DICTIONARIES[self.markers.dictionary]
        ids: list[tuple[tuple[int | str, ...], int]] = [
            (("markers", "table", j, "id"), m.id) for j, m in enumerate(self.markers.table)
        ]
        ids += [(("objects", i, "marker", "id"), o.marker.id) for i, o in with_marker if o.marker]
        seen: dict[int, tuple[int | str, ...]] = {}
        for loc, marker_id in ids:
            if marker_id >= count:
                raise field_error(
                    loc, f"the dictionary {self.markers.dictionary} has markers 0..{count - 1}"
                )
            if marker_id in seen:
                raise field_error(
                    loc, f"marker {marker_id} is used twice (also at {field_path(seen[marker_id])})"
                )
            seen[marker_id] = loc
        ws = self.workspace
        (cx, cy), (sx, sy) = ws.table_center, ws.table_size
        for j, m in enumerate(self.markers.table):
            if abs(m.x - cx) + m.size / 2 > sx / 2 or abs(m.y - cy) + m.size / 2 > sy / 2:
                raise field_error(
                    ("markers", "table", j), f"the marker at {[m.x, m.y]} is not on the table"
                )


def load_scene_spec(path: Path) -> SceneSpec:
    """Read and validate a scene file; errors name the file, the line and the field (every
    one of them)."""
    data, where = read_toml_with_lines(path, "scene")
    spec = validate(SceneSpec, data, str(path), where)
    if spec.name != path.stem:
        raise InputError(
            f"expected '{path.stem}' (the file's name), got '{spec.name}'",
            source=where.at(str(path), ("name",)),
            field="name",
        )
    return spec
