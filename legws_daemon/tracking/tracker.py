"""One camera frame in, the objects' planar poses in the robot base frame out.

Every frame stands alone: the camera's pose is solved again from the table markers seen in
it, and an object is reported only when its marker was seen and usable in this very
frame, so a drop-out never passes an old pose off as fresh. What is set aside is said in
one-line warnings: an unknown marker, a marker seen twice (its object reported unseen, never
guessed), a marker that does not fit its known square, no table marker at all (then no
object has a pose in this frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from legws_daemon.errors import InputError
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.tracking.camera import CameraPose, Intrinsics
from legws_daemon.tracking.detect import Detection, MarkerDetector
from legws_daemon.tracking.markers import SceneMarkers, scene_markers
from legws_daemon.tracking.pose import CameraFit, marker_pose, solve_camera

#: A marker whose measured corners lie farther than this fraction of its side (RMS) from
#: its fitted square is not used: a wrong printed size, or the object is not resting flat.
MAX_FIT_RESIDUAL = 0.15


@dataclass(frozen=True)
class TrackFrame:
    """What one frame shows.

    Attributes:
        poses: object name → its planar pose, for the objects measured in this frame.
        unseen: the objects carrying a marker that were not measured in this frame, in
            scene order.
        warnings: one-line messages on what was set aside.
        table_markers: how many table markers gave the camera pose.
        camera: the camera pose used (``None`` without a table marker).
        camera_rms: reprojection error of the table markers' corners, pixels (``None``
            without a table marker).
    """

    poses: dict[str, ObjectPose]
    unseen: tuple[str, ...]
    warnings: tuple[str, ...]
    table_markers: int
    camera: CameraPose | None
    camera_rms: float | None


class Tracker:
    """Tracks the objects of ``scene`` in pictures of a camera with ``intrinsics``.

    Raises:
        InputError: the scene has no ``[markers]`` table.
    """

    def __init__(self, scene: Scene, intrinsics: Intrinsics) -> None:
        self.markers: SceneMarkers = scene_markers(scene)
        self.intrinsics = intrinsics
        self._detector = MarkerDetector(self.markers)
        self._tracked = tuple(n for n in scene.objects if self.markers.of_object(n) is not None)

    def process(self, image: np.ndarray) -> TrackFrame:
        """Detect the markers in ``image`` (BGR or grey ``uint8``) and measure the poses."""
        return self.measure(self._detector.detect(image))

    def measure(self, detection: Detection) -> TrackFrame:
        """The frame's poses from markers already detected."""
        warnings = [f"unknown marker id {i} seen" for i in detection.unknown]
        warnings += [self._duplicate_warning(i) for i in detection.duplicated]
        table_ids = sorted(i for i in detection.corners if i in self.markers.table)
        try:
            fit = self._camera(detection, table_ids)
        except InputError as err:  # degenerate corners: as if no table marker were seen
            warnings.append(f"no camera pose from the table markers ({err})")
            fit = None
        poses: dict[str, ObjectPose] = {}
        if not table_ids:
            warnings.append("no table marker visible: no object poses in this frame")
        elif fit is not None:
            for i, pixels in detection.corners.items():
                marker = self.markers.objects.get(i)
                if marker is None:
                    continue
                z = self.markers.table_height + marker.height
                try:
                    measured = marker_pose(pixels, marker.size, z, self.intrinsics, fit.pose)
                except InputError as err:
                    warnings.append(f"marker {i} ({marker.object}) not usable: {err}")
                    continue
                if measured.rms > MAX_FIT_RESIDUAL * marker.size:
                    warnings.append(
                        f"marker {i} ({marker.object}) does not fit its {marker.size:g} m "
                        f"square (residual {measured.rms * 1000:.1f} mm): object reported unseen"
                    )
                    continue
                poses[marker.object] = measured.pose
        unseen = tuple(n for n in self._tracked if n not in poses)
        return TrackFrame(
            poses=poses,
            unseen=unseen,
            warnings=tuple(warnings),
            table_markers=len(table_ids),
            camera=None if fit is None else fit.pose,
            camera_rms=None if fit is None else fit.rms,
        )

    def _camera(self, detection: Detection, table_ids: list[int]) -> CameraFit | None:
        if not table_ids:
            return None
        pixels = np.concatenate([detection.corners[i] for i in table_ids])
        points = np.concatenate(
            [self.markers.table[i].corners(self.markers.table_height) for i in table_ids]
        )
        return solve_camera(pixels, points, self.intrinsics)

    def _duplicate_warning(self, marker_id: int) -> str:
        marker = self.markers.objects.get(marker_id)
        if marker is None:
            return f"table marker {marker_id} seen twice: not used for the camera pose"
        return f"marker {marker_id} seen twice: {marker.object} reported unseen"
