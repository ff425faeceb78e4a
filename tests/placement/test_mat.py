"""The sheet geometry of a placement mat (no drawing): the frame, the pages, the shapes, the
labels."""

from __future__ import annotations

import math
import random
import re

import numpy as np
import pytest

from legws_daemon.placement.mat import (
    MARGIN,
    MARK_ARM,
    MARK_RADIUS,
    OVERLAP,
    Content,
    Header,
    Mat,
    Rect,
    SheetFrame,
    build_mat,
    decision_mat,
    footprint,
    layout_mat,
    obstacles,
    page_joins,
    page_label,
    page_position,
    table_edges,
    tile,
)
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.task.plan import PlannedDecision
from legws_daemon.tracking.markers import placed_corners

HEADER = Header("tea", "test", 0.5, (0.8, 2), 3, True)


@pytest.fixture(scope="module")
def tea() -> Scene:
    return load_scene("tea")


def test_the_sheet_is_the_table_turned_robot_at_the_bottom_never_mirrored() -> None:
    frame = SheetFrame(near_x=0.2, left_y=0.55)
    origin = np.array(frame.to_sheet(0.5, 0.1))
    forward = np.array(frame.to_sheet(0.6, 0.1)) - origin  # robot +x
    left = np.array(frame.to_sheet(0.5, 0.2)) - origin  # robot +y
    assert forward == pytest.approx([0.0, 100.0])  # up the sheet
    assert left == pytest.approx([-100.0, 0.0])  # to the sheet's left
    assert forward[0] * left[1] - forward[1] * left[0] > 0  # same handedness: a rotation
    assert frame.to_base(*frame.to_sheet(0.43, -0.27)) == pytest.approx((0.43, -0.27))
    assert SheetFrame.angle(0.0) == pytest.approx(math.pi / 2)  # heading +x points up


def _random_layouts(scene: Scene, count: int, seed: int) -> list[dict[str, ObjectPose]]:
    """``count`` layouts of ``scene`` meeting its constraints, every movable object at a
    random pose."""
    rng, ws = random.Random(seed), scene.workspace
    constraints = LayoutConstraints.of(scene)
    out: list[dict[str, ObjectPose]] = []
    while len(out) < count:
        poses = dict(scene.poses())
        for name in scene.movable:
            poses[name] = ObjectPose(
                rng.uniform(*ws.x_range), rng.uniform(*ws.y_range), rng.uniform(-math.pi, math.pi)
            )
        if not constraints.problems(poses):
            out.append(poses)
    return out


def _covered(tiles: list[Rect], box: Rect, step: float = 2.0) -> bool:
    """Whether every point of ``box`` (on a ``step`` mm grid, its edges included) lies on
    a tile."""
    xs = np.append(np.arange(box.x0, box.x1, step), box.x1)
    ys = np.append(np.arange(box.y0, box.y1, step), box.y1)
    grown = [t.grown(1e-6) for t in tiles]  # tiles meet to within float rounding
    return all(any(t.contains(x, y) for t in grown) for x in xs for y in ys)


def _check_tiling(mat: Mat) -> None:
    """The pages carry everything drawn and nothing else: every outline with its arrows
    and every table marker lies on tiles, a table marker on one; every tile carries some
    of them; no two tiles overlap; the pages are numbered in reading order."""
    t = mat.tiling
    tiles = [p.tile for p in t.pages]
    drawn = [f.drawing() for f in mat.footprints] + [m.bounds() for m in mat.markers]
    for box in drawn:
        assert _covered(tiles, box), box
    for m in mat.markers:
        assert any(tile.holds(m.bounds()) for tile in tiles), m.id
    for each in tiles:
        assert any(each.grown(-1e-6).overlaps(box) for box in drawn), each
    for i, a in enumerate(tiles):
        for b in tiles[i + 1 :]:
            assert not a.grown(-1e-6).overlaps(b), (a, b)
    assert [p.number for p in t.pages] == list(range(1, len(t.pages) + 1))
    tops = [(-round(p.tile.y1, 6), round(p.tile.x0, 6)) for p in t.pages]
    assert tops == sorted(tops)


