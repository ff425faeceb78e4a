"""The geometry of a placement mat: the table drawn at true scale, on the pages that carry it.

Everything here is millimetres on the *sheet*: the whole mat as one big picture, before it
is cut into pages. The sheet is the table seen from above with the robot at the bottom
edge: sheet right is the robot's -y, sheet up is its +x (a rotation of the base frame,
never a mirror, so a marker printed on the sheet reads as the camera above the table sees
it). :class:`SheetFrame` maps base-frame metres to sheet millimetres and back; the table's
left near corner (the robot's left, its side) is the sheet's origin.

Only the parts of the sheet that carry something are printed (:func:`tile`): every
object's outline and arrows and every table marker lie on the *tiles* of the pages, and
no page is printed for bare table. The tiles lie in strips (rows, or columns) whose
position, page orientation and tile starts are chosen to need the fewest pages, then to
hang least over the table's edge; a table marker lies whole on one tile (taped across a
cut it would not lie flat). Each page prints
its tile and a band of :data:`OVERLAP` / 2 around it, inside a white :data:`MARGIN` that
carries the page label, where the page lies on the table, the header and a 100 mm scale
bar. Registration marks sit on every tile corner: each appears on every page whose tile
holds it, at the same sheet point, so taped pages line up.

Labels (:class:`Label`) are placed, not just anchored: each lies inside one tile, clear of
the outlines, arrows, markers, registration marks and other labels, next to what it names
(with a leader line when it had to move away), so no cut goes through one.

:func:`build_mat` gathers what is drawn (table, robot base, every object's footprint,
grasp and orientation arrows, the table's fiducial markers, the labels) as plain shapes in
sheet millimetres; :func:`decision_mat` and :func:`layout_mat` add the header (the
decision, its certificates). Nothing here draws or writes a file
(:mod:`legws_daemon.placement.pdf` does); text is only measured (the font's metrics).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache, lru_cache
from itertools import pairwise
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
#: the tile corners lie in it, whole on both pages.
OVERLAP = 20.0
#: Radius of a registration mark's circle and half the length of its cross, mm (within
#: half the overlap: a mark is whole on every page whose tile holds its corner).
MARK_RADIUS = 4.0
MARK_ARM = 7.0
#: Length of the scale bar on every page, mm.
SCALE_BAR = 100.0
#: Text sizes, points (6 pt is 2.1 mm: legible, small enough for a 55 mm tea bag).
SMALL = 6.0
NORMAL = 7.5
#: The font of every text (embedded in the PDF), and the distance of two lines of a label
#: in font sizes.
FONT = "DejaVu Sans"
LINE_PITCH = 1.15
#: Where a character's box lies around its baseline, in font sizes (DejaVu Sans' ascent
#: and descent; a PDF reader reports the same box).
ASCENT = 0.764
DESCENT = 0.236
#: Clearance of a label from a cut line and from what it must not cover, mm.
LABEL_INSET = 1.5
LABEL_GAP = 1.0
#: A label further than this from its object gets a leader line, mm.
LEADER = 4.0

MM_PER_POINT = 25.4 / 72
_EPS = 1e-6

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

    @property
    def center(self) -> Point:
        return ((self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2)

    def contains(self, x: float, y: float) -> bool:
        return self.x0 <= x <= self.x1 and self.y0 <= y <= self.y1

    def holds(self, other: Rect) -> bool:
        """Whether ``other`` lies wholly inside (its edges may touch)."""
        return (
            self.x0 <= other.x0 + _EPS
            and other.x1 <= self.x1 + _EPS
            and self.y0 <= other.y0 + _EPS
            and other.y1 <= self.y1 + _EPS
        )

    def overlaps(self, other: Rect) -> bool:
        return (
            self.x0 < other.x1 and other.x0 < self.x1 and self.y0 < other.y1 and other.y0 < self.y1
        )

    def grown(self, d: float) -> Rect:
        return Rect(self.x0 - d, self.y0 - d, self.x1 + d, self.y1 + d)

    def union(self, other: Rect) -> Rect:
        return Rect(
            min(self.x0, other.x0),
            min(self.y0, other.y0),
            max(self.x1, other.x1),
            max(self.y1, other.y1),
        )

    def distance(self, other: Rect) -> float:
        """The gap between the two rectangles (0 when they touch or overlap), mm."""
        dx = max(other.x0 - self.x1, self.x0 - other.x1, 0.0)
        dy = max(other.y0 - self.y1, self.y0 - other.y1, 0.0)
        return math.hypot(dx, dy)

    def nearest(self, x: float, y: float) -> Point:
        """The point of the rectangle nearest ``(x, y)``."""
        return (min(max(x, self.x0), self.x1), min(max(y, self.y0), self.y1))

    @staticmethod
    def around(points: Iterable[Point]) -> Rect:
        xs, ys = zip(*points, strict=True)
        return Rect(min(xs), min(ys), max(xs), max(ys))


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


# --- pages --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Page:
    """One sheet of paper of the mat.

    Attributes:
        number: 1-based, in reading order of the tiles (top to bottom, left to right).
        tile: the part of the sheet this page owns (inside its dashed cut line), mm.
        window: the part of the sheet it prints (the tile and half the overlap around it).
        paper: the page, in sheet coordinates (the window and the margin around it).
        landscape: the page is printed in landscape.
    """

    number: int
    tile: Rect
    window: Rect
    paper: Rect
    landscape: bool


Side = Literal["left", "right", "above", "below"]


@dataclass(frozen=True, slots=True)
class Tiling:
    """The pages of a mat.

    Attributes:
        paper: ``a4`` or ``a3``.
        pages: in reading order (see :attr:`Page.number`).
        full: how many pages a grid over the whole table would need (what is saved).
    """

    paper: str
    pages: tuple[Page, ...]
    full: int

    @property
    def orientations(self) -> tuple[int, int]:
        """How many pages are portrait, and how many landscape."""
        landscape = sum(p.landscape for p in self.pages)
        return (len(self.pages) - landscape, landscape)

    def bounds(self) -> Rect:
        """The part of the sheet the tiles cover, mm."""
        out = self.pages[0].tile
        for p in self.pages[1:]:
            out = out.union(p.tile)
        return out

    def corners(self) -> list[Point]:
        """Every tile corner (where the registration marks go), sheet mm, each once."""
        seen: dict[tuple[float, float], Point] = {}
        for p in self.pages:
            t = p.tile
            for c in ((t.x0, t.y0), (t.x1, t.y0), (t.x0, t.y1), (t.x1, t.y1)):
                seen.setdefault((round(c[0], 6), round(c[1], 6)), c)
        return list(seen.values())

    def page_at(self, x: float, y: float) -> Page:
        """The page whose tile holds the sheet point ``(x, y)`` (the last one on a cut);
        the nearest tile's page when no tile holds it."""
        holding = [p for p in self.pages if p.tile.contains(x, y)]
        if holding:
            return holding[-1]
        return min(self.pages, key=lambda p: p.tile.distance(Rect(x, y, x, y)))

    def neighbours(self, page: Page) -> list[tuple[Side, Page]]:
        """The pages whose tiles share a stretch of ``page``'s cut line (taped to it)."""
        t = page.tile
        out: list[tuple[Side, Page]] = []
        for p in self.pages:
            o = p.tile
            shared_x = min(t.x1, o.x1) - max(t.x0, o.x0)
            shared_y = min(t.y1, o.y1) - max(t.y0, o.y0)
            if p is page:
                continue
            if shared_y > 1.0 and abs(o.x1 - t.x0) < _EPS:
                out.append(("left", p))
            elif shared_y > 1.0 and abs(o.x0 - t.x1) < _EPS:
                out.append(("right", p))
            elif shared_x > 1.0 and abs(o.y0 - t.y1) < _EPS:
                out.append(("above", p))
            elif shared_x > 1.0 and abs(o.y1 - t.y0) < _EPS:
                out.append(("below", p))
        return out


