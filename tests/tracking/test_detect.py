"""Detection and the tracker's verdicts on pictures made of marker pictures: each marker's
picture (white margin included) is warped to where a synthetic camera sees it."""

from __future__ import annotations

import math
from functools import cache

import cv2
import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.tracking.camera import CameraPose, Intrinsics
from legws_daemon.tracking.detect import MarkerDetector
from legws_daemon.tracking.markers import (
    QUIET_CELLS,
    SceneMarkers,
    cells,
    marker_image,
    placed_corners,
    scene_markers,
)
from legws_daemon.tracking.tracker import Tracker

INTRINSICS = Intrinsics.pinhole(40.0, 1280, 960)  # the biscotti marker: 25 pixels wide
CAMERA = CameraPose.look_at((0.8, 0.0, 1.5), (0.575, 0.0, 0.0), up=(-1.0, 0.0, 0.0))
TABLE_GREY = 190


@cache
def tea() -> Scene:
    return load_scene("tea")


def project(points: np.ndarray) -> np.ndarray:
    rvec, tvec = CAMERA.to_opencv()
    px, _ = cv2.projectPoints(points, rvec, tvec, INTRINSICS.matrix, INTRINSICS.distortion)
    return np.asarray(px).reshape(-1, 2)


def paint(image: np.ndarray, markers: SceneMarkers, marker_id: int, x: float, y: float,
          yaw: float, size: float, z: float) -> np.ndarray:  # fmt: skip
    """Paste marker ``marker_id`` lying at ``(x, y, yaw)`` on the plane ``z``; returns the
    pixels of its corners (top-left, top-right, bottom-right, bottom-left)."""
    picture = marker_image(markers.dictionary, marker_id)
    n = cells(markers.dictionary)
    outer = size * (n + 2 * QUIET_CELLS) / n
    side = picture.shape[0]
    src = np.array([[0, 0], [side, 0], [side, side], [0, side]], dtype=np.float32) - 0.5
    dst = project(np.column_stack([placed_corners(outer, x, y, yaw), np.full(4, z)]))
    h = cv2.getPerspectiveTransform(src, dst.astype(np.float32))
    warped = cv2.warpPerspective(
        picture, h, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR
    )
    mask = cv2.warpPerspective(np.full_like(picture, 255), h, (image.shape[1], image.shape[0]))
    image[mask > 127] = warped[mask > 127]
    return project(np.column_stack([placed_corners(size, x, y, yaw), np.full(4, z)]))


def picture(*, table: bool = True, objects: bool = True,
            extra: tuple[tuple[int, float, float, float], ...] = ()) -> np.ndarray:  # fmt: skip
    """The tea scene's markers at its file poses (grey), plus ``extra`` object-sized markers
    ``(id, x, y, yaw)`` on the table."""
    scene = tea()
    m = scene_markers(scene)
    image = np.full((INTRINSICS.height, INTRINSICS.width), TABLE_GREY, dtype=np.uint8)
    if table:
        for t in m.table.values():
            paint(image, m, t.id, t.x, t.y, t.yaw, t.size, m.table_height)
    if objects:
        poses = scene.poses()
        for o in m.objects.values():
            p = poses[o.object]
            paint(image, m, o.id, p.x, p.y, p.yaw, o.size, m.table_height + o.height)
    for marker_id, x, y, yaw in extra:
        paint(image, m, marker_id, x, y, yaw, 0.04, m.table_height)
    return image


def test_corners_come_in_opencv_order_where_the_marker_lies() -> None:
    m = scene_markers(tea())
    image = np.full((INTRINSICS.height, INTRINSICS.width), TABLE_GREY, dtype=np.uint8)
    expected = paint(image, m, 10, 0.6, 0.1, 0.7, 0.05, 0.0)
    found = MarkerDetector(m).detect(image)
    assert set(found.corners) == {10} and found.duplicated == () and found.unknown == ()
    np.testing.assert_allclose(found.corners[10], expected, atol=1.0)  # a wrong order: ~30 px


def test_bgr_and_grey_pictures_give_the_same_corners() -> None:
    grey = picture()
    detector = MarkerDetector(scene_markers(tea()))
    a = detector.detect(grey).corners
    b = detector.detect(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)).corners
    assert a.keys() == b.keys() and all(np.array_equal(a[i], b[i]) for i in a)


def test_not_an_image_is_an_error() -> None:
    with pytest.raises(InputError, match="uint8"):
        MarkerDetector(scene_markers(tea())).detect(np.zeros((48, 64), dtype=np.float32))


def test_every_object_is_measured_from_a_clean_picture() -> None:
    scene = tea()
    frame = Tracker(scene, INTRINSICS).process(picture())
    assert frame.warnings == () and frame.unseen == () and frame.table_markers == 4
    truth = scene.poses()
    for name, p in frame.poses.items():
        assert math.hypot(p.x - truth[name].x, p.y - truth[name].y) < 0.002, name
        assert abs(math.remainder(p.yaw - truth[name].yaw, 2 * math.pi)) < math.radians(1)
    assert frame.camera is not None
    np.testing.assert_allclose(frame.camera.position, CAMERA.position, atol=0.01)


def test_an_unknown_marker_is_a_warning_only() -> None:
    frame = Tracker(tea(), INTRINSICS).process(picture(extra=((40, 0.5, -0.05, 0.3),)))
    assert frame.warnings == ("unknown marker id 40 seen",)
    assert frame.unseen == () and len(frame.poses) == 8


def test_a_marker_printed_twice_leaves_its_object_unseen() -> None:
    frame = Tracker(tea(), INTRINSICS).process(picture(extra=((11, 0.5, -0.05, 0.3),)))
    assert frame.unseen == ("green_tea",) and "green_tea" not in frame.poses
    assert frame.warnings == ("marker 11 seen twice: green_tea reported unseen",)
    assert len(frame.poses) == 7


def test_a_table_marker_printed_twice_is_left_out_of_the_camera_pose() -> None:
    frame = Tracker(tea(), INTRINSICS).process(picture(extra=((2, 0.5, -0.05, 0.3),)))
    assert frame.warnings == ("table marker 2 seen twice: not used for the camera pose",)
    assert frame.table_markers == 3 and len(frame.poses) == 8


def test_without_a_table_marker_no_object_has_a_pose() -> None:
    frame = Tracker(tea(), INTRINSICS).process(picture(table=False))
    assert frame.poses == {} and frame.camera is None and frame.table_markers == 0
    assert frame.unseen == tuple(tea().objects)
    assert frame.warnings == ("no table marker visible: no object poses in this frame",)


def test_one_table_marker_is_enough() -> None:
    scene = tea()
    image = picture(table=False)
    m = scene_markers(scene)
    t = m.table[2]
    paint(image, m, t.id, t.x, t.y, t.yaw, t.size, m.table_height)
    frame = Tracker(scene, INTRINSICS).process(image)
    assert frame.table_markers == 1 and frame.unseen == ()
    cup = frame.poses["cup"]
    assert math.hypot(cup.x - 0.45, cup.y - 0.3) < 0.02  # less precise than with four


def test_a_marker_of_the_wrong_size_is_not_used() -> None:
    scene = tea()
    m = scene_markers(scene)
    image = picture(objects=False)
    paint(image, m, 13, 0.65, -0.2, 0.0, 0.06, m.table_height + m.objects[13].height)
    frame = Tracker(scene, INTRINSICS).process(image)
    assert "cookie" in frame.unseen and "cookie" not in frame.poses
    assert frame.warnings[0].startswith("marker 13 (cookie) does not fit its 0.04 m square")