@pytest.mark.parametrize(("paper", "most"), [("a4", 12), ("a3", 9)])
def test_only_the_parts_of_the_table_with_something_on_them_are_printed(
    tea: Scene, paper: str, most: int
) -> None:
    full = {"a4": 21, "a3": 9}[paper]  # a grid over the 1100 x 750 mm table
    counts = []
    for poses in [tea.poses(), *_random_layouts(tea, 12, seed=3)]:
        mat = build_mat(tea, poses, tea.goal_names, HEADER, paper)
        _check_tiling(mat)
        assert mat.tiling.full == full
        counts.append(len(mat.tiling.pages))
    assert max(counts) <= most, counts
    assert mat.table == Rect(0.0, 0.0, 1100.0, 750.0)  # the sheet's origin: left near corner


def test_the_tiler_keeps_a_whole_item_on_one_tile_and_needs_the_fewest_pages() -> None:
    # three small things in a row, 400 mm apart end to end: two landscape A4 tiles
    # (253 mm long) reach, three portrait ones (166 mm) would be needed
    row = [Content(Rect(x, 0.0, x + 10.0, 10.0)) for x in (0.0, 190.0, 390.0)]
    t = tile("a4", row)
    assert len(t.pages) == 2 and t.orientations == (0, 2)
    # a whole item a tile laid from its first neighbour would cut lands on one tile
    items = [Content(Rect(0.0, 0.0, 10.0, 10.0)), Content(Rect(200.0, 0.0, 290.0, 90.0), True)]
    t = tile("a4", items, within=Rect(-500.0, -500.0, 1000.0, 1000.0))
    assert any(p.tile.holds(items[1].box) for p in t.pages)
    assert len(t.pages) == 2
    # something larger than any tile lies across tiles that join
    big = tile("a4", [Content(Rect(0.0, 0.0, 300.0, 100.0))])
    assert len(big.pages) == 2
    ((side, _),) = big.neighbours(big.pages[0])
    assert side in ("right", "below")


def test_a_tile_that_would_hang_over_the_table_edge_slides_back_onto_it() -> None:
    table = Rect(0.0, 0.0, 1100.0, 750.0)
    near_right = [Content(Rect(950.0, 300.0, 1000.0, 350.0))]
    (page,) = tile("a4", near_right, within=table).pages
    assert table.holds(page.tile) and page.tile.holds(near_right[0].box)
    at_the_corner = [Content(Rect(1050.0, 700.0, 1100.0, 750.0))]
    (page,) = tile("a4", at_the_corner, within=table).pages
    assert (page.tile.x1, page.tile.y1) == pytest.approx((1100.0, 750.0))  # not past it


def test_pages_share_an_overlap_band_and_every_tile_corner_is_whole_on_its_pages(
    tea: Scene,
) -> None:
    mat = build_mat(tea, tea.poses(), tea.goal_names, HEADER)
    t = mat.tiling
    for page in t.pages:
        w, h = (297.0, 210.0) if page.landscape else (210.0, 297.0)
        assert page.paper.width == pytest.approx(w) and page.paper.height == pytest.approx(h)
        assert page.window.x0 - page.paper.x0 == pytest.approx(MARGIN)
        assert page.window.y0 - page.paper.y0 == pytest.approx(MARGIN)
        assert page.window.width - page.tile.width == pytest.approx(OVERLAP)
    reach = max(MARK_RADIUS, MARK_ARM)
    joined = 0
    for page in t.pages:
        for side, other in t.neighbours(page):
            joined += 1
            shared = [c for c in t.corners() if page.tile.contains(*c) and other.tile.contains(*c)]
            assert len(shared) >= 2, (page.number, side, other.number)  # two marks to align
            assert (side in ("left", "right")) == (
                abs(page.tile.x0 - other.tile.x1) < 1e-6 or abs(page.tile.x1 - other.tile.x0) < 1e-6
            )
    assert joined > 0
    for x, y in t.corners():
        showing = [p for p in t.pages if p.tile.contains(x, y)]
        assert showing
        for p in showing:  # whole on every page whose tile holds it
            w = p.window
            assert w.x0 <= x - reach and x + reach <= w.x1
            assert w.y0 <= y - reach and y + reach <= w.y1


