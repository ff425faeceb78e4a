"""Drawing a placement mat: its PDF pages at true scale, a PNG preview, the marker sheet.

A page is a matplotlib figure of the paper's size in inches whose one axes fills it with
limits in sheet millimetres (:mod:`legws_daemon.placement.mat`), so one millimetre of the
table is one millimetre of paper: the PDF's geometry is the table's, within the precision
the PDF writes coordinates with. Printed at 100 % ("actual size", no "fit to page"), the
100 mm scale bar on every page measures 100 mm.

The preview draws the same shapes over the whole sheet at a reduced scale, with the page
grid. The marker sheet (``markers.pdf``) holds each object's fiducial marker at true size
with its name, to cut out and stick centred on the object's top face.

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

from legws_daemon.formats.files import write_atomic
from legws_daemon.placement.mat import (
    MARGIN,
    MARK_ARM,
    MARK_RADIUS,
    OVERLAP,
    SCALE_BAR,
    Arrow,
    Footprint,
    Mat,
    Page,
    PrintedMarker,
    Rect,
    marker_cells,
    page_label,
    paper_size,
)
from legws_daemon.scene.scene import Scene
from legws_daemon.tracking.markers import scene_markers

MM_PER_INCH = 25.4
#: Text sizes, points (6 pt is 2.1 mm: legible, small enough for a 55 mm tea bag).
SMALL = 6.0
NORMAL = 7.5
#: Line widths, points.
THIN = 0.4
OUTLINE = {"candidate": 1.3, "movable": 0.8, "fixed": 0.8}
#: How far a label or an arrow may reach beyond an outline, mm (for which page draws it).
REACH = 60.0
#: Width of the preview picture, pixels.
PREVIEW_WIDTH = 1600
#: What the shapes of a mat mean, on every page.
LEGEND = (
    "bold: candidate · thin: other object · dashed: fixed · magenta: grasp (side: "
    "approach, top: fingers closing) · grey arrow: object x axis"
)
#: Fonts embedded as TrueType (42), so the text of the PDF can be read back and searched.
_RC: Any = {"pdf.fonttype": 42, "font.family": "DejaVu Sans", "path.simplify": False}


@contextmanager
def _style() -> Iterator[None]:
    with mpl.rc_context(_RC):
        yield


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
        grown = Rect(bounds.x0 - reach, bounds.y0 - reach, bounds.x1 + reach, bounds.y1 + reach)
        return grown.overlaps(self.window)

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

    def text(self, x: float, y: float, s: str, **style: Any) -> None:
        """Text anchored at ``(x, y)``, left out when it cannot reach the window."""
        if not self.shows(Rect(x, y, x, y), REACH):
            return
        artist = self.ax.text(x, y, s, **style)
        if self._clip is not None:
            artist.set_clip_path(self._clip)

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
    style = {"fontsize": SMALL, "color": "0.25"}
    c.text(t.x0 + 4, t.y0 + 2, "table edge, robot side (near)", va="bottom", **style)
    c.text(t.x0 + 4, t.y1 - 2, "table edge, far side", va="top", **style)
    c.text(
        t.x0 + 2,
        t.y0 + t.height / 2,
        "robot's left (+y)",
        rotation=90,
        va="center",
        ha="left",
        **style,
    )
    c.text(
        t.x1 - 2,
        t.y0 + t.height / 2,
        "robot's right (−y)",
        rotation=-90,
        va="center",
        ha="right",
        **style,
    )
    if mat.center_line is not None:
        c.line(mat.center_line, color="0.45", linewidth=THIN, linestyle="-.")
        (x, _), (_, y1) = mat.center_line
        c.text(x + 1.5, y1 - 2, "robot y = 0", va="top", **style)
    _draw_base(c, mat)


def _draw_base(c: _Canvas, mat: Mat) -> None:
    x, y = mat.base.at
    if mat.base.inside:
        c.line([(x - 8, y), (x + 8, y)], color="black", linewidth=0.8)
        c.line([(x, y - 8), (x, y + 8)], color="black", linewidth=0.8)
        c.add(Circle((x, y), 5, fill=False, linewidth=0.8, color="black"))
    else:
        c.arrow(Arrow((x, y + 22), (x, y + 0.5)), width=0.6, head=3)
    c.text(x + 2, y + 8, mat.base.text, fontsize=NORMAL, va="bottom")


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
    c.arrow(f.orientation, width=0.35, head=2.0, color="0.2")
    for a in f.grasp:
        c.arrow(a, width=0.9, head=3.5, color="#c0007a")
    lines = [f.label + (" (fixed)" if f.role == "fixed" else "")]
    if f.marker is not None:
        lines.append(f"marker {f.marker}")
    weight = "bold" if f.role == "candidate" else "normal"
    c.text(*f.text_at, "\n".join(lines), fontsize=SMALL, ha="center", va="top", fontweight=weight)


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
    b = m.bounds()
    c.text(
        (b.x0 + b.x1) / 2,
        b.y0 - 1,
        f"table marker {m.id} ({m.size:g} mm)",
        fontsize=SMALL,
        ha="center",
        va="top",
    )


def _registration_mark(c: _Canvas, x: float, y: float) -> None:
    c.add(Circle((x, y), MARK_RADIUS, fill=False, linewidth=THIN, color="black"))
    c.line([(x - MARK_ARM, y), (x + MARK_ARM, y)], color="black", linewidth=THIN)
    c.line([(x, y - MARK_ARM), (x, y + MARK_ARM)], color="black", linewidth=THIN)


def _draw_sheet(c: _Canvas, mat: Mat) -> None:
    """What the mat shows, on the part of the sheet the canvas shows."""
    if c.shows(mat.table, REACH):
        _draw_table(c, mat)
    for m in mat.markers:
        if c.shows(m.bounds(), 10.0):
            _draw_marker(c, m)
    for f in mat.footprints:
        if c.shows(f.bounds(), REACH):
            _draw_footprint(c, f)


# --- pages --------------------------------------------------------------------------------


def _scale_bar(ax: Axes, x0: float, y: float) -> None:
    """A 100 mm bar with 10 mm ticks from ``(x0, y)``, mm: to check the print's scale."""
    ax.plot([x0, x0 + SCALE_BAR], [y, y], color="black", linewidth=0.8)
    xs = np.repeat(x0 + np.arange(0.0, SCALE_BAR + 1, 10.0), 3)
    ys = np.tile([y, y + 0.8, np.nan], 11)
    ys[1::15] = y + 1.6  # longer ticks at 0, 50 and 100 mm
    ax.plot(xs, ys, color="black", linewidth=THIN)
    ax.text(
        x0 + SCALE_BAR / 2,
        y + 2.0,
        "100 mm when printed at 100 % (actual size)",
        fontsize=SMALL,
        va="bottom",
        ha="center",
    )


