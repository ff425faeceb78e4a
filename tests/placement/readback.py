"""A placement mat read back: a PDF page's cut line, texts and what it carries (pdfplumber);
whether the preview's labels can be read (the PNG's pixels).

Only the PDF is read: the tile is the page's dashed cut line, a text is a run of touching
characters as the PDF draws them, an object's outline is a path filled in its scene
colour, a table marker's cells are black squares. Millimetres of the page, origin at its
bottom left.

The preview's criterion: every text is drawn at :data:`LEGIBLE_PX` or more (a 10 pt font
on a 96 dpi screen), its characters at least :data:`LEGIBLE_INK` pixels tall in the PNG
and across most of its box, and no two texts' boxes overlap.
"""

from __future__ import annotations

import io
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from PIL import Image

from legws_daemon.placement.mat import MARGIN, OVERLAP, Rect
from legws_daemon.placement.pdf import PreviewLabel

#: Millimetres per PDF point.
PT = 25.4 / 72
#: How close two characters' boxes are when they belong to one text, points.
TOUCH = 0.6
#: The preview's texts: font size, pixels; how tall their characters are drawn, pixels
#: (a 13 px font's capitals and ascenders are 9.5 px); how much of a text's box they span
#: (of three characters or more).
LEGIBLE_PX = 13.0
LEGIBLE_INK = 9
LEGIBLE_SPAN = 0.7
#: No text closer to the paper's edge than this, mm (most printers leave 4-5 mm blank).
PRINTABLE = 4.0


def box(page: Any, obj: dict[str, Any]) -> Rect:
    """An object's bounding box in the page's millimetres."""
    h = float(page.height)
    return Rect(obj["x0"] * PT, (h - obj["bottom"]) * PT, obj["x1"] * PT, (h - obj["top"]) * PT)


def cut_line(page: Any) -> Rect:
    """The page's tile: its dashed, stroked rectangle, the paper inside its margin and half
    the overlap band (a fixed box's dashed outline is another)."""
    inset = MARGIN + OVERLAP / 2
    paper = Rect(0.0, 0.0, float(page.width) * PT, float(page.height) * PT)
    expected = paper.grown(-inset)
    (found,) = [
        b
        for b in (box(page, r) for r in page.rects if r["stroke"] and r.get("dash"))
        if expected.grown(0.01).holds(b) and b.grown(0.01).holds(expected)
    ]
    return found


def texts(page: Any) -> list[tuple[str, Rect]]:
    """Each run of touching characters of one font and direction, in the order the PDF
    draws them, with its box."""
    out: list[tuple[str, Rect]] = []
    text, last, font = "", None, None
    for ch in page.chars:
        b = box(page, ch)
        style = (ch["fontname"].split("+")[-1], ch["upright"])  # a font's subsets as one
        if last is not None and style == font and b.distance(last) <= TOUCH * PT:
            text, last = text + ch["text"], last.union(b)
            continue
        if last is not None:
            out.append((text, last))
        text, last, font = ch["text"], b, style
    if last is not None:
        out.append((text, last))
    return [(t.strip(), b) for t, b in out if t.strip()]


def cut_texts(page: Any) -> list[tuple[str, Rect]]:
    """The texts a cut goes through, or that the printed part's edge cuts off: every text
    lies inside the tile, wholly in the overlap band around it, or in the top or bottom
    margin within the printable part of the paper."""
    tile = cut_line(page)
    window = tile.grown(OVERLAP / 2)
    paper = Rect(0.0, 0.0, float(page.width) * PT, float(page.height) * PT)
    printable = paper.grown(-PRINTABLE)
    bad = []
    for text, b in texts(page):
        in_margin = b.y0 >= window.y1 or b.y1 <= window.y0
        if in_margin:
            if not printable.holds(b):
                bad.append((text, b))
        elif not window.holds(b) or (tile.overlaps(b) and not tile.holds(b)):
            bad.append((text, b))
    return bad


def _grey(colour: Any) -> tuple[float, ...]:
    """A PDF colour as RGB (pdfplumber gives a grey as one number)."""
    if isinstance(colour, int | float):
        return (float(colour),) * 3
    values = tuple(float(c) for c in colour)
    return values * 3 if len(values) == 1 else values


def carried(
    page: Any, colours: Iterable[tuple[float, float, float]], labels: Iterable[str]
) -> list[str]:
    """What of an object the page's tile carries: outlines filled in one of ``colours``,
    table markers' black cells (filled squares of 5 mm or more), texts among ``labels``."""
    tile = cut_line(page).grown(-0.01)
    wanted = [tuple(round(c, 3) for c in colour) for colour in colours]
    found = []
    for obj in page.rects + page.curves:
        if not obj["fill"] or not tile.overlaps(box(page, obj)):
            continue
        colour = tuple(round(c, 3) for c in _grey(obj["non_stroking_color"]))
        b = box(page, obj)
        if colour in wanted:
            found.append(f"outline {colour}")
        elif colour == (0.0, 0.0, 0.0) and min(b.width, b.height) >= 5.0:
            found.append("table marker cells")
    names = set(labels)
    found += [f"label {t}" for t, b in texts(page) if t in names and tile.overlaps(b)]
    return found


def assert_legible_preview(png: bytes, labels: Sequence[PreviewLabel]) -> None:
    """The preview's texts can be read: each at :data:`LEGIBLE_PX` or more, drawn in the
    PNG inside the picture (its characters :data:`LEGIBLE_INK` pixels tall or more, across
    most of its box), no two overlapping."""
    with Image.open(io.BytesIO(png)) as img:
        rgb = np.asarray(img.convert("RGB")).astype(int)
    height, width, _ = rgb.shape
    ink = rgb.min(axis=2) < 150  # black, grey or blue text on its white box
    assert labels
    for label in labels:
        left, top, right, bottom = label.box
        assert label.px >= LEGIBLE_PX, label
        assert left >= 0 and right <= width and top >= 0 and bottom <= height, label
        patch = ink[int(top) : int(np.ceil(bottom)), int(left) : int(np.ceil(right))]
        rows, columns = np.nonzero(patch.any(axis=1))[0], np.nonzero(patch.any(axis=0))[0]
        assert len(rows) and rows[-1] - rows[0] + 1 >= LEGIBLE_INK, label
        if len(label.text) >= 3:  # (a "1" is narrower than its box)
            assert columns[-1] - columns[0] + 1 >= LEGIBLE_SPAN * (right - left), label
    for i, a in enumerate(labels):
        for b in labels[i + 1 :]:
            apart = a.box[2] <= b.box[0] or b.box[2] <= a.box[0]
            apart = apart or a.box[3] <= b.box[1] or b.box[3] <= a.box[1]
            assert apart, (a, b)