def test_each_page_says_where_it_lies_on_the_table(tea: Scene) -> None:
    mat = build_mat(tea, tea.poses(), tea.goal_names, HEADER)
    for page in mat.tiling.pages:
        found = re.fullmatch(
            r"cut line's lower-left corner: (\d+) mm (from the table's|outside its) left "
            r"edge, (\d+) mm (from the table's|outside its) near edge",
            page_position(mat, page),
        )
        assert found is not None, page_position(mat, page)
        left = float(found[1]) * (-1 if found[2] == "outside its" else 1)
        near = float(found[3]) * (-1 if found[4] == "outside its" else 1)
        x, y = mat.frame.to_base(page.tile.x0, page.tile.y0)  # the cut line's corner
        ws = tea.workspace
        assert left == pytest.approx(
            (ws.table_center[1] + ws.table_size[1] / 2 - y) * 1000, abs=0.5
        )
        assert near == pytest.approx(
            (x - ws.table_center[0] + ws.table_size[0] / 2) * 1000, abs=0.5
        )
        assert page_label(mat, page) == f"page {page.number} of {len(mat.tiling.pages)}"
        joins = page_joins(mat, page)
        for side, other in mat.tiling.neighbours(page):
            assert f"page {other.number} {side}" in joins
        if not mat.tiling.neighbours(page):
            assert joins.startswith("joins no other page: lay it ")
    corner = mat.tiling.page_at(0.0, 0.0)  # the table's left near corner
    assert {"left", "near"} <= set(table_edges(mat, corner))


def test_every_label_lies_inside_one_tile_next_to_what_it_names_and_clear(tea: Scene) -> None:
    for poses in [tea.poses(), *_random_layouts(tea, 6, seed=5)]:
        mat = build_mat(tea, poses, tea.goal_names, HEADER)
        labels = mat.labels
        for f in mat.footprints:
            (label,) = [la for la in labels if la.lines == f.text()]
            assert label.bold == (f.role == "candidate")
            gap = label.box.distance(f.drawing())
            assert (label.leader is not None) == (gap > 4.0), (f.name, gap)
            assert gap <= 70.0
        for m in mat.markers:
            assert len([la for la in labels if la.lines == (m.caption(),)]) == 1
        blocked = obstacles(mat.drawing(), mat.tiling.corners())
        for i, label in enumerate(labels):
            page = mat.tiling.pages[label.page - 1]
            assert page.tile.grown(-1.5 + 1e-6).holds(label.box), label
            assert not any(label.box.overlaps(b) for b in blocked), label
            assert not any(label.box.overlaps(o.box) for o in labels[i + 1 :]), label


def test_a_rotated_box_keeps_its_size_and_centre_on_the_sheet(tea: Scene) -> None:
    frame = SheetFrame(0.2, 0.55)
    pose = ObjectPose(0.6, -0.1, 0.7)
    f = footprint(tea, "biscotti", pose, frame, "candidate")  # 0.10 x 0.03 m
    sides = np.linalg.norm(np.roll(f.polygon, -1, axis=0) - f.polygon, axis=1)
    assert sides == pytest.approx([100.0, 30.0, 100.0, 30.0])
    assert f.polygon.mean(axis=0) == pytest.approx(frame.to_sheet(0.6, -0.1))
    long_side = f.polygon[1] - f.polygon[0]  # along the object's x axis
    assert math.atan2(long_side[1], long_side[0]) == pytest.approx(SheetFrame.angle(0.7))
    cookie = footprint(tea, "cookie", pose, frame, "movable")
    assert (cookie.shape, cookie.radius) == ("circle", pytest.approx(35.0))
    tip = np.subtract(f.orientation.end, f.orientation.start)
    assert math.atan2(tip[1], tip[0]) == pytest.approx(SheetFrame.angle(0.7))


def _heading(a: object) -> np.ndarray:
    start, end = np.array(a.start), np.array(a.end)  # type: ignore[attr-defined]
    d = end - start
    return np.asarray(d / np.linalg.norm(d))


