"""Drawing a placement mat: its PDF pages at true scale, a PNG preview, the marker sheet.

A page is a matplotlib figure of the paper's size in inches whose one axes fills it with
limits in sheet millimetres (:mod:`legws_daemon.placement.mat`), so one millimetre of the
table is one millimetre of paper: the PDF's geometry is the table's, within the precision
the PDF writes coordinates with. Printed at 100 % ("actual size", no "fit to page"), the
100 mm scale bar on every page measures 100 mm. The shapes are clipped to the page's
printed part; a label is drawn only on the pages that show it whole (it lies inside one
tile: :class:`~legws_daemon.placement.mat.Label`).

The preview draws the same shapes over the table at a reduced scale, with the printed
pages and their numbers; its text is sized in the PNG's pixels (:data:`PREVIEW_TEXT_PX`)
and its labels are placed again at that size, clear of each other and of the outlines
(:func:`preview_labels`). The marker sheet (``markers.pdf``) holds each object's fiducial
marker at true size with its name, to cut out and stick centred on the object's top face.

Only matplotlib's Agg and PDF back ends are used (no GUI); files are written through
:func:`~legws_daemon.formats.files.write_atomic`.
"""

from __future__ import annotations

import io
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib as mpl
import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.patches import Circle, FancyArrow, PathPatch, Polygon, Rectangle
from matplotlib.path import Path as MplPath
from matplotlib.text import Text

from legws_daemon.formats.files import write_atomic
from legws_daemon.placement.mat import (
    FONT,
    GRASP_HEAD,
    MARGIN,
    MARK_ARM,
    MARK_RADIUS,
    NORMAL,
    ORIENTATION_HEAD,
    SCALE_BAR,
    SMALL,
    Arrow,
    Footprint,
    Label,
    Mat,
    Page,
    Placer,
    PrintedMarker,
    Rect,
    around,
    leader,
    marker_cells,
    obstacles,
    page_joins,
    page_label,
    page_position,
    paper_size,
    text_size,
    text_width,
)
from legws_daemon.scene.scene import Scene
from legws_daemon.tracking.markers import scene_markers

MM_PER_INCH = 25.4
#: Line widths, points.
THIN = 0.4
OUTLINE = {"candidate": 1.3, "movable": 0.8, "fixed": 0.8}
#: Width of the preview picture, pixels.
PREVIEW_WIDTH = 1600
#: Text sizes of the preview, pixels of the PNG: 13 px is a 10 pt font on a 96 dpi screen
#: (its capitals 9.5 px tall); the page numbers and the title are larger.
PREVIEW_TEXT_PX = 13.0
PREVIEW_TITLE_PX = 17.0
#: Room around the table and the pages on the preview, mm of the sheet.
PREVIEW_BORDER = 15.0
#: What the shapes of a mat mean, on every page.
LEGEND = (
    "bold: candidate · thin: other object · dashed: fixed · magenta: grasp (side: "
    "approach, top: fingers closing) · grey arrow: object x axis"
)
#: Text drawn letter by letter, no ligatures (a PDF's "fi" glyph would not read back as
#: "f", "i": not searchable).
_PLAIN: Any = {"fontfeatures": ("-liga",)}
#: Fonts embedded as TrueType (42), so the text of the PDF can be read back and searched.
_RC: Any = {"pdf.fonttype": 42, "font.family": FONT, "path.simplify": False}


@contextmanager
def _style() -> Iterator[None]:
    with mpl.rc_context(_RC):
        yield


def _text(ax: Axes, x: float, y: float, s: str, **style: Any) -> Text:
    """A text of the axes, drawn without ligatures (:data:`_PLAIN`)."""
    return ax.text(x, y, s, **_PLAIN, **style)


def _figure(width_mm: float, height_mm: float, view: Rect) -> tuple[Figure, Axes]:
    """A figure ``width_mm`` x ``height_mm`` whose axes fill it and show ``view`` (mm)."""
    fig = Figure(figsize=(width_mm / MM_PER_INCH, height_mm / MM_PER_INCH))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    ax.set_xlim(view.x0, view.x1)
    ax.set_ylim(view.y0, view.y1)
    return fig, ax


