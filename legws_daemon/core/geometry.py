"""Poses, quaternions and the SE(3) distance of the method (section 1).

Conventions: metres, radians, quaternions ``[w, x, y, z]`` (MuJoCo's order), rotation
matrices act on column vectors and map local to world coordinates. A grasp frame's
local z axis is its approach axis (from the gripper into the object). Every function
accepts arbitrary leading batch dimensions.

A grasp's *symmetry* ``n`` means the grasp is unchanged by a turn of ``2 pi / n`` about its
own approach axis; ``0`` means any turn; ``1`` means no symmetry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from legws_daemon.arms.spec import yaw_quaternion
from legws_daemon.errors import InputError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_EPS = 1e-12


def normalize_quaternion(q: ArrayLike) -> FloatArray:
    """Unit quaternion(s) in canonical sign, so that ``q`` and ``-q`` map to one array."""
    arr = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(arr, axis=-1, keepdims=True)
    if np.any(norm < 1e-9) or not np.all(np.isfinite(arr)):
        raise InputError("quaternion must be finite with a non-zero norm")
    return canonical_sign(arr / norm)


def canonical_sign(q: FloatArray) -> FloatArray:
    """Of ``q`` and ``-q`` (the same rotation) the one whose first non-zero entry is positive."""
    significant = np.abs(q) > 1e-12
    first = np.argmax(significant, axis=-1)[..., None]
    lead = np.take_along_axis(q, first, axis=-1)
    return np.asarray(np.where(lead < 0.0, -q, q), dtype=np.float64)


def quat_to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` ``[w, x, y, z]``."""
    arr = np.asarray(q, dtype=np.float64)
    arr = arr / np.linalg.norm(arr, axis=-1, keepdims=True)
    w, x, y, z = arr[..., 0], arr[..., 1], arr[..., 2], arr[..., 3]
    out = np.empty((*arr.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def matrix_to_quat(R: ArrayLike) -> FloatArray:
    """Canonical quaternions ``[w, x, y, z]`` of rotation matrices ``(..., 3, 3)``.

    Uses the largest-pivot branch per matrix, so it is accurate for every rotation.
    """
    mats = np.asarray(R, dtype=np.float64)
    if mats.shape == (3, 3):
        return _one_matrix_to_quat(mats)
    m = mats.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    pivots = np.concatenate([tr[:, None], diag], axis=1)
    branch = np.argmax(pivots, axis=1)
    q = np.empty((m.shape[0], 4))
    for b in range(4):
        sel = branch == b
        if not np.any(sel):
            continue
        s = m[sel]
        if b == 0:
            r = np.sqrt(1.0 + tr[sel]) * 2.0
            q[sel] = np.stack(
                [
                    0.25 * r,
                    (s[:, 2, 1] - s[:, 1, 2]) / r,
                    (s[:, 0, 2] - s[:, 2, 0]) / r,
                    (s[:, 1, 0] - s[:, 0, 1]) / r,
                ],
                axis=1,
            )
        else:
            i = b - 1
            j, k = (i + 1) % 3, (i + 2) % 3
            r = np.sqrt(1.0 + s[:, i, i] - s[:, j, j] - s[:, k, k]) * 2.0
            vec = np.empty((s.shape[0], 3))
            vec[:, i] = 0.25 * r
            vec[:, j] = (s[:, j, i] + s[:, i, j]) / r
            vec[:, k] = (s[:, k, i] + s[:, i, k]) / r
            w = (s[:, k, j] - s[:, j, k]) / r
            q[sel] = np.concatenate([w[:, None], vec], axis=1)
    q = canonical_sign(q / np.linalg.norm(q, axis=1, keepdims=True))
    return np.asarray(q.reshape(*mats.shape[:-2], 4), dtype=np.float64)


def _one_matrix_to_quat(R: FloatArray) -> FloatArray:
    """:func:`matrix_to_quat` of one matrix in plain floats (a control tick's path: the
    batched form costs ~0.1 ms for a single matrix)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = R.tolist()
    tr = m00 + m11 + m22
    if tr >= m00 and tr >= m11 and tr >= m22:
        r = math.sqrt(1.0 + tr) * 2.0
        q = [0.25 * r, (m21 - m12) / r, (m02 - m20) / r, (m10 - m01) / r]
    elif m00 >= m11 and m00 >= m22:
        r = math.sqrt(1.0 + m00 - m11 - m22) * 2.0
        q = [(m21 - m12) / r, 0.25 * r, (m10 + m01) / r, (m20 + m02) / r]
    elif m11 >= m22:
        r = math.sqrt(1.0 + m11 - m22 - m00) * 2.0
        q = [(m02 - m20) / r, (m10 + m01) / r, 0.25 * r, (m21 + m12) / r]
    else:
        r = math.sqrt(1.0 + m22 - m00 - m11) * 2.0
        q = [(m10 - m01) / r, (m20 + m02) / r, (m21 + m12) / r, 0.25 * r]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    lead = next((v for v in q if abs(v) > 1e-12 * norm), 1.0)
    scale = (1.0 if lead >= 0.0 else -1.0) / norm
    return np.array([v * scale for v in q])


def yaw_quat(yaw: float) -> FloatArray:
    """The quaternion ``[w, x, y, z]`` of a turn by ``yaw`` (rad) about the world z axis:
    an object's orientation as it stands on the table (:func:`~legws_daemon.arms.spec.
    yaw_quaternion` as an array)."""
    return np.array(yaw_quaternion(yaw))


def rot_z(yaw: ArrayLike) -> FloatArray:
    """Rotations about the world z axis, ``(..., 3, 3)``."""
    angle = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros((*angle.shape, 3, 3))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    return out


def axis_rotation(axis: ArrayLike, angle: ArrayLike) -> FloatArray:
    """Rotations by ``angle`` (a number, or an array of them) about one unit ``axis``
    (Rodrigues): ``(3, 3)``, or ``(*angle.shape, 3, 3)``."""
    x, y, z = np.asarray(axis, dtype=np.float64)
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    t = np.asarray(angle, dtype=np.float64)
    s, c = np.sin(t)[..., None, None], np.cos(t)[..., None, None]
    return np.asarray(np.eye(3) + s * K + (1 - c) * (K @ K), dtype=np.float64)


def rotation_angle(R1: ArrayLike, R2: ArrayLike) -> FloatArray:
    """Geodesic angle in ``[0, pi]`` between rotations (no symmetry)."""
    tr = np.einsum(
        "...ij,...ij->...", np.asarray(R1, np.float64), np.asarray(R2, np.float64)
    )  # trace(R1^T R2)
    return np.asarray(np.arccos(np.clip((tr - 1.0) * 0.5, -1.0, 1.0)), dtype=np.float64)


def symmetric_angle(R: ArrayLike, R_goal: ArrayLike, symmetry: ArrayLike) -> FloatArray:
    """Smallest geodesic angle between ``R`` and the symmetric equivalents of ``R_goal``.

    The equivalents of ``R_goal`` are ``R_goal @ Rz(2 pi k / n)`` for ``k = 0..n-1``
    (``n = symmetry``); for ``n = 0`` every turn about the approach axis, where the
    smallest angle is the angle between the two approach (z) axes.

    Args:
        R: rotations ``(..., 3, 3)``.
        R_goal: goal rotations ``(..., 3, 3)``, broadcast against ``R``.
        symmetry: integers ``(...)`` broadcast against the batch shape, each >= 0.
    """
    n = np.asarray(symmetry, dtype=np.int64)
    # Q = R^T R_goal; trace(R^T R_goal Rz(phi)) = c (Q00 + Q11) + s (Q01 - Q10) + Q22.
    Q = np.einsum("...ji,...jk->...ik", np.asarray(R, np.float64), np.asarray(R_goal, np.float64))
    a = Q[..., 0, 0] + Q[..., 1, 1]
    b = Q[..., 0, 1] - Q[..., 1, 0]
    q22 = Q[..., 2, 2]
    a, b, q22, n = np.broadcast_arrays(a, b, q22, n)
    n_max = int(n.max()) if n.size else 1
    best = np.full(a.shape, -np.inf)
    for k in range(max(n_max, 1)):
        valid = (n >= 1) & (k < np.maximum(n, 1))
        phi = 2.0 * np.pi * k / np.maximum(n, 1)
        tr_k = a * np.cos(phi) + b * np.sin(phi) + q22
        best = np.where(valid, np.maximum(best, tr_k), best)
    continuous = np.hypot(a, b) + q22
    best = np.where(n == 0, continuous, best)
    return np.asarray(np.arccos(np.clip((best - 1.0) * 0.5, -1.0, 1.0)), dtype=np.float64)


def se3_distance(
    p: ArrayLike,
    R: ArrayLike,
    p_goal: ArrayLike,
    R_goal: ArrayLike,
    symmetry: ArrayLike,
    rotation_weight: float,
) -> FloatArray:
    """``d(x, g) = |p - p_g| + lambda_R * angle(R, R_g)`` with the grasp's symmetry."""
    diff = np.asarray(p, dtype=np.float64) - np.asarray(p_goal, dtype=np.float64)
    trans = np.sqrt(np.einsum("...i,...i->...", diff, diff))
    return np.asarray(
        trans + rotation_weight * symmetric_angle(R, R_goal, symmetry), dtype=np.float64
    )


def safe_unit(v: ArrayLike) -> FloatArray:
    """Unit vectors along the last axis; zero where the vector is (numerically) zero."""
    arr = np.asarray(v, dtype=np.float64)
    norm = np.sqrt(np.einsum("...i,...i->...", arr, arr))[..., None]
    return np.asarray(np.where(norm > _EPS, arr / np.maximum(norm, _EPS), 0.0), dtype=np.float64)


@dataclass(frozen=True, slots=True)
class Pose:
    """A rigid pose: position (3,) in metres and unit quaternion ``[w, x, y, z]``."""

    position: FloatArray
    quaternion: FloatArray

    def __post_init__(self) -> None:
        p = np.asarray(self.position, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"position must be 3 finite numbers, got {self.position!r}")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "quaternion", normalize_quaternion(self.quaternion))

    @property
    def rotation(self) -> FloatArray:
        return quat_to_matrix(self.quaternion)
