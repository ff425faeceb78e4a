"""Finding a scene's fiducial markers in a picture (OpenCV's ``cv2.aruco``).

Corners are refined to sub-pixel precision (lines fitted to the border) and come in
OpenCV's order (top-left, top-right, bottom-right, bottom-left of the marker's picture, see
:mod:`.markers`). A marker whose id
the scene does not know, or that shows up more than once, is set aside: which of two
copies is the real one cannot be told from the picture.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.tracking.markers import SceneMarkers, dictionary

#: Smallest marker perimeter the detector accepts, as a fraction of the image's larger side
#: (OpenCV's default 0.03 drops the smallest object markers seen across a table).
MIN_PERIMETER_RATE = 0.02


@dataclass(frozen=True)
class Detection:
    """The scene's markers found in one picture.

    Attributes:
        corners: marker id → its corners ``(4, 2)`` in pixels, for each known marker seen
            exactly once.
        duplicated: known ids seen more than once (none of their copies is in ``corners``).
        unknown: ids the scene does not have, each once, ascending.
    """

    corners: dict[int, FloatArray]
    duplicated: tuple[int, ...]
    unknown: tuple[int, ...]


def detector_parameters() -> Any:
    """OpenCV's detector parameters for a scene camera: small markers, sub-pixel corners
    where the lines fitted to the marker's border meet (``CORNER_REFINE_CONTOUR``). On
    markers 10 to 25 pixels wide that halves the yaw error of ``CORNER_REFINE_SUBPIX``,
    whose search window cannot stay inside cells 2 to 4 pixels wide; ``APRILTAG``'s
    refinement is as precise but drops most markers under 15 pixels."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR
    params.minMarkerPerimeterRate = MIN_PERIMETER_RATE
    return params


def grey(image: np.ndarray) -> np.ndarray:
    """The ``uint8`` grey picture of a BGR (as OpenCV captures) or grey image."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise InputError(
            f"expected a uint8 grey or BGR image, got {img.dtype} of shape {img.shape}"
        )
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


class MarkerDetector:
    """Detects the markers of one scene (its dictionary, its known ids)."""

    def __init__(self, markers: SceneMarkers) -> None:
        self.known = frozenset(markers.table) | frozenset(markers.objects)
        self._detector = cv2.aruco.ArucoDetector(
            dictionary(markers.dictionary), detector_parameters()
        )

    def detect(self, image: np.ndarray) -> Detection:
        """The known markers in ``image`` (BGR or grey ``uint8``), the duplicated and the
        unknown ones."""
        found, ids, _ = self._detector.detectMarkers(grey(image))
        if ids is None:
            return Detection({}, (), ())
        id_list = [int(i) for i in np.asarray(ids).reshape(-1)]
        counts = Counter(id_list)
        corners = {
            i: np.asarray(c, dtype=np.float64).reshape(4, 2)
            for i, c in zip(id_list, found, strict=True)
            if i in self.known and counts[i] == 1
        }
        duplicated = tuple(sorted(i for i, n in counts.items() if n > 1 and i in self.known))
        unknown = tuple(sorted(i for i in counts if i not in self.known))
        return Detection(corners, duplicated, unknown)