class _Canvas:
    """Adds artists to an axes, clipped to a window of the sheet (a page's printed part)."""

    def __init__(self, ax: Axes, window: Rect | None) -> None:
        self.ax = ax
        self.window = window
        self._clip = (
            None
            if window is None
            else Rectangle(
                (window.x0, window.y0), window.width, window.height, transform=ax.transData
            )
        )

    def shows(self, bounds: Rect, reach: float = 0.0) -> bool:
        """Whether something within ``bounds`` (and ``reach`` around) is on this canvas."""
        if self.window is None:
            return True
        return bounds.grown(reach).overlaps(self.window)

    def add(self, artist: Any) -> None:
        if isinstance(artist, PathPatch | Polygon | Circle | Rectangle | FancyArrow):
            self.ax.add_patch(artist)
        else:
            self.ax.add_artist(artist)
        if self._clip is not None:
            artist.set_clip_path(self._clip)

    def line(self, points: Sequence[tuple[float, float]], **style: Any) -> None:
        xs, ys = zip(*points, strict=True)
        (artist,) = self.ax.plot(xs, ys, **style)
        if self._clip is not None:
            artist.set_clip_path(self._clip)

    def label(self, label: Label, background: bool = False) -> list[Text]:
        """Draw ``label`` when the canvas shows it whole (never cut by its edge); with
        ``background``, on a white box."""
        if self.window is not None and not self.window.holds(label.box):
            return []
        if label.leader is not None:
            self.line(label.leader, color="0.35", linewidth=THIN)
        if background:
            b = label.box.grown(0.6)
            self.add(
                Rectangle(
                    (b.x0, b.y0), b.width, b.height, facecolor="white", edgecolor="none", alpha=0.85
                )
            )
        out = []
        for text, (x, y) in zip(label.lines, label.baselines(), strict=True):
            out.append(
                _text(
                    self.ax,
                    x,
                    y,
                    text,
                    fontsize=label.size,
                    fontweight="bold" if label.bold else "normal",
                    color=label.color,
                    ha="center",
                    va="baseline",
                    rotation=label.rotation,
                    rotation_mode="anchor",
                )
            )
        return out

    def arrow(self, a: Arrow, width: float = 0.5, head: float = 2.5, color: str = "black") -> None:
        (x0, y0), (x1, y1) = a.start, a.end
        self.add(
            FancyArrow(
                x0,
                y0,
                x1 - x0,
                y1 - y0,
                width=width,
                head_width=head,
                head_length=head,
                length_includes_head=True,
                color=color,
                linewidth=0,
            )
        )


# --- the shapes of a mat ------------------------------------------------------------------


def _draw_table(c: _Canvas, mat: Mat) -> None:
    t = mat.table
    c.add(Rectangle((t.x0, t.y0), t.width, t.height, fill=False, linewidth=1.6, color="black"))
    if mat.center_line is not None:
        c.line(mat.center_line, color="0.45", linewidth=THIN, linestyle="-.")
    x, y = mat.base.at
    if mat.base.inside:
        c.line([(x - 8, y), (x + 8, y)], color="black", linewidth=0.8)
        c.line([(x, y - 8), (x, y + 8)], color="black", linewidth=0.8)
        c.add(Circle((x, y), 5, fill=False, linewidth=0.8, color="black"))
    else:
        c.arrow(Arrow((x, y + 22), (x, y + 0.5)), width=0.6, head=3)


def _draw_footprint(c: _Canvas, f: Footprint) -> None:
    fill = (*f.color, 0.3 if f.role == "candidate" else 0.12)
    edge = "black" if f.role == "candidate" else "0.3"
    style = {
        "facecolor": fill,
        "edgecolor": edge,
        "linewidth": OUTLINE[f.role],
        "linestyle": "--" if f.role == "fixed" else "-",
    }
    if f.shape == "circle":
        c.add(Circle(f.center, f.radius, **style))
    else:
        c.add(Polygon(f.polygon, closed=True, **style))
    c.arrow(f.orientation, width=0.35, head=2 * ORIENTATION_HEAD, color="0.2")
    for a in f.grasp:
        c.arrow(a, width=0.9, head=2 * GRASP_HEAD, color="#c0007a")


