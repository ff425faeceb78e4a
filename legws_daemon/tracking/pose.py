"""From marker corners in an image to poses in the robot base frame (pure math).

1. The camera's extrinsics: one ``solvePnP`` over the corners of every visible table
   marker, whose 3-D positions in the base frame the scene file gives (all on the plane
   ``z = table_height``: OpenCV's globally optimal SQPnP, refined by Levenberg-Marquardt;
   the planar IPPE solver returns NaN on exactly symmetric views).
2. An object's planar pose: each corner of its marker is undistorted into a ray from the
   camera's optical centre, and the ray is intersected exactly with the plane of the
   object's top face, ``z = table_height + height``. A 2-D rigid fit (least squares,
   closed form) of the marker's known square to the four points gives its centre and yaw;
   the marker sits centred on the top face with its x axis along the object's, so that is
   the object's pose. A cylinder's yaw is the marker's (its shape is symmetric, the marker
   is not).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.scene.scene import ObjectPose
from legws_daemon.tracking.camera import CameraPose, Intrinsics, opencv_reason
from legws_daemon.tracking.markers import local_corners

#: Rays closer to parallel with a plane than this (cosine of the angle to its normal) miss it.
_GRAZING = 1e-6


@dataclass(frozen=True, slots=True)
class CameraFit:
    """The camera pose solved from table markers.

    Attributes:
        pose: the camera in the base frame.
        rms: root-mean-square reprojection error of the table corners, pixels.
    """

    pose: CameraPose
    rms: float


@dataclass(frozen=True, slots=True)
class MarkerFit:
    """An object's planar pose measured from its marker.

    Attributes:
        pose: centre and yaw of the marker in the base frame.
        rms: root-mean-square distance of the measured corners from the fitted square, m.
    """

    pose: ObjectPose
    rms: float


def solve_camera(pixels: ArrayLike, points: ArrayLike, intrinsics: Intrinsics) -> CameraFit:
    """The camera pose from ``N >= 4`` coplanar points ``(N, 3)`` of the base frame seen at
    ``pixels`` ``(N, 2)``."""
    img = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    obj = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(img) != len(obj) or len(obj) < 4:
        raise InputError(f"need as many pixels as points, at least 4: {len(img)}, {len(obj)}")
    k, d = intrinsics.matrix, intrinsics.distortion
    try:  # OpenCV raises on what it cannot solve: a frame without a pose, never the end
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, d, flags=cv2.SOLVEPNP_SQPNP)
        if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
            raise InputError("the table markers' corners give no camera pose (degenerate layout)")
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, d, rvec, tvec)
        projected, _ = cv2.projectPoints(obj, rvec, tvec, k, d)
    except cv2.error as err:
        raise InputError(f"OpenCV finds no camera pose: {opencv_reason(err)}") from None
    if not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        raise InputError("the table markers' corners give no camera pose (degenerate layout)")
    rms = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - img) ** 2, axis=1))))
    return CameraFit(CameraPose.from_opencv(rvec, tvec), rms)


def plane_points(
    pixels: ArrayLike, intrinsics: Intrinsics, camera: CameraPose, z: float
) -> FloatArray:
    """Where the rays through ``pixels`` ``(N, 2)`` meet the plane ``z`` of the base frame,
    ``(N, 3)``.

    Raises:
        InputError: a ray parallel to the plane or meeting it behind the camera.
    """
    norm = intrinsics.undistort(pixels)
    rays = np.column_stack([norm, np.ones(len(norm))]) @ np.asarray(camera.rotation).T
    origin = np.asarray(camera.position, dtype=np.float64)
    dz = rays[:, 2]
    if np.any(np.abs(dz) < _GRAZING * np.linalg.norm(rays, axis=1)):
        raise InputError(f"a ray runs parallel to the plane z = {z:g}")
    t = (z - origin[2]) / dz
    if np.any(t <= 0.0):
        raise InputError(f"the plane z = {z:g} lies behind the camera")
    return np.asarray(origin + t[:, None] * rays, dtype=np.float64)


def fit_square(points: ArrayLike, size: float) -> MarkerFit:
    """The rigid planar pose of a marker of side ``size`` whose corners (top-left,
    top-right, bottom-right, bottom-left) were measured at ``points`` ``(4, 2)`` (least
    squares over rotation and translation, closed form)."""
    p = np.asarray(points, dtype=np.float64).reshape(4, 2)
    local = local_corners(size)  # centred at the origin
    centre = p.mean(axis=0)
    q = p - centre
    cross = np.sum(local[:, 0] * q[:, 1] - local[:, 1] * q[:, 0])
    dot = np.sum(local * q)
    yaw = float(np.arctan2(cross, dot))
    c, s = np.cos(yaw), np.sin(yaw)
    residual = q - local @ np.array([[c, s], [-s, c]])
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    return MarkerFit(ObjectPose(float(centre[0]), float(centre[1]), yaw), rms)


def marker_pose(
    pixels: ArrayLike, size: float, z: float, intrinsics: Intrinsics, camera: CameraPose
) -> MarkerFit:
    """The planar pose of a marker of side ``size`` lying on the plane ``z`` whose corners
    were seen at ``pixels`` ``(4, 2)``."""
    return fit_square(plane_points(pixels, intrinsics, camera, z)[:, :2], size)
