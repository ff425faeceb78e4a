"""The geometry of a placement mat: the table drawn at true scale, tiled over paper pages.

Everything here is millimetres on the *sheet*: the whole mat as one big picture, before it
is cut into pages. The sheet is the table seen from above with the robot at the bottom
edge: sheet right is the robot's -y, sheet up is its +x (a rotation of the base frame,
never a mirror, so a marker printed on the sheet reads as the camera above the table sees
it). :class:`SheetFrame` maps base-frame metres to sheet millimetres and back.

The sheet is tiled by a grid of pages (:func:`tile`): each page prints its *tile* (the
part of the sheet it owns) and a band of :data:`OVERLAP` / 2 around it that the
neighbouring pages own too, inside a white :data:`MARGIN` that carries the page label,
the header and a 100 mm scale bar. Registration marks sit on every grid corner: each
appears on every page that shows it, at the same sheet point, so taped pages line up.

:func:`build_mat` gathers what is drawn (table, robot base, every object's footprint,
grasp and orientation arrows, the table's fiducial markers) as plain shapes in sheet
millimetres; :func:`decision_mat` and :func:`layout_mat` add the header (the decision, its
certificates). Nothing here draws or writes a file (:mod:`legws_daemon.placement.pdf` does).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import certify_commit
from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.task.plan import PlannedDecision
from legws_daemon.tracking.markers import QUIET_CELLS, marker_image, scene_markers

#: Paper sizes in portrait, (width, height) in millimetres (ISO 216).
PAPERS: dict[str, tuple[float, float]] = {"a4": (210.0, 297.0), "a3": (297.0, 420.0)}
#: White border of every page, mm: most printers print from 4-5 mm off the edge; the page
#: label, header and scale bar sit in this border, outside the drawing.
MARGIN = 12.0
#: Width of the band two neighbouring pages both print, mm: the registration marks on
#: the grid corners lie in it, whole on both pages.
OVERLAP = 20.0
#: Radius of a registration mark's circle and half the length of its cross, mm (within
#: half the overlap: a mark is whole on every page that shows its corner).
MARK_RADIUS = 4.0
MARK_ARM = 7.0
#: Length of the scale bar on every page, mm.
SCALE_BAR = 100.0

Role = Literal["candidate", "movable", "fixed"]
Point = tuple[float, float]


@dataclass(frozen=True, slots=True)
class Rect:
    """An axis-aligned rectangle of the sheet (or a page), mm."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def width(self) -> float:
        return self.x1 - self.x0

    @property
    def height(self) -> float:
        return self.y1 - self.y0

    def contains(self, x: float, y: float) -> bool:
        return self.x0 <= x <= self.x1 and self.y0 <= y <= self.y1

    def overlaps(self, other: Rect) -> bool:
        return (
            self.x0 < other.x1 and other.x0 < self.x1 and self.y0 < other.y1 and other.y0 < self.y1
        )


@dataclass(frozen=True, slots=True)
class SheetFrame:
    """Base frame (metres) to sheet (millimetres): sheet x = robot -y, sheet y = robot +x.

    Attributes:
        near_x: the base-frame x of the sheet's bottom edge (y = 0), m.
        left_y: the base-frame y of the sheet's left edge (x = 0), m.
    """

    near_x: float
    left_y: float

    def to_sheet(self, x: float, y: float) -> Point:
        """The sheet point (mm) of the base-frame point ``(x, y)`` (m)."""
        return ((self.left_y - y) * 1000.0, (x - self.near_x) * 1000.0)

    def points(self, xy: FloatArray) -> FloatArray:
        """Sheet points ``(N, 2)`` (mm) of base-frame points ``(N, 2)`` (m)."""
        xy = np.asarray(xy, dtype=np.float64)
        return np.column_stack(
            [(self.left_y - xy[:, 1]) * 1000.0, (xy[:, 0] - self.near_x) * 1000.0]
        )

    def to_base(self, sx: float, sy: float) -> Point:
        """The base-frame point (m) of the sheet point ``(sx, sy)`` (mm)."""
        return (self.near_x + sy / 1000.0, self.left_y - sx / 1000.0)

    @staticmethod
    def angle(yaw: float) -> float:
        """The sheet angle (rad, from sheet x, counter-clockwise) of base-frame heading ``yaw``."""
        return yaw + math.pi / 2