def marker_patches(m: PrintedMarker) -> tuple[Polygon, PathPatch]:
    """A marker's white margin and its black cells, as one path (no seams between cells
    when rasterised: the cells are filled together)."""
    quiet = Polygon(m.quiet_zone(), closed=True, facecolor="white", edgecolor="none")
    squares = m.black_cells()
    vertices = np.concatenate([np.vstack([s, s[:1]]) for s in squares])
    codes = [MplPath.MOVETO, MplPath.LINETO, MplPath.LINETO, MplPath.LINETO, MplPath.CLOSEPOLY]
    path = MplPath(vertices, codes * len(squares))
    return quiet, PathPatch(path, facecolor="black", edgecolor="none", linewidth=0)


def _draw_marker(c: _Canvas, m: PrintedMarker) -> None:
    quiet, cells = marker_patches(m)
    c.add(quiet)
    c.add(cells)


def _registration_mark(c: _Canvas, x: float, y: float) -> None:
    c.add(Circle((x, y), MARK_RADIUS, fill=False, linewidth=THIN, color="black"))
    c.line([(x - MARK_ARM, y), (x + MARK_ARM, y)], color="black", linewidth=THIN)
    c.line([(x, y - MARK_ARM), (x, y + MARK_ARM)], color="black", linewidth=THIN)


def _draw_shapes(c: _Canvas, mat: Mat) -> None:
    """The table, markers and objects, on the part of the sheet the canvas shows."""
    if c.shows(mat.table, 30.0):
        _draw_table(c, mat)
    for m in mat.markers:
        if c.shows(m.bounds()):
            _draw_marker(c, m)
    for f in mat.footprints:
        if c.shows(f.drawing()):
            _draw_footprint(c, f)


# --- pages --------------------------------------------------------------------------------


def _scale_bar(ax: Axes, x0: float, y: float) -> None:
    """A 100 mm bar with 10 mm ticks from ``(x0, y)``, mm: to check the print's scale."""
    ax.plot([x0, x0 + SCALE_BAR], [y, y], color="black", linewidth=0.8)
    xs = np.repeat(x0 + np.arange(0.0, SCALE_BAR + 1, 10.0), 3)
    ys = np.tile([y, y + 0.8, np.nan], 11)
    ys[1::15] = y + 1.6  # longer ticks at 0, 50 and 100 mm
    ax.plot(xs, ys, color="black", linewidth=THIN)
    _text(
        ax,
        x0 + SCALE_BAR / 2,
        y + 2.0,
        "100 mm when printed at 100 % (actual size)",
        fontsize=SMALL,
        va="bottom",
        ha="center",
    )


def _fitting(text: str, size: float, room: float, bold: bool = False) -> float:
    """``size``, or smaller (not under 4 pt) so that ``text`` fits in ``room`` mm."""
    width = text_width(text, size, bold)
    return size if width <= room else max(4.0, size * room / width)


def _draw_furniture(ax: Axes, mat: Mat, page: Page) -> None:
    """Header, page label and position, scale bar (in the margin), cut line and the
    registration marks on the tile's corners."""
    p, w = page.paper, page.window
    first, second = mat.header.lines()
    room = w.width
    _text(
        ax,
        w.x0,
        p.y1 - 4.3,
        first,
        fontsize=_fitting(first, NORMAL, room, True),
        va="top",
        fontweight="bold",
    )
    _text(ax, w.x0, p.y1 - 7.3, second, fontsize=_fitting(second, SMALL, room), va="top")
    _text(
        ax,
        w.x0,
        p.y1 - 9.8,
        LEGEND,
        fontsize=_fitting(LEGEND, SMALL - 1, room),
        va="top",
        color="0.3",
    )
    room = w.width - SCALE_BAR - 4.0  # left of the scale bar
    label = page_label(mat, page)
    _text(ax, w.x0, p.y0 + 9.0, label, fontsize=NORMAL, va="center", fontweight="bold")
    rest = room - text_width(label, NORMAL, True) - 2.0
    joins = page_joins(mat, page)
    _text(
        ax,
        w.x0 + room - rest,
        p.y0 + 9.0,
        joins,
        fontsize=_fitting(joins, SMALL, rest),
        va="center",
    )
    where = page_position(mat, page)
    _text(ax, w.x0, p.y0 + 5.6, where, fontsize=_fitting(where, SMALL, room), va="center")
    _scale_bar(ax, w.x1 - SCALE_BAR, p.y0 + 5.5)
    t = page.tile
    cut = Rectangle(
        (t.x0, t.y0),
        t.width,
        t.height,
        fill=False,
        linewidth=THIN,
        linestyle=(0, (4, 3)),
        edgecolor="0.35",
    )
    ax.add_patch(cut)
    c = _Canvas(ax, w)
    for x, y in mat.tiling.corners():
        if t.contains(x, y):
            _registration_mark(c, x, y)


