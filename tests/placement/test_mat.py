"""The sheet geometry of a placement mat (no drawing): the frame, the tiling, the shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from legws_daemon.placement.mat import (
    MARGIN,
    MARK_ARM,
    MARK_RADIUS,
    OVERLAP,
    Header,
    SheetFrame,
    build_mat,
    decision_mat,
    footprint,
    layout_mat,
    tile,
)
from legws_daemon.scene.catalog import load_scene
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


@pytest.mark.parametrize(
    ("paper", "pages", "rows", "columns", "landscape"),
    [("a4", 21, 3, 7, False), ("a3", 9, 3, 3, True)],
)
def test_the_tea_table_tiles_on_the_fewest_pages(
    tea: Scene, paper: str, pages: int, rows: int, columns: int, landscape: bool
) -> None:
    mat = build_mat(tea, tea.poses(), tea.goal_names, HEADER, paper)
    t = mat.tiling
    assert (len(t.pages), t.rows, t.columns, t.landscape) == (pages, rows, columns, landscape)
    other = tile(paper, 1100.0, 750.0)
    assert len(other.pages) == pages
    # the table (1100 x 750 mm on the sheet) lies inside the tiles, centred
    assert mat.table.width == pytest.approx(1100.0) and mat.table.height == pytest.approx(750.0)
    gw, gh = t.size
    assert mat.table.x0 >= 0 and mat.table.x1 <= gw and mat.table.y0 >= 0 and mat.table.y1 <= gh
    assert mat.table.x0 == pytest.approx(gw - mat.table.x1)


def test_pages_share_an_overlap_band_and_every_grid_corner_is_whole_on_its_pages(
    tea: Scene,
) -> None:
    t = build_mat(tea, tea.poses(), tea.goal_names, HEADER).tiling
    for page in t.pages:
        assert page.paper.width == pytest.approx(210.0) and page.paper.height == pytest.approx(297)
        assert page.window.x0 - page.paper.x0 == pytest.approx(MARGIN)
        assert page.window.width - page.tile.width == pytest.approx(OVERLAP)
        assert page.number == (page.row - 1) * t.columns + page.column
    first, right, below = t.pages[0], t.pages[1], t.pages[t.columns]
    assert first.window.x1 - right.window.x0 == pytest.approx(OVERLAP)
    assert first.window.y0 - below.window.y1 == pytest.approx(-OVERLAP)
    assert right.row == 1 and right.column == 2 and below.row == 2 and below.column == 1
    reach = max(MARK_RADIUS, MARK_ARM)
    for x, y in t.corners():
        showing = [p for p in t.pages if p.window.contains(x, y)]
        touching = [p for p in t.pages if p.tile.contains(x, y)]
        assert showing == touching  # every page whose tile has the corner prints it...
        for p in showing:  # ...whole
            w = p.window
            assert w.x0 <= x - reach and x + reach <= w.x1
            assert w.y0 <= y - reach and y + reach <= w.y1
    inner = (t.pitch[0], t.pitch[1])
    assert len([p for p in t.pages if p.window.contains(*inner)]) == 4


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


def test_a_table_marker_across_a_cut_is_reported(tea: Scene) -> None:
    spec = tea.spec.markers
    assert spec is not None
    moved = spec.model_copy(
        update={"table": [spec.table[0].model_copy(update={"y": 0.415})]}
    )  # sheet x = (0.55 - 0.415) m + 31 mm padding = 166 mm: the first cut on A4
    scene = Scene(tea.spec.model_copy(update={"markers": moved}), tea.source)
    ((marker, pages),) = build_mat(scene, scene.poses(), scene.goal_names, HEADER).split_markers()
    assert marker.id == 0 and [(p.row, p.column) for p in pages] == [(3, 1), (3, 2)]


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
