"""The parallel gripper on the Sawyer's hand: its geometry, in one place.

:mod:`legws_daemon.robot.world` builds the fingers from these numbers, and the safety
envelope keeps the fingertips above the table with :func:`lowest_point`. Frames: the
``ee`` site sits at the grasp point between the fingertips (the TCP), z along the approach
axis, x along the closing direction.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray

#: Distance from the hand flange to the grasp point between the fingertips, metres.
TCP_OFFSET = 0.11
#: Half of the opening between the fingers' inner faces, metres.
FINGER_GAP = 0.042
#: Half-sizes of a finger box in the ``ee`` frame (closing x, y, approach z), metres.
FINGER_HALF = (0.006, 0.008, 0.03)
#: The fingertips are kept this far above the table outside the final approach of a
#: grasp, metres.
FINGERTIP_CLEARANCE = 0.005


def finger_corners() -> FloatArray:
    """The 16 corners ``(16, 3)`` of both finger boxes in the ``ee`` frame.

    The fingers end at the TCP along the approach axis (their tips are at ``z = 0``) and
    reach ``2 * FINGER_HALF[2]`` back toward the hand.
    """
    hx, hy, hz = FINGER_HALF
    corners = []
    for side in (-1.0, 1.0):
        cx = side * (FINGER_GAP + hx)
        for dx in (-hx, hx):
            for dy in (-hy, hy):
                for z in (0.0, -2 * hz):
                    corners.append((cx + dx, dy, z))
    return np.array(corners, dtype=np.float64)


_CORNERS = finger_corners()


def lowest_point(rotation: ArrayLike) -> float:
    """Height of the fingers' lowest point above the TCP for an EE orientation (3, 3):
    ``<= 0`` (the tips are at the TCP's height when the gripper points straight down)."""
    R = np.asarray(rotation, dtype=np.float64)
    return float(np.min(_CORNERS @ R[2]))


def floor_height(rotation: ArrayLike, table_height: float) -> float:
    """Lowest EE (TCP) height that keeps every finger point ``FINGERTIP_CLEARANCE`` above a
    table at ``table_height``, for the EE orientation ``rotation``."""
    return table_height + FINGERTIP_CLEARANCE - lowest_point(rotation)