def _page_figure(mat: Mat, page: Page) -> Figure:
    pw, ph = paper_size(mat.tiling.paper, page.landscape)
    fig, ax = _figure(pw, ph, page.paper)
    c = _Canvas(ax, page.window)
    _draw_shapes(c, mat)
    for label in mat.labels:
        c.label(label)
    _draw_furniture(ax, mat, page)
    return fig


def mat_pdf(mat: Mat) -> bytes:
    """The mat's pages as one PDF, at true scale."""
    buffer = io.BytesIO()
    with _style(), PdfPages(buffer, metadata={"Creator": "legws placement"}) as pdf:
        for page in mat.tiling.pages:
            pdf.savefig(_page_figure(mat, page))
    return buffer.getvalue()


# --- the preview --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PreviewLabel:
    """A text of the preview as drawn: its lines, font size and box in the PNG's pixels.

    Attributes:
        text: its lines, joined by newlines.
        px: font size, pixels.
        box: ``(left, top, right, bottom)`` pixels of the PNG (top row 0): where its
            characters are drawn (as the renderer lays them out).
    """

    text: str
    px: float
    box: tuple[float, float, float, float]


@dataclass(frozen=True)
class _Preview:
    figure: Figure
    dpi: float
    texts: list[tuple[list[Text], float]]


def _preview(mat: Mat, width: int) -> _Preview:
    """The preview's figure: the table, the printed pages (numbered), the objects and
    markers, every label at :data:`PREVIEW_TEXT_PX` and placed for that size."""
    content = mat.table.union(mat.tiling.bounds()).grown(PREVIEW_BORDER)
    scale = width / content.width  # pixels per mm
    pt = 72.0 / MM_PER_INCH / scale  # points per pixel: mm per pixel in points
    header = (PREVIEW_TITLE_PX * 1.3 + PREVIEW_TEXT_PX * 1.3 * 2 + 14) / scale
    view = Rect(content.x0, content.y0, content.x1, content.y1 + header)
    dpi = scale * MM_PER_INCH
    fig, ax = _figure(view.width, view.height, view)
    fig.set_dpi(dpi)
    c = _Canvas(ax, None)
    texts: list[tuple[list[Text], float]] = []
    # the printed pages, their numbers in their top-left corners
    numbers: list[Label] = []
    for page in mat.tiling.pages:
        t = page.tile
        ax.add_patch(
            Rectangle(
                (t.x0, t.y0), t.width, t.height, facecolor="#2060c0", alpha=0.06, edgecolor="none"
            )
        )
        ax.add_patch(
            Rectangle(
                (t.x0, t.y0), t.width, t.height, fill=False, linewidth=1.0, edgecolor="#2060c0"
            )
        )
        w, h = text_size([str(page.number)], PREVIEW_TITLE_PX * pt, True)
        box = Rect(t.x0 + 4 / scale, t.y1 - 4 / scale - h, t.x0 + 4 / scale + w, t.y1 - 4 / scale)
        numbers.append(
            Label((str(page.number),), PREVIEW_TITLE_PX * pt, box, bold=True, color="#2060c0")
        )
    _draw_shapes(c, mat)
    for label in numbers:
        texts.append((c.label(label, background=True), PREVIEW_TITLE_PX))
    for label in _preview_placed(mat, content, numbers, PREVIEW_TEXT_PX * pt, scale):
        texts.append((c.label(label, background=True), PREVIEW_TEXT_PX))
    first, second = mat.header.lines()
    n = len(mat.tiling.pages)
    legend = (
        f"blue: the {n} printed {mat.tiling.paper.upper()} pages, numbered as printed "
        f"(a full grid over the table: {mat.tiling.full}) · robot at the bottom · bold: "
        "candidate · dashed: fixed · magenta: grasp"
    )
    top = view.y1 - 6 / scale
    for text, px, bold in (
        (first, PREVIEW_TITLE_PX, True),
        (second, PREVIEW_TEXT_PX, False),
        (legend, PREVIEW_TEXT_PX, False),
    ):
        artist = _text(
            ax,
            content.x0 + 6 / scale,
            top,
            text,
            fontsize=px * pt,
            va="top",
            fontweight="bold" if bold else "normal",
        )
        texts.append(([artist], px))
        top -= px * 1.3 / scale
    return _Preview(fig, dpi, texts)


