"""The fiducial markers of a scene: OpenCV's dictionaries, marker pictures, and where each
marker's corners lie.

A marker's own frame: origin at its centre, x along its top edge (left to right in the
marker's picture), y towards its top edge, z out of the printed face. Its corners come in
OpenCV's order: top-left, top-right, bottom-right, bottom-left. A table marker lies at
``(x, y, yaw)`` on the table; an object's marker is centred on its top face with its x axis
along the object's x axis, so an object at yaw ``θ`` shows its marker turned by ``θ``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Any

import cv2
import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.scene_file import MARKER_DICTIONARIES
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import Scene

#: White margin around a printed marker, in marker cells (OpenCV's detector needs one).
QUIET_CELLS = 1


@cache
def dictionary(name: str) -> Any:
    """OpenCV's predefined dictionary ``name`` (e.g. ``4X4_50``)."""
    if name not in MARKER_DICTIONARIES:
        raise InputError(
            f"unknown marker dictionary '{name}'; known: {', '.join(MARKER_DICTIONARIES)}"
        )
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, f"DICT_{name}"))


def cells(name: str) -> int:
    """Cells along a marker's side, its black border included (4x4 markers: 6)."""
    return int(dictionary(name).markerSize) + 2


def marker_image(
    name: str, marker_id: int, cell_pixels: int = 16, quiet: bool = True
) -> np.ndarray:
    """The picture of marker ``marker_id`` of dictionary ``name``: ``uint8`` grey, black on
    white, ``cell_pixels`` per cell, with a white margin of :data:`QUIET_CELLS` cells
    around it when ``quiet``. Its top row is the marker's top edge."""
    side = cells(name) * cell_pixels
    img = cv2.aruco.generateImageMarker(dictionary(name), int(marker_id), side, borderBits=1)
    if not quiet:
        return np.asarray(img, dtype=np.uint8)
    pad = QUIET_CELLS * cell_pixels
    return np.pad(np.asarray(img, dtype=np.uint8), pad, constant_values=255)


def local_corners(size: float) -> FloatArray:
    """The four corners of a marker of side ``size`` in its own frame, ``(4, 2)``:
    top-left, top-right, bottom-right, bottom-left."""
    h = size / 2
    return np.array([[-h, h], [h, h], [h, -h], [-h, -h]])


def placed_corners(size: float, x: float, y: float, yaw: float) -> FloatArray:
    """The corners ``(4, 2)`` of a marker of side ``size`` centred at ``(x, y)``, its x
    axis at ``yaw``, in the frame it lies in (robot base frame for the table)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.asarray(local_corners(size) @ np.array([[c, s], [-s, c]]) + [x, y], dtype=np.float64)


@dataclass(frozen=True, slots=True)
class TableMarker:
    id: int
    size: float
    x: float
    y: float
    yaw: float

    def corners(self, table_height: float) -> FloatArray:
        """Its corners ``(4, 3)`` in the robot base frame."""
        xy = placed_corners(self.size, self.x, self.y, self.yaw)
        return np.column_stack([xy, np.full(4, table_height)])


@dataclass(frozen=True, slots=True)
class ObjectMarker:
    id: int
    size: float
    object: str
    height: float  # of the top face above the table, m


@dataclass(frozen=True)
class SceneMarkers:
    """A scene's markers (``[markers]`` and each object's ``marker``).

    Attributes:
        dictionary: the OpenCV dictionary's name.
        table: the markers on the table, by id.
        objects: the objects' markers, by id.
        table_height: of the table top in the base frame, m.
    """

    dictionary: str
    table: dict[int, TableMarker]
    objects: dict[int, ObjectMarker]
    table_height: float

    def of_object(self, name: str) -> ObjectMarker | None:
        for m in self.objects.values():
            if m.object == name:
                return m
        return None


def scene_markers(scene: Scene) -> SceneMarkers:
    """The markers of ``scene``; an error naming the scene file when it has none."""
    spec = scene.spec.markers
    if spec is None:
        raise InputError(
            "the scene has no [markers] table: which fiducial markers lie on the table and "
            "which object carries which marker",
            source=scene.source,
            field="markers",
        )
    table = {m.id: TableMarker(m.id, m.size, m.x, m.y, m.yaw) for m in spec.table}
    objects = {
        o.marker.id: ObjectMarker(
            o.marker.id, o.marker.size, o.name, extents(o.shape, tuple(o.size))[2]
        )
        for o in scene.spec.objects
        if o.marker is not None
    }
    return SceneMarkers(spec.dictionary, table, objects, scene.workspace.table_height)
