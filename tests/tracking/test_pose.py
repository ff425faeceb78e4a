"""The pose math on synthetic cameras: corners projected with OpenCV come back as the
camera pose and the objects' planar poses they were made from."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.tracking.camera import CameraPose, Intrinsics
from legws_daemon.tracking.markers import placed_corners
from legws_daemon.tracking.pose import fit_square, marker_pose, plane_points, solve_camera

TABLE = [(0.245, 0.51), (0.245, -0.51), (0.905, 0.51), (0.905, -0.51)]
DISTORTED = Intrinsics(
    np.array([[610.0, 0.0, 322.0], [0.0, 605.0, 236.0], [0.0, 0.0, 1.0]]),
    np.array([-0.12, 0.05, 0.001, -0.0005, -0.01]),
    640,
    480,
)


def project(points: np.ndarray, camera: CameraPose, intrinsics: Intrinsics) -> np.ndarray:
    rvec, tvec = camera.to_opencv()
    px, _ = cv2.projectPoints(points, rvec, tvec, intrinsics.matrix, intrinsics.distortion)
    return np.asarray(px).reshape(-1, 2)


def table_points(z: float = 0.0, size: float = 0.07) -> np.ndarray:
    xy = np.concatenate([placed_corners(size, x, y, 0.0) for x, y in TABLE])
    return np.column_stack([xy, np.full(len(xy), z)])


def yaw_gap(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


def test_pinhole_intrinsics_follow_opencv_pixel_centres() -> None:
    k = Intrinsics.pinhole(60.0, 640, 480).matrix
    assert k[0, 2] == 319.5 and k[1, 2] == 239.5
    assert k[1, 1] == pytest.approx(240.0 / math.tan(math.radians(30.0)))


@pytest.mark.parametrize(
    ("matrix", "distortion", "size"),
    [(np.eye(2), np.zeros(5), (640, 480)), (np.eye(3), np.zeros(4), (640, 480)),
     (np.eye(3), np.zeros(5), (0, 480))],
)  # fmt: skip
def test_bad_intrinsics_are_one_line_errors(
    matrix: np.ndarray, distortion: np.ndarray, size: tuple[int, int]
) -> None:
    with pytest.raises(InputError):
        Intrinsics(matrix, distortion, *size)


def test_camera_pose_round_trips_through_opencv() -> None:
    pose = CameraPose.look_at((1.3, 0.2, 1.4), (0.5, 0.0, 0.0))
    again = CameraPose.from_opencv(*pose.to_opencv())
    np.testing.assert_allclose(again.rotation, pose.rotation, atol=1e-12)
    np.testing.assert_allclose(again.position, pose.position, atol=1e-12)
    # the optical axis points at the target, image y points down
    assert pose.rotation[:, 2] @ (np.array([0.5, 0.0, 0.0]) - pose.position) > 0
    assert pose.rotation[2, 1] < 0


def test_solve_camera_recovers_the_pose_from_table_corners() -> None:
    truth = CameraPose.look_at((1.3, 0.0, 1.4), (0.575, 0.0, 0.0))
    pts = table_points()
    fit = solve_camera(project(pts, truth, DISTORTED), pts, DISTORTED)
    np.testing.assert_allclose(fit.pose.position, truth.position, atol=1e-6)
    np.testing.assert_allclose(fit.pose.rotation, truth.rotation, atol=1e-7)
    assert fit.rms < 1e-6


def test_solve_camera_needs_four_points() -> None:
    with pytest.raises(InputError, match="at least 4"):
        solve_camera(np.zeros((3, 2)), np.zeros((3, 3)), DISTORTED)


def test_plane_points_meet_the_plane_exactly() -> None:
    camera = CameraPose.look_at((1.3, 0.0, 1.4), (0.575, 0.0, 0.0))
    pts = table_points(z=0.09)
    back = plane_points(project(pts, camera, DISTORTED), DISTORTED, camera, 0.09)
    np.testing.assert_allclose(back, pts, atol=1e-7)


def test_a_plane_behind_the_camera_is_an_error() -> None:
    camera = CameraPose.look_at((1.3, 0.0, 1.4), (0.575, 0.0, 0.0))
    with pytest.raises(InputError, match="behind the camera"):
        plane_points([[320.0, 240.0]], DISTORTED, camera, 2.0)


def test_fit_square_is_exact_and_measures_a_wrong_size() -> None:
    corners = placed_corners(0.04, 0.6, -0.2, 2.5)
    fit = fit_square(corners, 0.04)
    assert (fit.pose.x, fit.pose.y) == pytest.approx((0.6, -0.2), abs=1e-12)
    assert yaw_gap(fit.pose.yaw, 2.5) < 1e-12 and fit.rms < 1e-12
    assert fit_square(corners, 0.05).rms == pytest.approx(0.005 * math.sqrt(2), rel=1e-9)


def test_a_mirrored_marker_does_not_fit() -> None:
    corners = placed_corners(0.04, 0.6, -0.2, 0.3)[[1, 0, 3, 2]]  # left and right swapped
    assert fit_square(corners, 0.04).rms > 0.01


@given(
    eye=st.tuples(st.floats(0.9, 1.8), st.floats(-0.6, 0.6), st.floats(0.8, 2.0)),
    x=st.floats(0.3, 0.85),
    y=st.floats(-0.45, 0.45),
    yaw=st.floats(-math.pi, math.pi),
    height=st.floats(0.005, 0.12),
    size=st.floats(0.02, 0.06),
)
def test_random_cameras_and_poses_are_recovered(
    eye: tuple[float, float, float], x: float, y: float, yaw: float, height: float, size: float
) -> None:
    truth = CameraPose.look_at(eye, (0.575, 0.0, 0.0))
    table = table_points()
    camera = solve_camera(project(table, truth, DISTORTED), table, DISTORTED).pose
    corners = placed_corners(size, x, y, yaw)
    pts = np.column_stack([corners, np.full(4, height)])
    fit = marker_pose(project(pts, truth, DISTORTED), size, height, DISTORTED, camera)
    assert math.hypot(fit.pose.x - x, fit.pose.y - y) < 1e-6
    assert yaw_gap(fit.pose.yaw, yaw) < 1e-5
    assert fit.rms < 1e-6


@pytest.mark.parametrize(
    "pixels",
    [np.full((4, 2), np.nan), np.full((4, 2), 1e308), np.zeros((4, 2))],
    ids=["nan", "huge", "one point"],
)
def test_what_opencv_cannot_solve_is_a_frame_without_a_pose_not_the_end(
    pixels: np.ndarray,
) -> None:
    """cv2.solvePnP raises cv2.error on such corners (it ended the tracker once): one
    InputError line without OpenCV's source path, which the tracker reports per frame."""
    camera = Intrinsics.pinhole(60, 640, 480)
    square = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], dtype=np.float64)
    with pytest.raises(InputError) as err:
        solve_camera(pixels, square, camera)
    text = str(err.value)
    assert "camera pose" in text and ".cpp" not in text and "\n" not in text


@pytest.mark.parametrize(
    ("fx", "fy", "expected"),
    [
        (1e-300, 1e-300, "fx must be 0.02 to 100 times the picture's larger side"),
        (600.0, 1e9, "fy must be 0.02 to 100 times"),
        (600.0, 100.0, "fx / fy must be within 4 of 1"),
    ],
)
def test_implausible_intrinsics_are_refused(fx: float, fy: float, expected: str) -> None:
    k = np.array([[fx, 0.0, 320.0], [0.0, fy, 240.0], [0.0, 0.0, 1.0]])
    with pytest.raises(InputError, match=expected):
        Intrinsics(k, np.zeros(5), 640, 480)