def _preview_placed(
    mat: Mat, content: Rect, numbers: list[Label], size: float, scale: float
) -> list[Label]:
    """The preview's labels: each object's and table marker's, the base's, at ``size`` pt
    (sheet mm at the preview's scale), clear of each other and of what is drawn."""
    blocked = obstacles(mat.drawing(), []) + [n.box.grown(2 / scale) for n in numbers]
    placer = Placer([content.grown(-4 / scale)], blocked, gap=3 / scale)
    rings = tuple(g / scale for g in (2, 5, 9, 14, 20, 28, 38, 50, 64, 80, 100, 125))
    out: list[Label] = []
    order = {"candidate": 0, "movable": 1, "fixed": 2}
    for f in sorted(mat.footprints, key=lambda f: order[f.role]):
        lines, bold = f.text(), f.role == "candidate"
        w, h = text_size(lines, size, bold)
        got = placer.first(around(f.drawing(), w, h, rings))
        if got is not None:
            out.append(Label(lines, size, got[0], bold=bold, leader=leader(f, got[0])))
    for m in mat.markers:
        text = f"table marker {m.id}"
        w, h = text_size([text], size)
        got = placer.first(around(m.bounds(), w, h, rings))
        if got is not None:
            out.append(Label((text,), size, got[0]))
    w, h = text_size([mat.base.text], size)
    got = placer.first(around(mat.base.drawing(), w, h, rings))
    if got is not None:
        out.append(Label((mat.base.text,), size, got[0], color="0.25"))
    return out


def preview_labels(mat: Mat, width: int = PREVIEW_WIDTH) -> list[PreviewLabel]:
    """Every text of the preview (:func:`mat_png`) as the renderer lays it out."""
    with _style():
        preview = _preview(mat, width)
        FigureCanvasAgg(preview.figure)  # the extents as the Agg renderer lays them out
        height = preview.figure.bbox.height
        out = []
        for artists, px in preview.texts:
            boxes = [a.get_window_extent() for a in artists]
            left, right = min(b.x0 for b in boxes), max(b.x1 for b in boxes)
            low, high = min(b.y0 for b in boxes), max(b.y1 for b in boxes)
            text = "\n".join(a.get_text() for a in artists)
            out.append(PreviewLabel(text, px, (left, height - high, right, height - low)))
    return out


def mat_png(mat: Mat, width: int = PREVIEW_WIDTH) -> bytes:
    """The table at a reduced scale with the printed pages, as a PNG ``width`` wide."""
    with _style():
        preview = _preview(mat, width)
        FigureCanvasAgg(preview.figure)
        buffer = io.BytesIO()
        preview.figure.savefig(buffer, format="png", dpi=preview.dpi, facecolor="white")
    return buffer.getvalue()