def test_grasp_arrows_show_the_grasp_the_scene_derives(tea: Scene) -> None:
    frame = SheetFrame(0.2, 0.55)
    yaw = 0.3
    x_axis = np.array([math.cos(SheetFrame.angle(yaw)), math.sin(SheetFrame.angle(yaw))])
    y_axis = np.array([-x_axis[1], x_axis[0]])
    # a top grasp of a box: two fingers closing along the object's y axis, from outside
    bag = footprint(tea, "black_tea", ObjectPose(0.7, 0.2, yaw), frame, "candidate")
    assert len(bag.grasp) == 2
    for a in bag.grasp:
        heading = _heading(a)
        assert abs(heading @ y_axis) == pytest.approx(1.0)
        to_centre = np.array(bag.center) - np.array(a.end)
        assert heading @ to_centre > 0  # pointing at the object
        assert np.linalg.norm(to_centre) > 55 / 2  # ending outside its face
    # a top grasp of a cylinder: any turn is the same grasp, nothing to show
    assert footprint(tea, "cookie", ObjectPose(0.7, 0.2, yaw), frame, "movable").grasp == ()
    # a side grasp: from the object's -x side, along +x, onto the face
    breakfast = load_scene("breakfast")
    box = footprint(breakfast, "cereal_box", ObjectPose(0.6, 0.0, yaw), frame, "candidate")
    (approach,) = box.grasp
    assert _heading(approach) @ x_axis == pytest.approx(1.0)
    face = np.array(box.center) - x_axis * 190 / 2
    assert np.linalg.norm(np.array(approach.end) - face) == pytest.approx(4.0, abs=1e-6)


def test_table_markers_are_placed_with_the_trackers_corner_convention(tea: Scene) -> None:
    mat = build_mat(tea, tea.poses(), tea.goal_names, HEADER)
    assert sorted(m.id for m in mat.markers) == [0, 1, 2, 3]
    spec = {m.id: m for m in tea.spec.markers.table}  # type: ignore[union-attr]
    for m in mat.markers:
        s = spec[m.id]
        expected = placed_corners(s.size, s.x, s.y, s.yaw)
        back = np.array([mat.frame.to_base(*c) for c in m.corners()])
        assert back == pytest.approx(expected, abs=1e-9)
        assert m.cells.shape == (6, 6) and m.cells[0].all() and m.cells[:, 0].all()
        assert len(m.black_cells()) == int(m.cells.sum())
    assert mat.split_markers() == []  # the tea table's markers lie inside tiles on A4


def test_a_table_marker_no_tile_holds_is_reported(tea: Scene) -> None:
    spec = tea.spec.markers
    assert spec is not None
    grown = spec.model_copy(
        update={"table": [spec.table[0].model_copy(update={"size": 0.13, "x": 0.3, "y": 0.45})]}
    )  # its white margin is 173 mm square: more than an A4 tile's 166 mm side
    scene = Scene(tea.spec.model_copy(update={"markers": grown}), tea.source)
    ((marker, pages),) = build_mat(scene, scene.poses(), scene.goal_names, HEADER).split_markers()
    assert marker.id == 0 and len(pages) >= 2
    assert all(p.tile.overlaps(marker.bounds()) for p in pages)
    assert build_mat(scene, scene.poses(), scene.goal_names, HEADER, "a3").split_markers() == []


def test_the_base_mark_says_how_far_the_base_is_from_the_near_edge(tea: Scene) -> None:
    mat = build_mat(tea, tea.poses(), tea.goal_names, HEADER)
    assert not mat.base.inside
    assert mat.base.text == "robot base centre 200 mm ↓"
    assert mat.base.at == pytest.approx((mat.table.x0 + 550.0, mat.table.y0))
    assert mat.center_line is not None
    assert mat.center_line[0] == pytest.approx(mat.base.at)


def test_headers_carry_the_decisions_certificates(tea: Scene) -> None:
    decision = PlannedDecision(
        label="choose_tea", stages=("choose_tea",), candidates=("black_tea", "green_tea"),
        actions={}, inference=True, optimised=(), layout=tea.default_layout(),
        certificate=0.123, certificate_start=0.1, feasible=False, image=None,
        note="no IK solution", commit_objective=0.75, commit_certified=1,
    )  # fmt: skip
    mat = decision_mat(tea, decision)
    first, second = mat.header.lines()
    assert "scene tea" in first and "decision choose_tea" in first
    assert second == "J = 0.123 · K = 0.750 (1/2 commit-certified) · NOT feasible · no IK solution"
    roles = {f.name: f.role for f in mat.footprints}
    assert roles["black_tea"] == "candidate" and roles["cookie"] == "movable"
    assert roles["cup"] == "fixed"
    single = layout_mat(tea, tea.default_layout(), "default")
    assert single.header.certificate is not None and single.header.feasible is True
    assert {f.name for f in single.footprints} == set(tea.objects)