@dataclass(frozen=True, slots=True)
class Page:
    """One sheet of paper of the mat.

    Attributes:
        row, column: 1-based; row 1 is the far edge (top), column 1 the robot's left.
        number: 1-based, row by row from the top left.
        tile: the part of the sheet this page owns, mm.
        window: the part of the sheet it prints (the tile and half the overlap around it).
        paper: the page, in sheet coordinates (the window and the margin around it).
    """

    row: int
    column: int
    number: int
    tile: Rect
    window: Rect
    paper: Rect

    def to_page(self, x: float, y: float) -> Point:
        """A sheet point in the page's own millimetres (origin at its bottom-left corner)."""
        return (x - self.paper.x0, y - self.paper.y0)


@dataclass(frozen=True, slots=True)
class Tiling:
    """The pages covering a sheet.

    Attributes:
        paper: ``a4`` or ``a3``.
        landscape: the pages are printed in landscape.
        rows, columns: of the page grid.
        pitch: ``(width, height)`` of a tile, mm.
        pages: row by row from the top left.
    """

    paper: str
    landscape: bool
    rows: int
    columns: int
    pitch: Point
    pages: tuple[Page, ...]

    @property
    def size(self) -> Point:
        """The sheet covered by the tiles, mm."""
        return (self.columns * self.pitch[0], self.rows * self.pitch[1])

    def corners(self) -> list[Point]:
        """Every grid corner (where the registration marks go), sheet mm."""
        px, py = self.pitch
        return [(c * px, r * py) for r in range(self.rows + 1) for c in range(self.columns + 1)]

    def page_at(self, x: float, y: float) -> Page:
        """The page whose tile holds the sheet point ``(x, y)`` (the last one on a cut)."""
        column = min(max(int(x // self.pitch[0]), 0), self.columns - 1) + 1
        row = self.rows - min(max(int(y // self.pitch[1]), 0), self.rows - 1)
        return self.pages[(row - 1) * self.columns + column - 1]


def paper_size(paper: str, landscape: bool) -> Point:
    """``(width, height)`` of a page, mm."""
    try:
        w, h = PAPERS[paper]
    except KeyError:
        raise InputError(f"unknown paper '{paper}'; known: {', '.join(PAPERS)}") from None
    return (h, w) if landscape else (w, h)


def _grid(paper: str, landscape: bool, width: float, height: float) -> Tiling:
    pw, ph = paper_size(paper, landscape)
    pitch = (pw - 2 * MARGIN - OVERLAP, ph - 2 * MARGIN - OVERLAP)
    columns = max(1, math.ceil(width / pitch[0] - 1e-9))
    rows = max(1, math.ceil(height / pitch[1] - 1e-9))
    pages: list[Page] = []
    half = OVERLAP / 2
    for row in range(1, rows + 1):
        for column in range(1, columns + 1):
            x0, y0 = (column - 1) * pitch[0], (rows - row) * pitch[1]
            tile = Rect(x0, y0, x0 + pitch[0], y0 + pitch[1])
            window = Rect(tile.x0 - half, tile.y0 - half, tile.x1 + half, tile.y1 + half)
            sheet = Rect(
                window.x0 - MARGIN,
                window.y0 - MARGIN,
                window.x0 - MARGIN + pw,
                window.y0 - MARGIN + ph,
            )
            pages.append(Page(row, column, len(pages) + 1, tile, window, sheet))
    return Tiling(paper, landscape, rows, columns, pitch, tuple(pages))


def tile(paper: str, width: float, height: float) -> Tiling:
    """Pages of ``paper`` covering a sheet of ``width`` x ``height`` mm: portrait or
    landscape, whichever needs fewer pages (portrait on a tie)."""
    portrait = _grid(paper, False, width, height)
    landscape = _grid(paper, True, width, height)
    return landscape if len(landscape.pages) < len(portrait.pages) else portrait


# --- what is drawn ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Arrow:
    """An arrow from ``start`` to ``end`` (its head), sheet mm."""

    start: Point
    end: Point


@dataclass(frozen=True, slots=True)
class Footprint:
    """An object's outline on the table.

    Attributes:
        name, label: the object's name and its label (the name when it has none).
        shape: ``box`` (a rotated rectangle) or ``circle`` (cylinder, sphere).
        center: sheet mm.
        polygon: ``(4, 2)`` corners of a box, sheet mm (empty for a circle).
        radius: of a circle, mm (0 for a box).
        role: ``candidate`` of the decision, other ``movable`` object, or ``fixed``.
        color: the scene's RGB colour of the object.
        marker: the id of the marker it carries, if any.
        orientation: its x axis, from the centre.
        grasp: where the gripper comes from: a side grasp's approach onto its face, a top
            grasp's two fingers closing (none when any turn of it is the same grasp).
        text_at: where its label goes (under the outline), sheet mm.
    """

    name: str
    label: str
    shape: Literal["box", "circle"]
    center: Point
    polygon: FloatArray
    radius: float
    role: Role
    color: tuple[float, float, float]
    marker: int | None
    orientation: Arrow
    grasp: tuple[Arrow, ...]
    text_at: Point

    def bounds(self) -> Rect:
        """The outline's bounding box, sheet mm."""
        if self.shape == "circle":
            (x, y), r = self.center, self.radius
            return Rect(x - r, y - r, x + r, y + r)
        lo, hi = self.polygon.min(axis=0), self.polygon.max(axis=0)
        return Rect(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


@dataclass(frozen=True, slots=True)
class PrintedMarker:
    """A fiducial marker at true size.

    Attributes:
        id: its id in the dictionary.
        size: side of its black square, mm.
        center: sheet (or page) mm.
        angle: of its x axis (its top edge, left to right), rad.
        cells: ``(n, n)`` booleans, True where a cell is black; row 0 is the top edge.
    """

    id: int
    size: float
    center: Point
    angle: float
    cells: np.ndarray

    def _to_sheet(self, local: FloatArray) -> FloatArray:
        c, s = math.cos(self.angle), math.sin(self.angle)
        placed: FloatArray = local @ np.array([[c, s], [-s, c]]) + np.array(self.center)
        return placed

    def corners(self) -> FloatArray:
        """Top-left, top-right, bottom-right, bottom-left corners ``(4, 2)``, mm."""
        h = self.size / 2
        return self._to_sheet(np.array([[-h, h], [h, h], [h, -h], [-h, -h]]))

    def quiet_zone(self) -> FloatArray:
        """Corners ``(4, 2)`` of the white square around it that the detector needs, mm."""
        n = self.cells.shape[0]
        h = self.size / 2 * (n + 2 * QUIET_CELLS) / n
        return self._to_sheet(np.array([[-h, h], [h, h], [h, -h], [-h, -h]]))

    def black_cells(self) -> list[FloatArray]:
        """The black cells as squares ``(4, 2)``, counter-clockwise, mm."""
        n = self.cells.shape[0]
        cell = self.size / n
        out = []
        for r, c in zip(*np.nonzero(self.cells), strict=True):
            u0, v1 = -self.size / 2 + c * cell, self.size / 2 - r * cell
            square = np.array([[u0, v1 - cell], [u0 + cell, v1 - cell], [u0 + cell, v1], [u0, v1]])
            out.append(self._to_sheet(square))
        return out

    def bounds(self) -> Rect:
        q = self.quiet_zone()
        lo, hi = q.min(axis=0), q.max(axis=0)
        return Rect(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def marker_cells(dictionary: str, marker_id: int) -> np.ndarray:
    """The cells of a marker, black border included: ``(n, n)`` booleans, True = black."""
    return np.asarray(marker_image(dictionary, marker_id, cell_pixels=1, quiet=False) < 128)


@dataclass(frozen=True, slots=True)
class Header:
    """What the mat is of, printed on every page.

    Attributes:
        scene: the scene's name.
        title: the decision's label, or what the layout is.
        certificate: J of the candidates (``None``: no inference).
        commit: K of the candidates and how many are commit-certified (``None``: unknown).
        candidates: how many candidates the decision has.
        feasible: the decision's layout is feasible (``None``: not known).
        note: what "feasible" means here, or why it is not.
    """

    scene: str
    title: str
    certificate: float | None
    commit: tuple[float, int] | None
    candidates: int
    feasible: bool | None
    note: str = ""

    def lines(self) -> tuple[str, str]:
        """Two lines: what the mat is of, and its certificates."""
        first = f"legws placement mat · scene {self.scene} · {self.title}"
        parts = [
            "J = " + ("- (no inference)" if self.certificate is None else f"{self.certificate:.3f}")
        ]
        if self.commit is not None:
            k, n = self.commit
            parts.append(f"K = {k:.3f} ({n}/{self.candidates} commit-certified)")
        if self.feasible is not None:
            parts.append("feasible" if self.feasible else "NOT feasible")
        if self.note:
            parts.append(self.note)
        return first, " · ".join(parts)


@dataclass(frozen=True, slots=True)
class BaseMark:
    """Where the robot base is: on the sheet (``inside``), or off it below the centre line."""

    at: Point
    inside: bool
    text: str


@dataclass(frozen=True)
class Mat:
    """Everything a placement mat shows, in sheet millimetres.

    Attributes:
        header: what it is of.
        frame: base frame to sheet.
        tiling: the pages.
        table: the table's outline on the sheet.
        center_line: the robot's y = 0 across the table (``None`` when off the table).
        base: the robot base's mark.
        footprints: one per object.
        markers: the table's fiducial markers.
    """

    header: Header
    frame: SheetFrame
    tiling: Tiling
    table: Rect
    center_line: tuple[Point, Point] | None
    base: BaseMark
    footprints: tuple[Footprint, ...]
    markers: tuple[PrintedMarker, ...]

    def split_markers(self) -> list[tuple[PrintedMarker, list[Page]]]:
        """The table markers (with their white margin) crossed by a cut between pages, and
        the pages they lie on: taped together, they would not lie flat and exact."""
        out = []
        for m in self.markers:
            b = m.bounds()
            pages = [p for p in self.tiling.pages if p.tile.overlaps(b)]
            if len(pages) > 1:
                out.append((m, pages))
        return out


def _support(shape: str, size: Point, direction: FloatArray) -> float:
    """How far an outline reaches from its centre along a unit ``direction`` (object frame)."""
    if shape == "circle":
        return size[0] / 2
    return abs(float(direction[0])) * size[0] / 2 + abs(float(direction[1])) * size[1] / 2


def _grasp_arrows(
    scene: Scene, name: str, pose: ObjectPose, frame: SheetFrame, shape: str, size: Point
) -> tuple[Arrow, ...]:
    """The grasp's arrows (see :class:`Footprint`), from the grasp frame of the scene."""
    grasp = scene.grasps[name]
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    Rz = np.array([[c, -s], [s, c]])

    def arrow(direction: FloatArray, far: float, near: float) -> Arrow:
        a, b = Rz @ (direction * far), Rz @ (direction * near)
        return Arrow(
            frame.to_sheet(pose.x + a[0], pose.y + a[1]),
            frame.to_sheet(pose.x + b[0], pose.y + b[1]),
        )

    approach = grasp.rotation[:, 2]
    if abs(approach[2]) < 0.5:  # horizontal: the gripper comes from the side, onto a face
        d = approach[:2] / np.linalg.norm(approach[:2])
        reach = _support(shape, size, d) / 1000.0
        return (arrow(-d, reach + 0.045, reach + 0.004),)
    if grasp.symmetry == 0:  # from above, any turn is the same grasp: nothing to show
        return ()
    closing = grasp.rotation[:2, 0] / np.linalg.norm(grasp.rotation[:2, 0])
    reach = _support(shape, size, closing) / 1000.0
    return tuple(arrow(sign * closing, reach + 0.02, reach + 0.003) for sign in (1.0, -1.0))


def footprint(
    scene: Scene, name: str, pose: ObjectPose, frame: SheetFrame, role: Role
) -> Footprint:
    """The outline, arrows and label of object ``name`` at ``pose``."""
    spec = scene.object(name)
    sx, sy, _ = extents(spec.shape, tuple(spec.size))
    shape: Literal["box", "circle"] = "box" if spec.shape == "box" else "circle"
    size = (sx * 1000.0, sy * 1000.0)
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    center = frame.to_sheet(pose.x, pose.y)
    polygon = np.zeros((0, 2))
    if shape == "box":
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * np.array([sx, sy]) / 2
        world = local @ np.array([[c, s], [-s, c]]) + np.array([pose.x, pose.y])
        polygon = frame.points(world)
    radius = size[0] / 2 if shape == "circle" else 0.0
    grasp = _grasp_arrows(scene, name, pose, frame, shape, size)
    below = center[1] - radius if shape == "circle" else float(polygon[:, 1].min())
    below = min([below] + [p[1] for a in grasp for p in (a.start, a.end)])  # under the arrows
    half_x = min(0.8 * sx / 2, 0.025)
    orientation = Arrow(center, frame.to_sheet(pose.x + c * half_x, pose.y + s * half_x))
    return Footprint(
        name=name,
        label=spec.label or name,
        shape=shape,
        center=center,
        polygon=polygon,
        radius=radius,
        role=role,
        color=spec.color,
        marker=spec.marker.id if spec.marker is not None else None,
        orientation=orientation,
        grasp=grasp,
        text_at=(center[0], below - 2.0),
    )


def table_markers(scene: Scene, frame: SheetFrame) -> tuple[PrintedMarker, ...]:
    """The scene's table markers on the sheet (none when the scene has no ``[markers]``)."""
    if scene.spec.markers is None:
        return ()
    markers = scene_markers(scene)
    return tuple(
        PrintedMarker(
            m.id,
            m.size * 1000.0,
            frame.to_sheet(m.x, m.y),
            SheetFrame.angle(m.yaw),
            marker_cells(markers.dictionary, m.id),
        )
        for m in markers.table.values()
    )


def _base_mark(frame: SheetFrame, table: Rect) -> BaseMark:
    at = frame.to_sheet(0.0, 0.0)
    if table.contains(*at):
        return BaseMark(at, True, "robot base centre")
    if table.x0 <= at[0] <= table.x1 and at[1] < table.y0:
        distance = table.y0 - at[1]
        return BaseMark((at[0], table.y0), False, f"robot base centre {distance:.0f} mm ↓")
    x, y = frame.to_base(table.x0, table.y0)
    return BaseMark(
        (table.x0, table.y0),
        False,
        f"this corner: x = {x * 1000:.0f} mm, y = {y * 1000:.0f} mm from the robot base centre",
    )


def build_mat(
    scene: Scene,
    poses: Mapping[str, ObjectPose],
    candidates: Sequence[str],
    header: Header,
    paper: str = "a4",
) -> Mat:
    """The mat of ``scene`` with its objects at ``poses`` (every object, by name), the
    ``candidates`` highlighted, on pages of ``paper``.

    The table (``workspace.table_center``, ``table_size``) is centred on the page grid.
    """
    ws = scene.workspace
    (cx, cy), (tx, ty) = ws.table_center, ws.table_size
    width, height = ty * 1000.0, tx * 1000.0
    tiling = tile(paper, width, height)
    gw, gh = tiling.size
    pad_x, pad_y = (gw - width) / 2, (gh - height) / 2
    frame = SheetFrame(cx - tx / 2 - pad_y / 1000.0, cy + ty / 2 + pad_x / 1000.0)
    table = Rect(pad_x, pad_y, pad_x + width, pad_y + height)
    center_line = None
    if cy - ty / 2 < 0 < cy + ty / 2:
        center_line = (frame.to_sheet(cx - tx / 2, 0.0), frame.to_sheet(cx + tx / 2, 0.0))
    prints = tuple(
        footprint(scene, n, p, frame, _role(scene, n, candidates)) for n, p in poses.items()
    )
    return Mat(
        header,
        frame,
        tiling,
        table,
        center_line,
        _base_mark(frame, table),
        prints,
        table_markers(scene, frame),
    )


def _role(scene: Scene, name: str, candidates: Sequence[str]) -> Role:
    if name in candidates:
        return "candidate"
    return "movable" if name in scene.movable else "fixed"


def page_label(mat: Mat, page: Page) -> str:
    """``row r, column c (page k of N)``: where the page goes (row 1 is the far edge)."""
    return f"row {page.row}, column {page.column} (page {page.number} of {len(mat.tiling.pages)})"


# --- the mats of a plan's decisions and of one layout ---------------------------------------


def decision_mat(scene: Scene, decision: PlannedDecision, paper: str = "a4") -> Mat:
    """The mat of a planned decision: its layout, its candidates highlighted, and the
    certificates the plan records."""
    commit = None
    if decision.commit_objective is not None and decision.commit_certified is not None:
        commit = (decision.commit_objective, decision.commit_certified)
    header = Header(
        scene=scene.name,
        title=f"decision {decision.label}",
        certificate=decision.certificate,
        commit=commit,
        candidates=len(decision.candidates),
        feasible=decision.feasible,
        note="" if decision.feasible else decision.note,
    )
    return build_mat(scene, scene.poses(decision.layout), decision.candidates, header, paper)


def layout_mat(
    scene: Scene, layout: Layout, title: str, paper: str = "a4", params: Params | None = None
) -> Mat:
    """The mat of one layout of ``scene``: the scene's candidate goals highlighted, their
    ``J`` and ``K`` from the EE home (``params``: the defaults), and whether the layout
    meets the scene's constraints (bounds, clearances; the IK is not checked here)."""
    params = params or Params()
    goals = scene.goal_set(layout)
    commit = certify_commit(goals, params)
    problems = LayoutConstraints.of(scene).problems(scene.poses(layout))
    header = Header(
        scene=scene.name,
        title=title,
        certificate=certify(goals, params).objective,
        commit=(commit.objective, commit.certified),
        candidates=len(goals.names),
        feasible=not problems,
        note=problems[0] if problems else "constraints met (IK not checked)",
    )
    return build_mat(scene, scene.poses(layout), scene.goal_names, header, paper)
