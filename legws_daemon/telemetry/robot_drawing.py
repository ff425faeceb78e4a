"""The arm in Rerun: its meshes once (static), the link poses every tick, the fingers' opening.

Entities under ``world/robot``: ``world/robot/<link>`` carries the link's pose (a
``Transform3D`` per tick, sent only when it changed); ``world/robot/<link>/mesh`` the link's
merged meshes (``Mesh3D``, static), ``world/robot/<link>/<box>`` its primitive boxes (the
gripper base) and ``world/robot/<hand>/fingers`` the two fingers, re-sent when the opening
changes. Without a :class:`~legws_daemon.robot.visual.RobotVisual` (a test's synthetic
robot), the arm is a thin line through the link origins at ``world/robot/links``.

The per-tick transforms are Arrow slices built straight from numpy (see
:class:`legws_daemon.telemetry.rerun_log._Fast`): ten links cost about as much as ten
posterior points.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from legws_daemon.core.geometry import FloatArray

if TYPE_CHECKING:  # MuJoCo (under robot.visual) loads only where the meshes are made
    from legws_daemon.robot.visual import RobotVisual

ROBOT_PATH = "world/robot"
#: Path of the fallback line strip (no meshes given).
LINKS_PATH = f"{ROBOT_PATH}/links"
#: The fingers' opening is re-sent when it changes by more than this, m.
_GAP_STEP = 5e-4

Batches = list[rr.DescribedComponentBatch]


def _xyzw(q_wxyz: FloatArray) -> list[float]:
    return [float(q_wxyz[1]), float(q_wxyz[2]), float(q_wxyz[3]), float(q_wxyz[0])]


class RobotDrawing:
    """Draws one arm into a recording stream.

    Args:
        log: ``stream.log`` of the recording.
        fast: the recording's batch builder (``_Fast``), for the per-tick transforms.
        visual: the arm's meshes; ``None`` draws the fallback line.
        every: send the link poses every this many ticks (0: the first tick only).
    """

    def __init__(
        self,
        log: Callable[..., None],
        fast: Any,
        visual: RobotVisual | None,
        every: int = 1,
    ) -> None:
        self._log = log
        self._fast = fast
        self._visual = visual
        self._every = every
        self._sent: dict[int, bytes] = {}
        self._line: bytes = b""
        self._gap: float | None = None
        self._paths: dict[int, str] = {}
        if visual is not None:
            self._paths = {i: f"{ROBOT_PATH}/{rr.escape_entity_path_part(visual.links[i])}"
                           for i in visual.drawn_links}  # fmt: skip

    @property
    def every(self) -> int:
        return self._every

    def log_static(self) -> None:
        """The meshes and boxes of every link (once; static)."""
        v = self._visual
        if v is None:
            return
        for mesh in v.meshes:
            self._log(
                f"{self._paths[mesh.link]}/mesh",
                rr.Mesh3D(
                    vertex_positions=mesh.vertices,
                    vertex_normals=mesh.normals,
                    vertex_colors=mesh.colors,
                    triangle_indices=mesh.triangles,
                ),
                static=True,
            )
        for box in v.boxes:
            self._log(
                f"{self._paths[box.link]}/{rr.escape_entity_path_part(box.name)}",
                rr.Boxes3D(
                    centers=[box.center],
                    half_sizes=[box.half_size],
                    quaternions=[rr.Quaternion(xyzw=_xyzw(box.quaternion))],
                    colors=[box.color],
                    fill_mode="solid",
                ),
                static=True,
            )

    def log_poses(self, tick: int, positions: FloatArray, rotations: FloatArray) -> None:
        """The link poses of one tick (origins ``(K, 3)``, rotations ``(K, 3, 3)``)."""
        pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        rot = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
        if self._visual is None:
            self._log_line(pos)
            return
        if len(pos) != len(self._visual.links):
            raise ValueError(f"{len(pos)} link poses for a robot of {len(self._visual.links)}")
        if self._sent and (self._every <= 0 or tick % self._every):
            return
        changed = []
        for i in self._paths:
            key = pos[i].tobytes() + rot[i].tobytes()
            if self._sent.get(i) != key:
                self._sent[i] = key
                changed.append(i)
        if not changed:
            return
        fast = self._fast
        # one Arrow array per quantity, zero-copy slices per link; rerun stores column-major
        translations = pa.array(pos[changed].astype(np.float32).ravel())
        matrices = pa.array(rot[changed].transpose(0, 2, 1).astype(np.float32).ravel())
        for k, i in enumerate(changed):
            frame = [
                fast.wrap("Transform3D:translation", translations.slice(3 * k, 3)),
                fast.wrap("Transform3D:mat3x3", matrices.slice(9 * k, 9)),
            ]
            self._log(self._paths[i], frame)

    def log_fingers(self, half_gap: float) -> None:
        """The fingers at a half-opening (m); sent when it changed by a step."""
        v = self._visual
        if v is None or v.fingers is None:
            return
        if self._gap is not None and abs(half_gap - self._gap) < _GAP_STEP:
            return
        self._gap = half_gap
        f = v.fingers
        centers = f.centers(half_gap)
        self._log(
            f"{self._paths[f.link]}/fingers",
            rr.Boxes3D(
                centers=centers,
                half_sizes=[f.half_size, f.half_size],
                colors=[f.color, f.color],
                fill_mode="solid",
            ),
        )

    def _log_line(self, pos: FloatArray) -> None:
        key = pos.tobytes()
        if key != self._line:
            self._line = key
            strip = [self._fast.strips("LineStrips3D:strips", pos)]
            self._log(LINKS_PATH, strip)
