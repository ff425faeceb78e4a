"""The PDF of a placement mat read back: its outlines, marks, labels and markers in mm; its
preview's labels.

Outlines, registration marks and scale bars come from the PDF's drawn geometry
(pdfplumber); the fiducial markers from its pages rasterised at 300 dpi (pypdfium2) and
found by OpenCV's ArUco detector, as the camera tracker finds them.
"""

from __future__ import annotations

import io
from typing import Any

import cv2
import numpy as np
import pdfplumber
import pypdfium2
import pytest
from PIL import Image

from legws_daemon.placement.mat import MARK_RADIUS, Footprint, Mat, Page, Rect, layout_mat
from legws_daemon.placement.pdf import (
    PREVIEW_WIDTH,
    marker_sheet,
    markers_pdf,
    mat_pdf,
    mat_png,
    preview_labels,
)
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.tracking.markers import dictionary, placed_corners
from tests.placement.readback import assert_legible_preview, carried, cut_line, cut_texts, texts

#: Millimetres per PDF point.
PT = 25.4 / 72
#: The issue's measure: a printed outline's size and position agree with the layout to 1 mm.
TOLERANCE = 1.0
DPI = 300

#: A layout with turned objects (and one across a cut between pages on A3).
LAYOUT = {
    "black_tea": ObjectPose(0.72, 0.26, 0.6),
    "green_tea": ObjectPose(0.55, 0.1, -1.1),
    "biscotti": ObjectPose(0.77, -0.27, 2.5),
    "cookie": ObjectPose(0.5, -0.15, 0.3),
}


@pytest.fixture(scope="module")
def scene() -> Scene:
    return load_scene("tea")


@pytest.fixture(scope="module")
def mat(scene: Scene) -> Mat:
    return layout_mat(scene, LAYOUT, "test layout", "a3")


@pytest.fixture(scope="module")
def pdf(mat: Mat) -> Any:
    with pdfplumber.open(io.BytesIO(mat_pdf(mat))) as doc:
        yield doc


def _points(page: Any, obj: dict[str, Any]) -> np.ndarray:
    """A drawn path's points in the page's millimetres (origin at its bottom left)."""
    return np.array([(x * PT, (float(page.height) - top) * PT) for x, top in obj["pts"]])


def _stroked(page: Any) -> list[np.ndarray]:
    return [_points(page, o) for o in page.rects + page.curves if o["stroke"]]


def outline_error(page: Any, page_geom: Page, f: Footprint, ext: tuple[float, float]) -> float:
    """How far (mm) the outline drawn on ``page`` is from ``f``'s layout pose and size:
    the nearest stroked path's corners (a box) or centre and radius (a circle)."""
    origin = np.array([page_geom.paper.x0, page_geom.paper.y0])
    centre = np.array(f.center) - origin
    paths = _stroked(page)
    if f.shape == "circle":
        fits = [((p.min(0) + p.max(0)) / 2, (p.max(0) - p.min(0)) / 2) for p in paths]
        c, r = min(fits, key=lambda cr: float(np.linalg.norm(cr[0] - centre)))
        return float(max(np.linalg.norm(c - centre), *abs(r - ext[0] / 2)))
    boxes = [np.unique(p.round(6), axis=0) for p in paths]
    boxes = [b for b in boxes if len(b) == 4]
    found = min(boxes, key=lambda b: float(np.linalg.norm(b.mean(0) - centre)))
    expected = f.polygon - origin
    corner = max(float(np.min(np.linalg.norm(found - e, axis=1))) for e in expected)
    ordered = found[np.argsort(np.arctan2(*(found - found.mean(0)).T[::-1]))]
    sides = np.sort(np.linalg.norm(np.roll(ordered, -1, axis=0) - ordered, axis=1))
    size = float(np.max(abs(sides - np.sort([ext[0], ext[0], ext[1], ext[1]]))))
    return max(corner, size)