def paper_size(paper: str, landscape: bool) -> Point:
    """``(width, height)`` of a page, mm."""
    try:
        w, h = PAPERS[paper]
    except KeyError:
        raise InputError(f"unknown paper '{paper}'; known: {', '.join(PAPERS)}") from None
    return (h, w) if landscape else (w, h)


def tile_size(paper: str, landscape: bool) -> Point:
    """``(width, height)`` of a page's tile, mm: the paper inside its margin and band."""
    pw, ph = paper_size(paper, landscape)
    return (pw - 2 * MARGIN - OVERLAP, ph - 2 * MARGIN - OVERLAP)


def make_page(number: int, tile: Rect, paper: str, landscape: bool) -> Page:
    """The page of ``tile`` (its window and paper around it)."""
    pw, ph = paper_size(paper, landscape)
    window = tile.grown(OVERLAP / 2)
    sheet = Rect(
        window.x0 - MARGIN, window.y0 - MARGIN, window.x0 - MARGIN + pw, window.y0 - MARGIN + ph
    )
    return Page(number, tile, window, sheet, landscape)


def full_grid(paper: str, width: float, height: float) -> int:
    """How many pages of ``paper`` a grid over a whole ``width`` x ``height`` mm sheet
    needs (portrait or landscape, whichever needs fewer)."""
    counts = []
    for landscape in (False, True):
        tw, th = tile_size(paper, landscape)
        counts.append(max(1, math.ceil(width / tw - 1e-9)) * max(1, math.ceil(height / th - 1e-9)))
    return min(counts)


@dataclass(frozen=True, slots=True)
class Content:
    """Something the pages must carry: a box of the sheet (mm); ``whole``: on one tile."""

    box: Rect
    whole: bool = False


_Span = tuple[float, float, bool]