def _draw_furniture(ax: Axes, mat: Mat, page: Page) -> None:
    """Header, page label, scale bar (in the margin), cut lines and registration marks."""
    p, w = page.paper, page.window
    first, second = mat.header.lines()
    ax.text(w.x0, p.y1 - 3.5, first, fontsize=NORMAL, va="top", fontweight="bold")
    ax.text(w.x0, p.y1 - 6.6, second, fontsize=SMALL, va="top")
    ax.text(w.x0, p.y1 - 9.2, LEGEND, fontsize=SMALL - 1, va="top", color="0.3")
    ax.text(
        w.x0, p.y0 + 6.5, page_label(mat, page), fontsize=NORMAL, va="center", fontweight="bold"
    )
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
        if w.contains(x, y):
            _registration_mark(c, x, y)


def _page_figure(mat: Mat, page: Page) -> Figure:
    pw, ph = paper_size(mat.tiling.paper, mat.tiling.landscape)
    fig, ax = _figure(pw, ph, page.paper)
    _draw_sheet(_Canvas(ax, page.window), mat)
    _draw_furniture(ax, mat, page)
    return fig


def mat_pdf(mat: Mat) -> bytes:
    """The mat's pages as one PDF, at true scale."""
    buffer = io.BytesIO()
    with _style(), PdfPages(buffer, metadata={"Creator": "legws placement"}) as pdf:
        for page in mat.tiling.pages:
            pdf.savefig(_page_figure(mat, page))
    return buffer.getvalue()


def mat_png(mat: Mat, width: int = PREVIEW_WIDTH) -> bytes:
    """The whole mat at a reduced scale with its page grid, as a PNG."""
    gw, gh = mat.tiling.size
    view = Rect(-OVERLAP, -OVERLAP, gw + OVERLAP, gh + OVERLAP + 30)
    with _style():
        fig, ax = _figure(view.width, view.height, view)
        _draw_sheet(_Canvas(ax, None), mat)
        for page in mat.tiling.pages:
            t = page.tile
            ax.add_patch(
                Rectangle(
                    (t.x0, t.y0), t.width, t.height, fill=False, linewidth=0.6, edgecolor="#2060c0"
                )
            )
            ax.text(
                t.x0 + 3,
                t.y1 - 3,
                str(page.number),
                fontsize=14,
                color="#2060c0",
                va="top",
                alpha=0.7,
            )
        first, second = mat.header.lines()
        ax.text(0, gh + OVERLAP + 26, first, fontsize=20, va="top", fontweight="bold")
        ax.text(0, gh + OVERLAP + 12, second, fontsize=16, va="top")
        FigureCanvasAgg(fig)
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=width / (view.width / MM_PER_INCH), facecolor="white")
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
    ax.text(x, bottom - 1.5, "\n".join(item.lines), fontsize=SMALL, ha="center", va="top")


def _marker_page(scene: Scene, items: list[MarkerLabel], paper: str) -> Figure:
    pw, ph = paper_size(paper, False)
    fig, ax = _figure(pw, ph, Rect(0.0, 0.0, pw, ph))
    ax.text(
        MARGIN,
        ph - MARGIN,
        f"legws object markers · scene {scene.name}",
        fontsize=NORMAL,
        va="top",
        fontweight="bold",
    )
    ax.text(
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