def test_every_outline_is_at_its_layout_pose_and_size_within_1_mm(
    scene: Scene, mat: Mat, pdf: Any
) -> None:
    worst = 0.0
    for f in mat.footprints:
        spec = scene.objects[f.name]
        sx, sy, _ = extents(spec.shape, tuple(spec.size))
        page = mat.tiling.page_at(*f.center)
        error = outline_error(pdf.pages[page.number - 1], page, f, (sx * 1000, sy * 1000))
        assert error <= TOLERANCE, (f.name, error)
        worst = max(worst, error)
    assert len(mat.footprints) == len(scene.objects)
    assert worst < 0.01  # the PDF holds the geometry exactly (to its printing precision)


def test_pages_have_the_papers_size_labels_and_a_100_mm_scale_bar(mat: Mat, pdf: Any) -> None:
    t = mat.tiling
    assert len(pdf.pages) == len(t.pages) < t.full == 9
    for page, geom in zip(pdf.pages, t.pages, strict=True):
        size = (420.0, 297.0) if geom.landscape else (297.0, 420.0)
        assert (page.width * PT, page.height * PT) == pytest.approx(size, abs=0.01)
        text = page.extract_text()
        assert f"page {geom.number} of {len(t.pages)}" in text
        assert "scene tea · test layout" in text and "J = " in text
        assert "cut line's lower-left corner: " in text
        bars = [ln for ln in page.lines if abs((ln["x1"] - ln["x0"]) * PT - 100.0) < 0.01]
        assert bars, geom.number
        tile = cut_line(page)
        origin = (geom.paper.x0, geom.paper.y0)
        assert (tile.x0 + origin[0], tile.y0 + origin[1]) == pytest.approx(
            (geom.tile.x0, geom.tile.y0), abs=0.01
        )
        assert (tile.width, tile.height) == pytest.approx(
            (geom.tile.width, geom.tile.height), abs=0.01
        )


def test_no_text_is_cut_and_every_page_carries_an_object(scene: Scene, mat: Mat) -> None:
    colours = [o.color for o in scene.spec.objects]
    names = [o.label or o.name for o in scene.spec.objects]
    names += [f"table marker {m.id} ({m.size:g} mm)" for m in mat.markers]
    a4 = layout_mat(scene, LAYOUT, "test layout", "a4")
    for each in (mat, a4):
        with pdfplumber.open(io.BytesIO(mat_pdf(each))) as doc:
            assert len(doc.pages) == len(each.tiling.pages)
            for number, page in enumerate(doc.pages, 1):
                assert cut_texts(page) == [], number
                assert carried(page, colours, names), number


def test_labels_are_drawn_where_they_were_placed(mat: Mat, pdf: Any) -> None:
    """The font's metrics the labels were placed with are the PDF's (to 0.3 mm)."""
    checked = 0
    for label in mat.labels:
        geom = mat.tiling.pages[label.page - 1]
        found = [b for t, b in texts(pdf.pages[label.page - 1]) if t in label.lines]
        assert len(found) == len(label.lines), label
        drawn = found[0]
        for b in found[1:]:
            drawn = drawn.union(b)
        placed = label.box
        origin = (geom.paper.x0, geom.paper.y0)
        moved = Rect(
            placed.x0 - origin[0],
            placed.y0 - origin[1],
            placed.x1 - origin[0],
            placed.y1 - origin[1],
        )
        for side, want in zip(
            (drawn.x0, drawn.y0, drawn.x1, drawn.y1),
            (moved.x0, moved.y0, moved.x1, moved.y1),
            strict=True,
        ):
            assert side == pytest.approx(want, abs=0.3), (label.lines, drawn, moved)
        checked += 1
    assert checked >= len(mat.footprints) + len(mat.markers)


def _mark_centres(page: Any, geom: Page) -> list[np.ndarray]:
    """Sheet points (mm) of the registration marks' circles on ``page``."""
    origin = np.array([geom.paper.x0, geom.paper.y0])
    out = []
    for o in page.curves:
        p = _points(page, o)
        size = p.max(0) - p.min(0)
        if o["stroke"] and np.allclose(size, 2 * MARK_RADIUS, atol=0.01):
            out.append((p.max(0) + p.min(0)) / 2 + origin)
    return out