def _cover(
    spans: Sequence[_Span], length: float, end_at: float = math.inf
) -> tuple[tuple[float, ...], int]:
    """Tiles of ``length`` along a line covering every span ``(start, end, whole)``, from
    the left: each starts at the first point not yet covered (or ends just before a whole
    span it would cut, when there is room). Then the last tiles, when they reach past
    ``end_at`` (the table's edge), slide back as far as what they cover and the tile
    before them allow. Returns the tiles' starts and the whole spans cut."""
    tiles: list[list[float]] = []  # start, end, the furthest point it has to cover
    covered, cut = -math.inf, 0

    def cuts(end: float, spans: Sequence[_Span]) -> int:
        return sum(1 for a, b, whole in spans if whole and a < end - _EPS and b > end + _EPS)

    while True:
        rest = [s for s in spans if s[1] > covered + _EPS]
        if not rest:
            break
        start = max(covered, min(s[0] for s in rest))
        end = start + length
        blocked = [a for a, b, whole in rest if whole and start + _EPS < a < end - _EPS < b]
        if blocked and min(blocked) - length >= covered - _EPS:
            earlier = min(blocked)
            if cuts(earlier, rest) < cuts(end, rest):
                start, end = earlier - length, earlier
        cut += cuts(end, rest)
        reach = max(min(b, end) for a, b, _ in rest if a < end - _EPS)
        tiles.append([start, end, reach])
        covered = end
    if tiles and tiles[-1][1] > end_at + _EPS:
        # the last tiles that abut slide back together: by how far the last reaches past
        # ``end_at``, as far as what it has to cover and the tile before them allow
        first = len(tiles) - 1
        while first and abs(tiles[first - 1][1] - tiles[first][0]) < _EPS:
            first -= 1
        floor = tiles[first - 1][1] if first else -math.inf
        start, end, reach = tiles[-1]
        by = min(end - end_at, end - reach, tiles[first][0] - floor)
        ends = [t[1] for t in tiles[first:]]
        if by > _EPS and sum(cuts(e - by, spans) for e in ends) <= sum(
            cuts(e, spans) for e in ends
        ):
            for t in tiles[first:]:
                t[0], t[1] = t[0] - by, t[1] - by
    return tuple(t[0] for t in tiles), cut


@dataclass(frozen=True, slots=True)
class _Strip:
    """A strip of tiles: from ``start`` across, ``thickness`` thick, tiles of ``length``."""

    start: float
    thickness: float
    length: float
    landscape: bool
    starts: tuple[float, ...]


_Option = tuple[int, int, float, tuple[_Strip, ...]]


def _overhang(lo: float, hi: float, within: tuple[float, float]) -> float:
    """How far ``[lo, hi]`` reaches out of ``within``, mm."""
    return max(within[0] - lo, 0.0) + max(hi - within[1], 0.0)


def _strips(
    items: Sequence[Content], sizes: Sequence[tuple[float, float, bool]], within: Rect
) -> _Option:
    """Strips along x, stacked in y, covering ``items`` with the fewest tiles: each strip
    is one of ``sizes`` ``(thickness, length, landscape)`` and starts at or after the end
    of the one below, at the lowest point not yet covered or lower (down to where it
    still covers that point). Of those, the tiles reaching least out of ``within`` (the
    table). Returns the whole items cut, the tiles, their overhang (mm) and the strips."""
    boxes = [(c.box, c.whole) for c in items]
    edges = sorted({v for b, _ in boxes for v in (b.y0, b.y1)})
    lengthwise, crosswise = (within.x0, within.x1), (within.y0, within.y1)

    @cache
    def strip(
        start: float, thickness: float, length: float
    ) -> tuple[int, float, tuple[float, ...]]:
        top = start + thickness
        spans = [(b.x0, b.x1, w) for b, w in boxes if b.y0 < top - _EPS and b.y1 > start + _EPS]
        starts, cut = _cover(spans, length, within.x1)
        cut += sum(1 for b, w in boxes if w and b.y0 < top - _EPS and b.y1 > top + _EPS)
        over = sum(_overhang(x, x + length, lengthwise) for x in starts)
        over += len(starts) * _overhang(start, top, crosswise)
        return cut, over, starts

    @cache
    def best(y: float) -> _Option:
        rest = [b for b, _ in boxes if b.y1 > y + _EPS]
        if not rest:
            return (0, 0, 0.0, ())
        low = max(y, min(b.y0 for b in rest))
        found: _Option | None = None
        for thickness, length, landscape in sizes:
            lowest = max(y, low - thickness)
            starts = {low, lowest, within.y0, within.y1 - thickness}
            starts |= {e - thickness for e in edges} | set(edges)
            for s in sorted(v for v in starts if lowest - _EPS <= v <= low + _EPS):
                cut, over, tiles = strip(round(s, 6), thickness, length)
                more_cut, more, more_over, strips = best(round(s + thickness, 6))
                option = (
                    cut + more_cut,
                    len(tiles) + more,
                    over + more_over,
                    (_Strip(s, thickness, length, landscape, tiles), *strips),
                )
                if found is None or option[:3] < found[:3]:
                    found = option
        assert found is not None
        return found

    return best(-math.inf)


def _shared(a: Rect, b: Rect) -> float:
    """How long a stretch of cut line two tiles share, mm (0: they do not join)."""
    if abs(a.x1 - b.x0) < _EPS or abs(b.x1 - a.x0) < _EPS:
        return max(min(a.y1, b.y1) - max(a.y0, b.y0), 0.0)
    if abs(a.y1 - b.y0) < _EPS or abs(b.y1 - a.y0) < _EPS:
        return max(min(a.x1, b.x1) - max(a.x0, b.x0), 0.0)
    return 0.0


#: A tile slid back onto the table keeps this much of a cut line it shares, mm (room for
#: two registration marks).
KEEP_JOIN = 20.0


