"""A camera's intrinsics and its pose in the robot base frame (pure values, no I/O).

Conventions are OpenCV's: the camera frame has x to the image's right, y down the image,
z along the optical axis into the scene; pixel ``(u, v)`` has its origin at the centre of
the top-left pixel, so the image centre is ``((w - 1) / 2, (h - 1) / 2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError

#: A focal length below this fraction of the picture's larger side would be a field of view
#: wider than ~176°; above ``MAX_FOCAL`` times it, narrower than ~0.6°: no lens of a tracker.
MIN_FOCAL = 0.02
MAX_FOCAL = 100.0
#: Pixels this far from square (fx / fy) are no camera's.
MAX_ASPECT = 4.0


def intrinsics_problem(matrix: np.ndarray, width: int, height: int) -> str | None:
    """What makes a camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` of a
    ``width`` x ``height`` picture unusable (``None``: nothing): focal lengths outside
    ``[MIN_FOCAL, MAX_FOCAL]`` times the larger side, pixels more than ``MAX_ASPECT`` from
    square. Such a matrix is ill-conditioned and OpenCV's solvers fail on it."""
    size = max(width, height)
    fx, fy = float(matrix[0][0]), float(matrix[1][1])
    for name, f in (("fx", fx), ("fy", fy)):
        if not MIN_FOCAL * size <= f <= MAX_FOCAL * size:
            return (
                f"the focal length {name} must be {MIN_FOCAL:g} to {MAX_FOCAL:g} times the "
                f"picture's larger side ({MIN_FOCAL * size:g} to {MAX_FOCAL * size:g} px), "
                f"got {f:g}"
            )
    if not 1 / MAX_ASPECT <= fx / fy <= MAX_ASPECT:
        return f"fx / fy must be within {MAX_ASPECT:g} of 1 (square-ish pixels), got {fx / fy:g}"
    return None


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera with OpenCV's lens distortion model.

    Attributes:
        matrix: ``(3, 3)`` camera matrix ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``,
            pixels.
        distortion: ``(5,)`` distortion coefficients in OpenCV's order
            ``k1, k2, p1, p2, k3`` (all zero for an ideal pinhole).
        width: image width, pixels.
        height: image height, pixels.
    """

    matrix: np.ndarray
    distortion: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        k = np.asarray(self.matrix, dtype=np.float64)
        d = np.asarray(self.distortion, dtype=np.float64).reshape(-1)
        if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise InputError("camera matrix must be a finite 3x3 matrix with fx, fy > 0")
        if d.shape != (5,) or not np.all(np.isfinite(d)):
            raise InputError("distortion must be 5 finite coefficients k1, k2, p1, p2, k3")
        if self.width < 1 or self.height < 1:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        problem = intrinsics_problem(k, self.width, self.height)
        if problem is not None:
            raise InputError(problem)
        object.__setattr__(self, "matrix", k)
        object.__setattr__(self, "distortion", d)

    @classmethod
    def pinhole(cls, fovy_deg: float, width: int, height: int) -> Intrinsics:
        """An ideal camera (square pixels, no distortion) of vertical field of view
        ``fovy_deg`` degrees, its principal point at the image centre."""
        if not 0.0 < fovy_deg < 180.0:
            raise InputError(f"vertical field of view must be in (0, 180) degrees: {fovy_deg}")
        f = (height / 2) / math.tan(math.radians(fovy_deg) / 2)
        k = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
        return cls(k, np.zeros(5), int(width), int(height))

    def undistort(self, pixels: ArrayLike) -> FloatArray:
        """Normalised image coordinates ``(N, 2)`` (``x/z, y/z`` in the camera frame) of
        pixels ``(N, 2)``, lens distortion removed."""
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        try:
            out = cv2.undistortPoints(pts, self.matrix, self.distortion)
        except cv2.error as err:
            reason = opencv_reason(err)
            raise InputError(f"OpenCV cannot undistort these pixels: {reason}") from None
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class CameraPose:
    """Where a camera is in the robot base frame.

    Attributes:
        rotation: ``(3, 3)`` the camera's axes (columns: x right, y down, z optical axis)
            in the base frame; maps camera to base coordinates.
        position: ``(3,)`` the camera's optical centre in the base frame, m.
    """

    rotation: np.ndarray
    position: np.ndarray

    @classmethod
    def from_opencv(cls, rvec: ArrayLike, tvec: ArrayLike) -> CameraPose:
        """From ``solvePnP``'s ``rvec, tvec`` (base → camera: ``x_c = R x_b + t``)."""
        r_cb, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))
        t = np.asarray(tvec, dtype=np.float64).reshape(3)
        return cls(r_cb.T, -r_cb.T @ t)

    def to_opencv(self) -> tuple[FloatArray, FloatArray]:
        """``rvec, tvec`` ``(3,)`` of the base → camera transform (for ``projectPoints``)."""
        r_cb = np.asarray(self.rotation, dtype=np.float64).T
        rvec, _ = cv2.Rodrigues(r_cb)
        return np.asarray(rvec, dtype=np.float64).reshape(3), -r_cb @ self.position

    @classmethod
    def look_at(cls, eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0, 0, 1)) -> CameraPose:
        """A camera at ``eye`` whose optical axis passes through ``target``, image up
        towards ``up`` (base frame)."""
        e = np.asarray(eye, dtype=np.float64)
        z = np.asarray(target, dtype=np.float64) - e
        x = np.cross(z, np.asarray(up, dtype=np.float64))
        if np.linalg.norm(z) < 1e-9 or np.linalg.norm(x) < 1e-9 * np.linalg.norm(z):
            raise InputError("camera target must differ from its position and not lie along up")
        z /= np.linalg.norm(z)
        x /= np.linalg.norm(x)
        return cls(np.column_stack([x, np.cross(z, x), z]), e)


def opencv_reason(err: BaseException) -> str:
    """OpenCV's error in one line, without its source path (``cv2.error`` carries the
    C++ file, line and function)."""
    text = getattr(err, "err", None) or str(err)
    lines = [line.strip() for line in str(text).splitlines() if line.strip()]
    reason = lines[-1] if lines else type(err).__name__
    return reason.split(") ", 1)[-1] if reason.startswith("OpenCV(") else reason
