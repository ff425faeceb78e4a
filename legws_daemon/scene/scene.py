"""A loaded scene: objects with their grasps, the default layout, and goal sets of layouts."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, IntArray, Pose, matrix_to_quat
from legws_daemon.core.goals import GoalSet
from legws_daemon.errors import InputError
from legws_daemon.formats.scene_file import ObjectSpec, SceneSpec, WorkspaceSpec
from legws_daemon.scene.grasps import Grasp, derive_grasp, extents


@dataclass(frozen=True, slots=True)
class ObjectPose:
    """Planar pose of an object resting on the table: centre ``x``, ``y`` and ``yaw``."""

    x: float
    y: float
    yaw: float


#: A layout: poses of (some of) a scene's movable objects, by name.
Layout = dict[str, ObjectPose]


class Scene:
    """A validated scene with derived grasps.

    Attributes:
        name: scene name (the file's stem).
        source: where it was loaded from (for messages).
        workspace: table, bounds, clearances and EE home.
        objects: object specifications by name, in file order.
        movable: names of objects a layout may move.
        fixed: names of objects that never move (clutter, place targets).
        goal_names: the default candidate goals (movable objects).
        grasps: one :class:`Grasp` per object.
        home: the EE home pose, start pose ``x0`` of every episode.
    """

    def __init__(self, spec: SceneSpec, source: str) -> None:
        self.spec = spec
        self.name = spec.name
        self.source = source
        self.workspace: WorkspaceSpec = spec.workspace
        self.objects: dict[str, ObjectSpec] = {o.name: o for o in spec.objects}
        self.movable = tuple(o.name for o in spec.objects if o.movable)
        self.fixed = tuple(o.name for o in spec.objects if not o.movable)
        self.goal_names = tuple(spec.goals) if spec.goals is not None else self.movable
        self.grasps: dict[str, Grasp] = {
            o.name: derive_grasp(o.shape, tuple(o.size), o.grasp, o.symmetry) for o in spec.objects
        }
        home = spec.workspace.ee_home
        self.home = Pose(np.array(home.position), np.array(home.quaternion))

    def __repr__(self) -> str:
        return f"Scene({self.name!r}, M={len(self.goal_names)}, total={len(self.objects)})"

    def object(self, name: str) -> ObjectSpec:
        try:
            return self.objects[name]
        except KeyError:
            raise InputError(
                f"unknown object '{name}' in scene '{self.name}'; known: {', '.join(self.objects)}"
            ) from None

    def z_center(self, name: str) -> float:
        """Height of the object's centre when it rests on the table."""
        o = self.object(name)
        return self.workspace.table_height + extents(o.shape, tuple(o.size))[2] / 2

    def default_layout(self) -> Layout:
        """The shipped layout of the movable objects (their poses in the scene file)."""
        return {n: self._spec_pose(n) for n in self.movable}

    def _spec_pose(self, name: str) -> ObjectPose:
        o = self.objects[name]
        return ObjectPose(o.x, o.y, o.yaw)

    def check_names(self, names: Sequence[str], what: str = "layout") -> None:
        """Every name must be a movable object of this scene."""
        for n in names:
            if n not in self.objects:
                raise InputError(
                    f"unknown object '{n}' in {what}; scene '{self.name}' has: "
                    f"{', '.join(self.objects)}"
                )
            if n not in self.movable:
                raise InputError(
                    f"object '{n}' is fixed in scene '{self.name}'; movable: "
                    f"{', '.join(self.movable)}"
                )

    def poses(self, layout: Mapping[str, ObjectPose] | None = None) -> dict[str, ObjectPose]:
        """Poses of every object: the layout's where given, the scene file's otherwise."""
        layout = layout or {}
        self.check_names(list(layout))
        return {n: layout.get(n, self._spec_pose(n)) for n in self.objects}

    def goal_set(
        self,
        layout: Mapping[str, ObjectPose] | None = None,
        goals: Sequence[str] | None = None,
    ) -> GoalSet:
        """The grasp poses of ``goals`` (default: the scene's candidates) in ``layout``."""
        names = tuple(goals) if goals is not None else self.goal_names
        self.check_names(names, "goals")
        poses = self.poses(layout)
        arr = np.array([[poses[n].x, poses[n].y, poses[n].yaw] for n in names])
        pos, rot, sym = self.grasp_batch(names, arr[None])
        return GoalSet(names, pos[0], matrix_to_quat(rot[0]), sym, self.home)

    def grasp_batch(
        self, names: Sequence[str], poses: ArrayLike
    ) -> tuple[FloatArray, FloatArray, IntArray]:
        """Grasp poses of the named objects for a batch of layouts.

        Args:
            names: M object names.
            poses: ``(B, M, 3)`` object ``(x, y, yaw)``.

        Returns:
            positions ``(B, M, 3)``, rotations ``(B, M, 3, 3)`` and symmetry ``(M,)``.
        """
        arr = np.asarray(poses, dtype=np.float64)
        if arr.ndim != 3 or arr.shape[1:] != (len(names), 3):
            raise InputError(f"expected poses of shape (B, {len(names)}, 3), got {arr.shape}")
        positions = np.empty((arr.shape[0], len(names), 3))
        rotations = np.empty((arr.shape[0], len(names), 3, 3))
        for k, n in enumerate(names):
            g = self.grasps[n]
            positions[:, k], rotations[:, k] = g.world(
                arr[:, k, 0], arr[:, k, 1], arr[:, k, 2], self.z_center(n)
            )
        symmetry = np.array([self.grasps[n].symmetry for n in names], dtype=np.int64)
        return positions, rotations, symmetry