def _onto(
    tiles: list[tuple[Rect, bool]], contents: Sequence[Content], within: Rect
) -> list[tuple[Rect, bool]]:
    """``tiles`` with each that reaches past ``within`` (the table) slid back towards it,
    one side after the other, as far as it goes without leaving uncovered what it holds,
    cutting a whole item, running into another tile or losing a join with one."""
    out = [r for r, _ in tiles]
    for i in range(len(out)):
        for axis, sign in ((0, -1.0), (0, 1.0), (1, -1.0), (1, 1.0)):
            t = out[i]
            lo, hi = (t.x0, t.x1) if axis == 0 else (t.y0, t.y1)
            w_lo, w_hi = (within.x0, within.x1) if axis == 0 else (within.y0, within.y1)
            want = hi - w_hi if sign < 0 else w_lo - lo  # how far past the table's edge
            if want <= _EPS:
                continue
            others = [o for j, o in enumerate(out) if j != i]

            def moved(by: float, t: Rect = t, axis: int = axis, sign: float = sign) -> Rect:
                d = sign * by
                if axis == 0:
                    return Rect(t.x0 + d, t.y0, t.x1 + d, t.y1)
                return Rect(t.x0, t.y0 + d, t.x1, t.y1 + d)

            def fine(r: Rect, t: Rect = t, others: list[Rect] = others) -> bool:
                if any(r.grown(-_EPS).overlaps(o) for o in others):
                    return False
                for c in contents:
                    held = t.grown(-_EPS).overlaps(c.box)
                    if held and not _covered_by([r, *others], c.box):
                        return False
                    if c.whole and t.holds(c.box) and not r.holds(c.box):
                        return False
                return all(_shared(r, o) >= KEEP_JOIN for o in others if _shared(t, o) > _EPS)

            # the farthest of a few steps that is fine (what is fine is not monotone in
            # general: a step at a time, from the whole way back)
            for by in (want, *(want * k / 8 for k in range(7, 0, -1))):
                if fine(moved(by)):
                    out[i] = moved(by)
                    break
    return [(r, land) for r, (_, land) in zip(out, tiles, strict=True)]


def _covered_by(tiles: Sequence[Rect], box: Rect) -> bool:
    """Whether ``tiles`` cover ``box``: every corner of the pieces they cut it into lies on
    a tile (exact for axis-aligned tiles: the pieces are the cells of their edges)."""
    xs = sorted({box.x0, box.x1, *(v for t in tiles for v in (t.x0, t.x1) if box.x0 < v < box.x1)})
    ys = sorted({box.y0, box.y1, *(v for t in tiles for v in (t.y0, t.y1) if box.y0 < v < box.y1)})
    grown = [t.grown(_EPS) for t in tiles]
    for x0, x1 in pairwise(xs):
        for y0, y1 in pairwise(ys):
            if not any(g.holds(Rect(x0, y0, x1, y1)) for g in grown):
                return False
    return True


#: The ways the strips are laid: ``(columns, from the right, from the top)``.
_View = tuple[bool, bool, bool]
_VIEWS: tuple[_View, ...] = tuple(
    (c, fx, fy) for c in (False, True) for fx in (False, True) for fy in (False, True)
)


def _view(r: Rect, view: _View) -> Rect:
    """``r`` as the strips see it: mirrored (x, y), then turned (columns become rows)."""
    columns, fx, fy = view
    if fx:
        r = Rect(-r.x1, r.y0, -r.x0, r.y1)
    if fy:
        r = Rect(r.x0, -r.y1, r.x1, -r.y0)
    return Rect(r.y0, r.x0, r.y1, r.x1) if columns else r


def _unview(r: Rect, view: _View) -> Rect:
    """The sheet's rectangle ``r`` seen in ``view`` is."""
    columns, fx, fy = view
    if columns:
        r = Rect(r.y0, r.x0, r.y1, r.x1)
    if fy:
        r = Rect(r.x0, -r.y1, r.x1, -r.y0)
    if fx:
        r = Rect(-r.x1, r.y0, -r.x0, r.y1)
    return r


def tile(
    paper: str, contents: Sequence[Content], within: Rect | None = None, full: int = 0
) -> Tiling:
    """The fewest pages of ``paper`` whose tiles cover ``contents``, no whole item cut
    when that can be helped.

    Tried: strips of rows and of columns, laid from either side; all portrait pages, all
    landscape, or either per strip. Among tilings cutting as few whole items and needing
    as few pages, one orientation is preferred over a mix, then tiles that reach least out
    of ``within`` (the table: paper hanging over its edge does not lie flat), then the
    fewest objects cut by a cut line. ``full``: what a grid over the whole table needs
    (reported by :attr:`Tiling.full`).
    """
    if not contents:
        raise ValueError("a mat carries at least one object")
    if within is None:
        within = contents[0].box
        for c in contents[1:]:
            within = within.union(c.box)
    portrait, landscape = tile_size(paper, False), tile_size(paper, True)
    best: tuple[tuple[int, int, int, int, int], list[tuple[Rect, bool]]] | None = None
    for view in _VIEWS:
        items = [Content(_view(c.box, view), c.whole) for c in contents]
        columns = view[0]
        options = {
            False: (portrait[0], portrait[1], False),
            True: (landscape[0], landscape[1], True),
        }
        for kinds in ((False,), (True,), (False, True)):
            # a strip's thickness is the tile's height (rows) or width (columns)
            sizes = [
                (h, w, land) if not columns else (w, h, land)
                for w, h, land in (options[k] for k in kinds)
            ]
            cut, _, over, strips = _strips(items, sizes, _view(within, view))
            tiles = [
                (_unview(Rect(x, s.start, x + s.length, s.start + s.thickness), view), s.landscape)
                for s in strips
                for x in s.starts
            ]
            split = sum(
                sum(r.grown(-_EPS).overlaps(c.box) for r, _ in tiles) - 1
                for c in contents
                if not c.whole
            )
            mixed = len({land for _, land in tiles}) > 1
            key = (cut, len(tiles), int(mixed), round(over / 10.0), split)
            if best is None or key < best[0]:
                best = (key, tiles)
    assert best is not None
    tiles = _onto(best[1], contents, within)
    ordered = sorted(tiles, key=lambda t: (-round(t[0].y1, 6), round(t[0].x0, 6)))
    pages = tuple(make_page(i, r, paper, land) for i, (r, land) in enumerate(ordered, 1))
    return Tiling(paper, pages, full)


