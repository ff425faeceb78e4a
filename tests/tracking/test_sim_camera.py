"""The MuJoCo stand-in's camera: markers textured the right way round, and the tracker
measures what was rendered (tea scene, 640 × 480, the arm at home)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import cv2
import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose
from legws_daemon.tracking.detect import MarkerDetector
from legws_daemon.tracking.markers import placed_corners
from legws_daemon.tracking.sim_camera import SimCamera
from legws_daemon.tracking.tracker import Tracker, TrackFrame

SCENE = load_scene("tea")


@pytest.fixture(scope="module")
def camera() -> Iterator[SimCamera]:
    with SimCamera(SCENE) as cam:
        yield cam


def track(camera: SimCamera, layout: dict[str, ObjectPose]) -> TrackFrame:
    image = camera.render({**SCENE.default_layout(), **layout})
    return Tracker(SCENE, camera.intrinsics).process(image)


def project(camera: SimCamera, points: np.ndarray) -> np.ndarray:
    rvec, tvec = camera.pose.to_opencv()
    k, d = camera.intrinsics.matrix, camera.intrinsics.distortion
    px, _ = cv2.projectPoints(points, rvec, tvec, k, d)
    return np.asarray(px).reshape(-1, 2)


def test_the_picture_is_bgr_at_the_requested_size(camera: SimCamera) -> None:
    image = camera.render()
    assert image.shape == (480, 640, 3) and image.dtype == np.uint8
    k = camera.intrinsics.matrix
    assert (k[0, 2], k[1, 2]) == (319.5, 239.5)
    # the biscotti is brown (R > G > B) 4 cm from its centre along its length
    p = SCENE.poses()["biscotti"]
    top = SCENE.workspace.table_height + 0.02
    u, v = np.round(project(camera, np.array([[p.x + 0.04, p.y, top]]))[0]).astype(int)
    b, g, r = (int(c) for c in image[v, u])
    assert r > g > b


def test_decals_show_each_marker_with_its_corners_in_order(camera: SimCamera) -> None:
    markers = Tracker(SCENE, camera.intrinsics).markers
    found = MarkerDetector(markers).detect(camera.render(SCENE.default_layout()))
    assert set(found.corners) == set(markers.table) | set(markers.objects)
    poses = SCENE.poses()
    for i, t in markers.table.items():
        expected = project(camera, t.corners(markers.table_height))
        np.testing.assert_allclose(found.corners[i], expected, atol=1.5)
    for i, o in markers.objects.items():
        p = poses[o.object]
        xy = placed_corners(o.size, p.x, p.y, p.yaw)
        expected = project(camera, np.column_stack([xy, np.full(4, o.height)]))
        np.testing.assert_allclose(found.corners[i], expected, atol=1.5)


def test_every_object_is_measured_within_5_mm_and_3_degrees(camera: SimCamera) -> None:
    layout = {
        "black_tea": ObjectPose(0.78, 0.3, 0.4),
        "green_tea": ObjectPose(0.6, 0.2, -1.2),
        "chamomile_tea": ObjectPose(0.75, 0.05, 2.8),
        "cookie": ObjectPose(0.62, -0.17, -2.5),
        "cracker": ObjectPose(0.5, -0.42, 1.0),
        "biscotti": ObjectPose(0.8, -0.35, 1.2),  # its 2.5 cm marker: 13 px, not seen everywhere
    }
    frame = track(camera, layout)
    assert frame.unseen == () and frame.warnings == () and frame.table_markers == 4
    truth = SCENE.poses(layout)
    for name, p in frame.poses.items():
        assert math.hypot(p.x - truth[name].x, p.y - truth[name].y) < 0.005, name
        assert abs(math.remainder(p.yaw - truth[name].yaw, 2 * math.pi)) < math.radians(3), name
    assert frame.camera is not None
    np.testing.assert_allclose(frame.camera.position, camera.pose.position, atol=0.01)


def test_an_object_moved_4_cm_left_is_measured_4_cm_left(camera: SimCamera) -> None:
    home = SCENE.poses()["green_tea"]
    before = track(camera, {}).poses["green_tea"]
    after = track(camera, {"green_tea": ObjectPose(home.x, home.y + 0.04, home.yaw)})
    moved = after.poses["green_tea"]
    assert moved.y - before.y == pytest.approx(0.04, abs=0.002)  # +y: the robot's left
    assert moved.x - before.x == pytest.approx(0.0, abs=0.002)


def test_an_object_off_the_table_is_unseen(camera: SimCamera) -> None:
    frame = track(camera, {"cookie": ObjectPose(2.5, 0.0, 0.0)})
    assert frame.unseen == ("cookie",) and "cookie" not in frame.poses
    assert len(frame.poses) == 7


def test_an_unknown_object_name_is_an_error(camera: SimCamera) -> None:
    with pytest.raises(InputError, match="unknown object 'teapot'"):
        camera.set_layout({"teapot": ObjectPose(0.5, 0.0, 0.0)})
