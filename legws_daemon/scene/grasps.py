"""Grasp library (method.md section 6): one grasp per object, derived from its bounding box.

Grasp frame: origin at the centre between the fingertips, local z the approach axis (from
the gripper into the object), local x the closing direction of the fingers.

* ``top``: above the object, gripper pointing down, fingers closing along the object's
  local y axis (so the yaw of the grasp follows the object's yaw). The origin sits
  ``min(FINGER_DEPTH, height / 2)`` below the top surface, so the fingertips touch the
  object's sides just under its top.
* ``side``: at mid-height, approaching horizontally along the object's local +x axis
  (the gripper stands on the object's -x side), fingers closing along local y. The
  origin is ``min(FINGER_DEPTH, depth / 2)`` inside the -x face. The height is raised to
  ``SIDE_MIN_HEIGHT`` above the table where mid-height is lower (but never above the top
  minus ``FINGER_DEPTH``): with a horizontal approach the Sawyer's wrist, ~7 cm in radius,
  would otherwise hit the table (measured: docs/decisions.md).

Symmetry (turns about the approach axis that leave the grasp unchanged): a top grasp of a
cylinder or sphere is unchanged by any turn (0); of a square box by a quarter turn (4); of
any other box by a half turn (2). A side grasp of a parallel-jaw gripper is unchanged by a
half turn (2): the fingers swap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, rot_z
from legws_daemon.formats.scene_file import GRASP_KINDS as GRASP_KINDS
from legws_daemon.formats.scene_file import SHAPES as SHAPES
from legws_daemon.formats.scene_file import GraspKind, Shape

#: How far the fingertips reach over the object's surface, metres.
FINGER_DEPTH = 0.02
#: Lowest height above the table of a side grasp, metres (the wrist's clearance).
SIDE_MIN_HEIGHT = 0.07

# Columns are the grasp frame's x (closing), y, z (approach) axes in the object frame.
_R_TOP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_R_SIDE = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def extents(shape: Shape, size: tuple[float, ...]) -> tuple[float, float, float]:
    """Full bounding-box extents ``(sx, sy, sz)`` in the object frame."""
    if shape == "box":
        return (size[0], size[1], size[2])
    if shape == "cylinder":
        return (2 * size[0], 2 * size[0], size[1])
    return (2 * size[0], 2 * size[0], 2 * size[0])


@dataclass(frozen=True, slots=True)
class Grasp:
    """A grasp in the object frame (origin at the object's centre, z up).

    Attributes:
        kind: ``top`` or ``side``.
        offset: ``(3,)`` grasp origin in the object frame.
        rotation: ``(3, 3)`` grasp frame in the object frame.
        symmetry: symmetry order about the approach axis (0 = any turn).
    """

    kind: GraspKind
    offset: FloatArray
    rotation: FloatArray
    symmetry: int

    def world(
        self, x: ArrayLike, y: ArrayLike, yaw: ArrayLike, z_center: float
    ) -> tuple[FloatArray, FloatArray]:
        """Grasp positions ``(..., 3)`` and rotations ``(..., 3, 3)`` for object poses."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        Rz = rot_z(yaw)
        center = np.stack([x, y, np.full_like(x, z_center)], axis=-1)
        position = center + Rz @ self.offset
        rotation = Rz @ self.rotation
        return position, rotation


def derive_grasp(
    shape: Shape, size: tuple[float, ...], kind: GraspKind, symmetry: int | None = None
) -> Grasp:
    """The grasp of an object from its shape and size; ``symmetry`` overrides the derived one."""
    sx, sy, sz = extents(shape, size)
    if kind == "top":
        offset = np.array([0.0, 0.0, sz / 2 - min(FINGER_DEPTH, sz / 2)])
        rotation = _R_TOP.copy()
        if shape in ("cylinder", "sphere"):
            derived = 0
        elif abs(sx - sy) < 1e-6:
            derived = 4
        else:
            derived = 2
    else:
        lift = min(max(SIDE_MIN_HEIGHT - sz / 2, 0.0), max(sz / 2 - FINGER_DEPTH, 0.0))
        offset = np.array([-(sx / 2 - min(FINGER_DEPTH, sx / 2)), 0.0, lift])
        rotation = _R_SIDE.copy()
        derived = 2
    return Grasp(kind, offset, rotation, derived if symmetry is None else symmetry)