# --- what is drawn ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Arrow:
    """An arrow from ``start`` to ``end`` (its head), sheet mm."""

    start: Point
    end: Point

    def bounds(self, head: float = 0.0) -> Rect:
        """Its bounding box, ``head`` (half the head's width, mm) around."""
        return Rect.around([self.start, self.end]).grown(head)


#: Half the widths of the heads of the orientation and grasp arrows, mm (as drawn).
ORIENTATION_HEAD = 1.0
GRASP_HEAD = 1.75


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

    def bounds(self) -> Rect:
        """The outline's bounding box, sheet mm."""
        if self.shape == "circle":
            (x, y), r = self.center, self.radius
            return Rect(x - r, y - r, x + r, y + r)
        lo, hi = self.polygon.min(axis=0), self.polygon.max(axis=0)
        return Rect(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

    def drawing(self) -> Rect:
        """What is drawn of it (the outline and its grasp arrows), sheet mm."""
        out = self.bounds()
        for a in self.grasp:
            out = out.union(a.bounds(GRASP_HEAD))
        return out

    def text(self) -> tuple[str, ...]:
        """The lines of its label: its name (and that it is fixed), its marker."""
        lines = [self.label + (" (fixed)" if self.role == "fixed" else "")]
        if self.marker is not None:
            lines.append(f"marker {self.marker}")
        return tuple(lines)

    def edge_towards(self, x: float, y: float) -> Point:
        """Where the outline crosses the ray from its centre towards ``(x, y)``."""
        cx, cy = self.center
        d = np.array([x - cx, y - cy])
        n = float(np.linalg.norm(d))
        if n < _EPS:
            return self.center
        d /= n
        if self.shape == "circle":
            return (cx + d[0] * self.radius, cy + d[1] * self.radius)
        reach = math.inf
        for a, b in zip(self.polygon, np.roll(self.polygon, -1, axis=0), strict=True):
            e = b - a
            det = d[0] * -e[1] + e[0] * d[1]
            if abs(det) < _EPS:
                continue
            rel = a - np.array(self.center)
            t = (rel[0] * -e[1] + e[0] * rel[1]) / det
            u = (d[0] * rel[1] - d[1] * rel[0]) / det
            if t >= 0 and -_EPS <= u <= 1 + _EPS:
                reach = min(reach, t)
        reach = 0.0 if reach == math.inf else reach
        return (cx + d[0] * reach, cy + d[1] * reach)


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

    def caption(self) -> str:
        return f"table marker {self.id} ({self.size:g} mm)"


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

    def drawing(self) -> Rect:
        """What is drawn of it (a cross in a circle, or an arrow up to the near edge), mm."""
        x, y = self.at
        return Rect(x - 8, y - 8, x + 8, y + 8) if self.inside else Rect(x - 2, y, x + 2, y + 22)


# --- labels -------------------------------------------------------------------------------


@lru_cache(maxsize=4096)
def text_width(text: str, size: float, bold: bool = False) -> float:
    """The advance width of one line of ``text`` at ``size`` pt in :data:`FONT`, mm."""
    from matplotlib.font_manager import FontProperties, findfont, get_font
    from matplotlib.ft2font import LoadFlags

    prop = FontProperties(family=FONT, weight="bold" if bold else "normal")
    font = get_font(findfont(prop))
    font.set_size(size, 72)
    width = 0.0
    for ch in text:
        glyph = font.load_char(ord(ch), flags=LoadFlags.NO_HINTING)
        width += glyph.linearHoriAdvance / 65536
    return width * MM_PER_POINT


def text_size(lines: Sequence[str], size: float, bold: bool = False) -> Point:
    """``(width, height)`` of the box of ``lines`` at ``size`` pt, mm: the widest line, and
    every line's character boxes (:data:`ASCENT` above to :data:`DESCENT` below its
    baseline, lines :data:`LINE_PITCH` apart)."""
    width = max(text_width(line, size, bold) for line in lines)
    height = size * (1 + LINE_PITCH * (len(lines) - 1)) * MM_PER_POINT
    return width, height


@dataclass(frozen=True, slots=True)
class Label:
    """A text of the mat, placed.

    Attributes:
        lines: top to bottom.
        size: pt.
        box: what its characters cover, sheet mm (the drawing centres each line in it).
        rotation: 0; 90 (reads upwards) or -90 (downwards): one line along a side.
        bold, color: how it is drawn.
        leader: a line from the label to what it names, when it is not next to it.
        page: the page whose tile holds it (0: not on a page, as on the preview).
    """

    lines: tuple[str, ...]
    size: float
    box: Rect
    rotation: int = 0
    bold: bool = False
    color: str = "black"
    leader: tuple[Point, Point] | None = None
    page: int = 0

    def baselines(self) -> list[tuple[float, float]]:
        """The anchor of each line (its baseline's centre), sheet mm."""
        s = self.size * MM_PER_POINT
        (cx, cy), b = self.box.center, self.box
        if self.rotation == 90:
            return [(b.x0 + ASCENT * s, cy)]
        if self.rotation == -90:
            return [(b.x0 + DESCENT * s, cy)]
        return [(cx, b.y1 - ASCENT * s - i * LINE_PITCH * s) for i in range(len(self.lines))]


@dataclass
class Placer:
    """Places labels one by one: each in one of ``regions``, clear (by ``gap``) of what is
    ``blocked`` and of the labels placed before it."""

    regions: Sequence[Rect]
    blocked: list[Rect] = field(default_factory=list)
    gap: float = LABEL_GAP

    def region_of(self, box: Rect) -> int | None:
        """The index of a region holding ``box`` with nothing in the way, if any."""
        if any(box.overlaps(b.grown(self.gap)) for b in self.blocked):
            return None
        for i, r in enumerate(self.regions):
            if r.holds(box):
                return i
        return None

    def first(self, boxes: Iterable[Rect]) -> tuple[Rect, int] | None:
        """The first of ``boxes`` that is free (and its region), taken; ``None``: none."""
        for box in boxes:
            i = self.region_of(box)
            if i is not None:
                self.blocked.append(box)
                return box, i
        return None


#: How far from what it names a label is tried, mm (the first gaps keep it next to it).
RINGS = (1.5, 3.0, 5.0, 8.0, 12.0, 17.0, 23.0, 30.0, 40.0, 52.0, 66.0)


def around(
    near: Rect, width: float, height: float, rings: Sequence[float] = RINGS
) -> Iterator[Rect]:
    """Boxes of ``width`` x ``height`` around ``near``, nearest first: under it, over
    it, right and left of it, then slid along each side."""
    cx, cy = near.center
    for g in rings:
        below = Rect(cx - width / 2, near.y0 - g - height, cx + width / 2, near.y0 - g)
        above = Rect(cx - width / 2, near.y1 + g, cx + width / 2, near.y1 + g + height)
        right = Rect(near.x1 + g, cy - height / 2, near.x1 + g + width, cy + height / 2)
        left = Rect(near.x0 - g - width, cy - height / 2, near.x0 - g, cy + height / 2)
        yield from (below, above, right, left)
        for k in (1, 2, 3, 4):
            dx = k * width / 4
            dy = k * max(height, near.height / 2) / 2
            for box, sx, sy in (
                (below, dx, 0.0),
                (below, -dx, 0.0),
                (above, dx, 0.0),
                (above, -dx, 0.0),
                (right, 0.0, dy),
                (right, 0.0, -dy),
                (left, 0.0, dy),
                (left, 0.0, -dy),
            ):
                yield Rect(box.x0 + sx, box.y0 + sy, box.x1 + sx, box.y1 + sy)


def along(
    fixed: float, lo: float, hi: float, length: float, thickness: float, vertical: bool
) -> Iterator[Rect]:
    """Boxes along a line from ``lo`` to ``hi``: ``length`` along it, ``thickness`` across
    from ``fixed`` (positive: above or right of it, negative: below or left), every 4 mm
    from ``lo``."""
    a, b = (fixed, fixed + thickness) if thickness > 0 else (fixed + thickness, fixed)
    start = lo
    while start + length <= hi + _EPS:
        if vertical:
            yield Rect(a, start, b, start + length)
        else:
            yield Rect(start, a, start + length, b)
        start += 4.0


def leader(f: Footprint, box: Rect) -> tuple[Point, Point] | None:
    """A line from ``box`` to ``f``'s outline when the label is not right next to it."""
    if box.distance(f.drawing()) <= LEADER:
        return None
    start = box.nearest(*f.center)
    return (start, f.edge_towards(*start))


@dataclass(frozen=True, slots=True)
class Drawing:
    """What a mat draws, before its pages and labels (sheet mm)."""

    table: Rect
    center_line: tuple[Point, Point] | None
    base: BaseMark
    footprints: tuple[Footprint, ...]
    markers: tuple[PrintedMarker, ...]


@dataclass(frozen=True)
class Mat:
    """Everything a placement mat shows, in sheet millimetres.

    Attributes:
        header: what it is of.
        frame: base frame to sheet.
        tiling: the pages.
        table: the table's outline on the sheet (its left near corner at the origin).
        center_line: the robot's y = 0 across the table (``None`` when off the table).
        base: the robot base's mark.
        footprints: one per object.
        markers: the table's fiducial markers.
        labels: every text on the tiles (names, marker ids, edges), placed.
    """

    header: Header
    frame: SheetFrame
    tiling: Tiling
    table: Rect
    center_line: tuple[Point, Point] | None
    base: BaseMark
    footprints: tuple[Footprint, ...]
    markers: tuple[PrintedMarker, ...]
    labels: tuple[Label, ...] = ()

    def drawing(self) -> Drawing:
        """What it draws, without its pages and labels."""
        return Drawing(self.table, self.center_line, self.base, self.footprints, self.markers)

    def split_markers(self) -> list[tuple[PrintedMarker, list[Page]]]:
        """The table markers (with their white margin) crossed by a cut between pages, and
        the pages they lie on: taped together, they would not lie flat and exact."""
        out = []
        for m in self.markers:
            b = m.bounds()
            pages = [p for p in self.tiling.pages if p.tile.grown(-_EPS).overlaps(b)]
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
    """The outline and arrows of object ``name`` at ``pose``."""
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
        grasp=_grasp_arrows(scene, name, pose, frame, shape, size),
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


#: The table's edges as the pages name them.
NEAR_EDGE = "table edge, robot side (near)"
FAR_EDGE = "table edge, far side"
LEFT_EDGE = "robot's left (+y)"
RIGHT_EDGE = "robot's right (−y)"
CENTER_LINE = "robot y = 0"
_ROLES: dict[Role, int] = {"candidate": 0, "movable": 1, "fixed": 2}


def obstacles(drawn: Drawing, corners: Iterable[Point]) -> list[Rect]:
    """What a label must not cover: outlines, arrows, markers, the base mark, the table's
    edges and centre line, and the registration marks at ``corners``."""
    out: list[Rect] = []
    for f in drawn.footprints:
        out.append(f.bounds())
        out.extend(a.bounds(GRASP_HEAD) for a in f.grasp)
    out.extend(m.bounds() for m in drawn.markers)
    out.append(drawn.base.drawing())
    t, w = drawn.table, 0.5
    out += [
        Rect(t.x0, t.y0 - w, t.x1, t.y0 + w),
        Rect(t.x0, t.y1 - w, t.x1, t.y1 + w),
        Rect(t.x0 - w, t.y0, t.x0 + w, t.y1),
        Rect(t.x1 - w, t.y0, t.x1 + w, t.y1),
    ]
    if drawn.center_line is not None:
        (x, y0), (_, y1) = drawn.center_line
        out.append(Rect(x - 0.3, y0, x + 0.3, y1))
    reach = MARK_ARM + 0.3
    out += [Rect(x - reach, y - reach, x + reach, y + reach) for x, y in corners]
    return out


def _labels(drawn: Drawing, tiling: Tiling) -> tuple[list[Label], list[Rect]]:
    """The labels of a mat placed on its tiles, and where each object's or marker's label
    that found no room would go (right under it)."""
    pages = tiling.pages
    regions = [p.tile.grown(-LABEL_INSET) for p in pages]
    placer = Placer(regions, obstacles(drawn, tiling.corners()))
    labels: list[Label] = []
    missing: list[Rect] = []
    for f in sorted(drawn.footprints, key=lambda f: _ROLES[f.role]):
        lines, bold = f.text(), f.role == "candidate"
        w, h = text_size(lines, SMALL, bold)
        got = placer.first(around(f.drawing(), w, h))
        if got is None:
            missing.append(next(around(f.drawing(), w, h)))
            continue
        box, i = got
        labels.append(Label(lines, SMALL, box, bold=bold, leader=leader(f, box), page=i + 1))
    for m in drawn.markers:
        w, h = text_size([m.caption()], SMALL)
        got = placer.first(around(m.bounds(), w, h))
        if got is None:
            missing.append(next(around(m.bounds(), w, h)))
            continue
        box, i = got
        labels.append(Label((m.caption(),), SMALL, box, page=i + 1))
    for i, region in enumerate(regions):
        labels += _table_labels(drawn, placer, region, i + 1)
    return labels, missing


def _table_labels(drawn: Drawing, placer: Placer, region: Rect, page: int) -> list[Label]:
    """The table's edges, centre line and base named on one tile, where there is room."""
    t, r, out = drawn.table, region, []
    grey = "0.25"
    lo_x, hi_x = max(r.x0, t.x0 + 2.0), min(r.x1, t.x1 - 2.0)
    lo_y, hi_y = max(r.y0, t.y0 + 2.0), min(r.y1, t.y1 - 2.0)

    def put(text: str, boxes: Iterable[Rect], rotation: int = 0, size: float = SMALL) -> None:
        got = placer.first(b for b in boxes if r.holds(b))
        if got is not None:
            out.append(Label((text,), size, got[0], rotation=rotation, color=grey, page=page))

    h = text_size(["x"], SMALL)[1]
    if r.y0 <= t.y0 <= r.y1:
        put(NEAR_EDGE, along(t.y0 + 1.6, lo_x, hi_x, text_width(NEAR_EDGE, SMALL), h, False))
    if r.y0 <= t.y1 <= r.y1:
        put(FAR_EDGE, along(t.y1 - 1.6, lo_x, hi_x, text_width(FAR_EDGE, SMALL), -h, False))
    if r.x0 <= t.x0 <= r.x1:
        w = text_width(LEFT_EDGE, SMALL)
        put(LEFT_EDGE, along(t.x0 + 1.6, lo_y, hi_y, w, h, True), rotation=90)
    if r.x0 <= t.x1 <= r.x1:
        w = text_width(RIGHT_EDGE, SMALL)
        put(RIGHT_EDGE, along(t.x1 - 1.6, lo_y, hi_y, w, -h, True), rotation=-90)
    if drawn.center_line is not None:
        (x, _), _ = drawn.center_line
        if r.x0 <= x <= r.x1:
            w = text_width(CENTER_LINE, SMALL)
            tops = np.arange(hi_y, lo_y + h, -4.0)
            put(CENTER_LINE, (Rect(x + 1.6, y - h, x + 1.6 + w, y) for y in tops))
    base = drawn.base
    if r.overlaps(base.drawing()):
        w, hb = text_size([base.text], NORMAL)
        put(base.text, around(base.drawing(), w, hb, RINGS[:6]), size=NORMAL)
    return out


def build_mat(
    scene: Scene,
    poses: Mapping[str, ObjectPose],
    candidates: Sequence[str],
    header: Header,
    paper: str = "a4",
) -> Mat:
    """The mat of ``scene`` with its objects at ``poses`` (every object, by name), the
    ``candidates`` highlighted, on pages of ``paper``.

    The pages carry every object's outline and arrows and every table marker (see
    :func:`tile`); when a label finds no room on them, the room right under its object is
    carried too and the pages are tiled again.
    """
    ws = scene.workspace
    (cx, cy), (tx, ty) = ws.table_center, ws.table_size
    width, height = ty * 1000.0, tx * 1000.0
    frame = SheetFrame(cx - tx / 2, cy + ty / 2)
    table = Rect(0.0, 0.0, width, height)
    center_line = None
    if cy - ty / 2 < 0 < cy + ty / 2:
        center_line = (frame.to_sheet(cx - tx / 2, 0.0), frame.to_sheet(cx + tx / 2, 0.0))
    prints = tuple(
        footprint(scene, n, p, frame, _role(scene, n, candidates)) for n, p in poses.items()
    )
    drawn = Drawing(
        table, center_line, _base_mark(frame, table), prints, table_markers(scene, frame)
    )
    contents = [Content(f.drawing()) for f in prints]
    contents += [Content(m.bounds(), whole=True) for m in drawn.markers]
    full = full_grid(paper, width, height)
    tiling = tile(paper, contents, table, full)
    labels, missing = _labels(drawn, tiling)
    for _ in range(3):
        if not missing:
            break
        contents += [Content(box, whole=True) for box in missing]
        tiling = tile(paper, contents, table, full)
        labels, missing = _labels(drawn, tiling)
    if missing:  # still no room: the labels go where a tile holds them, over what is there
        labels = _forced(drawn, tiling, labels)
    return Mat(
        header,
        frame,
        tiling,
        table,
        center_line,
        drawn.base,
        prints,
        drawn.markers,
        tuple(labels),
    )


def _forced(drawn: Drawing, tiling: Tiling, placed: list[Label]) -> list[Label]:
    """``placed`` and the object and marker labels it lacks, each on the first tile that
    holds it, whatever it covers."""
    have = {label.lines for label in placed}
    placer = Placer([p.tile.grown(-LABEL_INSET) for p in tiling.pages], [], 0.0)
    out = list(placed)
    for f in drawn.footprints:
        if f.text() not in have:
            w, h = text_size(f.text(), SMALL, f.role == "candidate")
            got = placer.first(around(f.drawing(), w, h))
            if got is not None:
                box, i = got
                bold = f.role == "candidate"
                out.append(
                    Label(f.text(), SMALL, box, bold=bold, leader=leader(f, box), page=i + 1)
                )
    for m in drawn.markers:
        if (m.caption(),) not in have:
            w, h = text_size([m.caption()], SMALL)
            got = placer.first(around(m.bounds(), w, h))
            if got is not None:
                out.append(Label((m.caption(),), SMALL, got[0], page=got[1] + 1))
    return out


def _role(scene: Scene, name: str, candidates: Sequence[str]) -> Role:
    if name in candidates:
        return "candidate"
    return "movable" if name in scene.movable else "fixed"


def page_label(mat: Mat, page: Page) -> str:
    """``page k of N``."""
    return f"page {page.number} of {len(mat.tiling.pages)}"


def table_edges(mat: Mat, page: Page) -> list[str]:
    """The table's edges that cross the page's tile: ``near``, ``far``, ``left``, ``right``."""
    t, tile = mat.table, page.tile
    across_x = tile.x0 < t.x1 and t.x0 < tile.x1
    across_y = tile.y0 < t.y1 and t.y0 < tile.y1
    edges = [
        ("near", across_x and tile.y0 <= t.y0 <= tile.y1),
        ("far", across_x and tile.y0 <= t.y1 <= tile.y1),
        ("left", across_y and tile.x0 <= t.x0 <= tile.x1),
        ("right", across_y and tile.x0 <= t.x1 <= tile.x1),
    ]
    return [name for name, crossing in edges if crossing]


def page_joins(mat: Mat, page: Page) -> str:
    """Which pages are taped to this one, and on which side; for a page that joins none,
    how to lay it."""
    joins = mat.tiling.neighbours(page)
    if joins:
        return "joins " + ", ".join(f"page {p.number} {side}" for side, p in joins)
    edges = table_edges(mat, page)
    if edges:
        return f"joins no other page: lay it on the table's {' and '.join(edges)} edge"
    return "joins no other page: lay it by the distances below"


def page_position(mat: Mat, page: Page) -> str:
    """Where the page's tile lies on the table: its cut line's lower-left corner from the
    table's left and near edges (to lay a page that joins no other)."""

    def off(d: float, edge: str) -> str:
        if d >= -0.5:
            return f"{d:.0f} mm from the table's {edge} edge"
        return f"{-d:.0f} mm outside its {edge} edge"

    dx, dy = page.tile.x0 - mat.table.x0, page.tile.y0 - mat.table.y0
    return f"cut line's lower-left corner: {off(dx, 'left')}, {off(dy, 'near')}"


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
