"""How exactly a placement mat's PDF draws the layout: the worst outline error, mm.

Builds the mats of ``legws placement`` (each decision of a plan folder, or the scene file's
layout), writes their PDFs in memory, reads the drawn geometry back with pdfplumber and,
for every object, compares the outline on the page whose tile holds its centre with the
layout: a box's four corners and side lengths, a circle's centre and radius. The issue asks
for 1 mm; the page offsets are undone with the pages' positions on the sheet.

Usage:
    python benchmarks/placement_accuracy.py [--scene tea] [--plan DIR] [--paper a4]
"""

from __future__ import annotations

import argparse
import io
import time
from pathlib import Path
from typing import Any

import numpy as np
import pdfplumber

from legws_daemon.placement.mat import Footprint, Mat, Page, decision_mat, layout_mat
from legws_daemon.placement.pdf import mat_pdf
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import Scene
from legws_daemon.task.plan_file import load_plan

PT = 25.4 / 72  # mm per PDF point


def _paths(page: Any) -> list[np.ndarray]:
    """The stroked paths of a PDF page, in the page's mm (origin at its bottom left)."""
    h = float(page.height)
    return [
        np.array([(x * PT, (h - top) * PT) for x, top in o["pts"]])
        for o in page.rects + page.curves
        if o["stroke"]
    ]


def outline_error(paths: list[np.ndarray], page: Page, f: Footprint, size: np.ndarray) -> float:
    """mm between the drawn outline nearest ``f`` and ``f`` (corners and sides, or centre
    and radius); ``size``: the object's extents along its x and y, mm."""
    origin = np.array([page.paper.x0, page.paper.y0])
    centre = np.array(f.center) - origin
    if f.shape == "circle":
        fits = [((p.min(0) + p.max(0)) / 2, (p.max(0) - p.min(0)) / 2) for p in paths]
        c, r = min(fits, key=lambda cr: float(np.linalg.norm(cr[0] - centre)))
        return float(max(np.linalg.norm(c - centre), *np.abs(r - size[0] / 2)))
    boxes = [b for b in (np.unique(p.round(6), axis=0) for p in paths) if len(b) == 4]
    found = min(boxes, key=lambda b: float(np.linalg.norm(b.mean(0) - centre)))
    corners = max(float(np.min(np.linalg.norm(found - e, axis=1))) for e in f.polygon - origin)
    ordered = found[np.argsort(np.arctan2(*(found - found.mean(0)).T[::-1]))]
    sides = np.sort(np.linalg.norm(np.roll(ordered, -1, axis=0) - ordered, axis=1))
    expected = np.sort(np.repeat(size, 2))
    return max(corners, float(np.max(np.abs(sides - expected))))


def worst_error(scene: Scene, mat: Mat) -> tuple[float, str, int]:
    """The largest outline error of a mat (mm), its object and the number of outlines."""
    with pdfplumber.open(io.BytesIO(mat_pdf(mat))) as pdf:
        worst, name = 0.0, ""
        for f in mat.footprints:
            spec = scene.objects[f.name]
            sx, sy, _ = extents(spec.shape, tuple(spec.size))
            page = mat.tiling.page_at(*f.center)
            paths = _paths(pdf.pages[page.number - 1])
            error = outline_error(paths, page, f, np.array([sx, sy]) * 1000)
            if error >= worst:
                worst, name = error, f.name
    return worst, name, len(mat.footprints)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="tea")
    ap.add_argument("--plan", type=Path, help="a plan folder from `legws plan --out DIR`")
    ap.add_argument("--paper", choices=["a4", "a3"], default="a4")
    args = ap.parse_args()
    scene = load_scene(args.scene)
    if args.plan is not None:
        plan = load_plan(args.plan / "plan.json", scene)
        mats = [(d.label, decision_mat(scene, d, args.paper)) for d in plan.decisions]
    else:
        mats = [("layout", layout_mat(scene, scene.default_layout(), "layout", args.paper))]
    overall, outlines, start = 0.0, 0, time.perf_counter()
    for label, mat in mats:
        error, name, count = worst_error(scene, mat)
        overall, outlines = max(overall, error), outlines + count
        print(f"{label}: {len(mat.tiling.pages)} pages, {count} outlines, worst {error:.1e} mm "
              f"({name})")  # fmt: skip
    seconds = time.perf_counter() - start
    print(f"worst outline error over {outlines} outlines: {overall:.1e} mm ({seconds:.1f} s)")


if __name__ == "__main__":
    main()