def test_registration_marks_sit_at_the_same_table_point_on_neighbouring_pages(
    mat: Mat, pdf: Any
) -> None:
    t = mat.tiling
    marks = {g.number: _mark_centres(pdf.pages[g.number - 1], g) for g in t.pages}
    shared = 0
    for corner in t.corners():
        pages = [g for g in t.pages if g.tile.contains(*corner)]
        for g in pages:
            distance = min(float(np.linalg.norm(m - corner)) for m in marks[g.number])
            assert distance < 0.01, (corner, g.number)
        shared += len(pages) > 1
    assert shared >= 2  # the pages that join line up on two marks or more
    for g in t.pages:  # each page: the tile corners it holds, no other mark
        held = [c for c in t.corners() if g.tile.contains(*c)]
        assert len(marks[g.number]) == len(held) >= 4


def _render(data: bytes, index: int) -> tuple[np.ndarray, float]:
    """Page ``index`` of a PDF as a grey picture at :data:`DPI`, and its height in mm."""
    doc = pypdfium2.PdfDocument(data)
    page = doc[index]
    grey = np.asarray(page.render(scale=DPI / 72, grayscale=True).to_pil().convert("L"))
    height = page.get_height() * PT
    doc.close()
    return grey, height


def _detect(grey: np.ndarray) -> dict[int, np.ndarray]:
    detector = cv2.aruco.ArucoDetector(dictionary("4X4_50"), cv2.aruco.DetectorParameters())
    corners, ids, _ = detector.detectMarkers(grey)
    return {} if ids is None else {int(i): c[0] for i, c in zip(ids.ravel(), corners, strict=True)}


def _page_mm(pixels: np.ndarray, height: float) -> np.ndarray:
    mm = 25.4 / DPI
    return np.column_stack([(pixels[:, 0] + 0.5) * mm, height - (pixels[:, 1] + 0.5) * mm])


@pytest.mark.slow  # rasterises four A3 pages at 300 dpi: ~4 s
def test_table_markers_are_found_by_opencv_where_the_scene_puts_them(
    scene: Scene, mat: Mat
) -> None:
    data = mat_pdf(mat)
    table = {m.id: m for m in scene.spec.markers.table}  # type: ignore[union-attr]
    for marker in mat.markers:
        page = mat.tiling.page_at(*marker.center)
        grey, height = _render(data, page.number - 1)
        found = _detect(grey)
        assert marker.id in found, (marker.id, sorted(found))
        sheet = _page_mm(found[marker.id], height) + np.array([page.paper.x0, page.paper.y0])
        base = np.array([mat.frame.to_base(*p) for p in sheet])
        s = table[marker.id]
        expected = placed_corners(s.size, s.x, s.y, s.yaw)  # top-left, top-right, ...
        error = np.linalg.norm(base - expected, axis=1) * 1000
        assert error.max() <= TOLERANCE, (marker.id, error)


def test_the_marker_sheet_holds_each_objects_marker_at_true_size(scene: Scene) -> None:
    items = marker_sheet(scene)
    assert [i.marker.id for i in items] == [10, 11, 12, 13, 14, 15, 16, 17]
    assert items[0].lines[0] == "black tea bag (black_tea)"
    data = markers_pdf(scene)
    assert data is not None
    grey, height = _render(data, 0)
    found = _detect(grey)
    assert sorted(found) == [i.marker.id for i in items]
    for item in items:
        corners = _page_mm(found[item.marker.id], height)
        sides = np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)
        assert sides == pytest.approx([item.marker.size] * 4, abs=0.5)
        assert corners == pytest.approx(item.marker.corners(), abs=0.5)  # upright, in place
    assert markers_pdf(load_scene("feeding")) is None  # no markers, no sheet


def test_the_preview_is_a_png_of_the_table_and_its_printed_pages(mat: Mat) -> None:
    with Image.open(io.BytesIO(mat_png(mat))) as img:
        assert img.format == "PNG"
        assert img.width == PREVIEW_WIDTH
        content = mat.table.union(mat.tiling.bounds())
        assert img.height > PREVIEW_WIDTH * content.height / (content.width + 30)
    texts = [label.text for label in preview_labels(mat)]
    assert [str(p.number) for p in mat.tiling.pages] == texts[: len(mat.tiling.pages)]
    for f in mat.footprints:
        assert "\n".join(f.text()) in texts


def test_the_previews_labels_are_legible_and_apart(mat: Mat) -> None:
    assert_legible_preview(mat_png(mat), preview_labels(mat))