def write_mat(mat: Mat, folder: Path, stem: str) -> list[Path]:
    """Write ``stem.pdf`` (the pages) and ``stem.png`` (the preview) into ``folder``."""
    return [
        write_atomic(folder / f"{stem}.pdf", mat_pdf(mat)),
        write_atomic(folder / f"{stem}.png", mat_png(mat)),
    ]


# --- the marker sheet ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MarkerLabel:
    """An object's marker on the marker sheet: the marker (page mm) and its caption."""

    marker: PrintedMarker
    page: int
    lines: tuple[str, ...]


#: Room under a marker for its caption, and between markers, mm.
CAPTION = 14.0
GAP = 8.0


def marker_sheet(scene: Scene, paper: str = "a4") -> list[MarkerLabel]:
    """Each object's marker at true size, upright, packed row by row on pages of
    ``paper`` (portrait); empty when no object carries a marker."""
    if scene.spec.markers is None:
        return []
    markers = scene_markers(scene)
    pw, ph = paper_size(paper, False)
    top = ph - MARGIN - 14.0  # under the page's title
    out: list[MarkerLabel] = []
    x, y, row_height, page = MARGIN, top, 0.0, 1
    for m in sorted(markers.objects.values(), key=lambda m: list(scene.objects).index(m.object)):
        cells = marker_cells(markers.dictionary, m.id)
        size = m.size * 1000.0
        quiet = size * (cells.shape[0] + 2) / cells.shape[0]
        width = max(quiet, 46.0)
        if x + width > pw - MARGIN:
            x, y, row_height = MARGIN, y - row_height - GAP, 0.0
        if y - quiet - CAPTION < MARGIN + 12.0:  # above the scale bar
            x, y, row_height, page = MARGIN, top, 0.0, page + 1
        center = (x + width / 2, y - quiet / 2)
        spec = scene.objects[m.object]
        lines = (
            f"{spec.label or m.object} ({m.object})",
            f"marker {m.id} · {size:g} mm · its x axis →",
        )
        out.append(MarkerLabel(PrintedMarker(m.id, size, center, 0.0, cells), page, lines))
        x += width + GAP
        row_height = max(row_height, quiet + CAPTION)
    return out


def _draw_marker_label(ax: Axes, item: MarkerLabel) -> None:
    quiet, cells = marker_patches(item.marker)
    ax.add_patch(quiet)
    ax.add_patch(cells)
    q = item.marker.quiet_zone()
    ax.add_patch(
        Polygon(q, closed=True, fill=False, linewidth=THIN, linestyle=(0, (3, 2)), edgecolor="0.4")
    )
    x, bottom = item.marker.center[0], float(q[:, 1].min())
    _text(ax, x, bottom - 1.5, "\n".join(item.lines), fontsize=SMALL, ha="center", va="top")


def _marker_page(scene: Scene, items: list[MarkerLabel], paper: str) -> Figure:
    pw, ph = paper_size(paper, False)
    fig, ax = _figure(pw, ph, Rect(0.0, 0.0, pw, ph))
    _text(
        ax,
        MARGIN,
        ph - MARGIN,
        f"legws object markers · scene {scene.name}",
        fontsize=NORMAL,
        va="top",
        fontweight="bold",
    )
    _text(
        ax,
        MARGIN,
        ph - MARGIN - 4.5,
        "Print at 100 %. Cut along the dashed squares; stick each marker centred on its "
        "object's top face, its x axis (the arrow) along the object's x axis.",
        fontsize=SMALL,
        va="top",
    )
    for item in items:
        _draw_marker_label(ax, item)
    _scale_bar(ax, pw - MARGIN - SCALE_BAR, MARGIN - 6.5)
    return fig


def markers_pdf(scene: Scene, paper: str = "a4") -> bytes | None:
    """The marker sheet of ``scene`` as a PDF (``None``: no object carries a marker)."""
    items = marker_sheet(scene, paper)
    if not items:
        return None
    buffer = io.BytesIO()
    with _style(), PdfPages(buffer, metadata={"Creator": "legws placement"}) as pdf:
        for number in range(1, items[-1].page + 1):
            pdf.savefig(_marker_page(scene, [i for i in items if i.page == number], paper))
    return buffer.getvalue()
