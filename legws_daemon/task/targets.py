"""Goal poses of a stage's candidates, and what the gripper holds.

The observer infers over these poses, the certificate certifies them, and assistance
moves to them; each action computes its own (:mod:`legws_daemon.task.actions`): ``pick``
— the object's grasp; ``place`` — above the container or surface, gripper down, with the
held object clearing its top; ``dip`` — the held food's tip just below the bowl's rim;
``feed`` and a ``place`` at a named place — the place's pose; ``return`` — the grasp the
object was picked with. Orientation about the vertical is free (symmetry 0) where the
action does not care.

:class:`Held` records an object the gripper has closed on, as it was taken: where the EE
was (the pose to put it back with) and where the object sits in the gripper (to set it
down elsewhere, at any gripper orientation, with its bottom just above the table).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from legws_daemon.core.geometry import FloatArray, Pose, matrix_to_quat, rot_z
from legws_daemon.core.goals import GoalSet
from legws_daemon.scene.grasps import FINGER_DEPTH, extents
from legws_daemon.scene.scene import ObjectPose, Scene

#: Gripper pointing down (grasp-frame z along world -z): the top-grasp orientation.
DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Gap between a held object's bottom and the container's top when it is released, m.
DROP_CLEARANCE = 0.03
#: How deep food goes into a dip, below the bowl's rim, m.
DIP_DEPTH = 0.015
#: Held-object height assumed when the held object is not known, m.
DEFAULT_HELD_HEIGHT = 0.03
#: A set-down lets go of the held object with its bottom this far above the table, m ...
SET_DOWN_CLEARANCE = 0.01
#: ... and never with its bottom higher than this (the EE cannot get lower), m.
MAX_SET_DOWN_DROP = 0.05


@dataclass(frozen=True, slots=True)
class Target:
    """One candidate's goal pose."""

    name: str
    stage: str
    action: str
    position: FloatArray
    rotation: FloatArray
    symmetry: int


def held_above_grasp(scene: Scene, held: str | None) -> float:
    """Distance from the grasp point down to the held object's bottom."""
    if held is None or held not in scene.objects:
        return DEFAULT_HELD_HEIGHT - FINGER_DEPTH
    o = scene.objects[held]
    h = extents(o.shape, tuple(o.size))[2]
    return h - min(FINGER_DEPTH, h / 2)


def top_of(scene: Scene, name: str, pose: ObjectPose) -> FloatArray:
    """The centre of an object's top face, standing at ``pose``."""
    o = scene.objects[name]
    h = extents(o.shape, tuple(o.size))[2]
    return np.array([pose.x, pose.y, scene.workspace.table_height + h])


@dataclass(frozen=True, slots=True)
class Held:
    """An object in the gripper, as it was taken.

    Attributes:
        name: the object.
        position, rotation: the EE pose when the gripper closed on it (the grasp pose
            that puts it back exactly where it stood).
        center, frame: the object's centre and rotation in the grasp (EE) frame.
        extents: the object's bounding box, m.
        q: the arm's joint angles when the gripper closed (the motion planner starts its
            IK of the way back from there).
    """

    name: str
    position: FloatArray
    rotation: FloatArray
    center: FloatArray
    frame: FloatArray
    extents: FloatArray
    q: FloatArray

    @property
    def origin(self) -> FloatArray:
        """The object's centre where it was taken from."""
        return np.asarray(self.position + self.rotation @ self.center, dtype=np.float64)

    def bottom(self, position: FloatArray, rotation: FloatArray) -> float:
        """Height of the lowest point of the object's box with the EE at this pose."""
        c = np.asarray(position, dtype=np.float64) + rotation @ self.center
        half = 0.5 * float(np.abs((rotation @ self.frame)[2]) @ self.extents)
        return float(c[2]) - half

    def set_down_position(
        self, rotation: FloatArray, table_height: float, over: FloatArray | None = None
    ) -> FloatArray:
        """The EE position that, with the gripper at ``rotation``, holds the object's
        centre above ``over`` (x, y; default: where it was taken from) with its bottom
        :data:`SET_DOWN_CLEARANCE` above the table."""
        R = np.asarray(rotation, dtype=np.float64)
        xy = self.origin[:2] if over is None else np.asarray(over, dtype=np.float64)[:2]
        c = R @ self.center
        out = np.array([xy[0] - c[0], xy[1] - c[1], 0.0])
        out[2] = table_height + SET_DOWN_CLEARANCE - self.bottom(out, R)
        return out


def held_object(
    scene: Scene,
    layout: Mapping[str, ObjectPose],
    name: str,
    position: FloatArray,
    rotation: FloatArray,
    q: FloatArray,
) -> Held:
    """What the gripper took when it closed at EE pose (``position``, ``rotation``) and
    joint angles ``q`` on ``name``, standing at its pose in ``layout``."""
    o = scene.object(name)
    pose = scene.poses(dict(layout))[name]
    p = np.asarray(position, dtype=np.float64)
    R = np.asarray(rotation, dtype=np.float64)
    center = np.array([pose.x, pose.y, scene.z_center(name)])
    return Held(
        name,
        p.copy(),
        R.copy(),
        R.T @ (center - p),
        R.T @ rot_z(pose.yaw),
        np.array(extents(o.shape, tuple(o.size))),
        np.asarray(q, dtype=np.float64).copy(),
    )


def goal_set(targets: Sequence[Target], x0: Pose) -> GoalSet:
    """The observer's goals for >= 2 targets, seen from ``x0``."""
    return GoalSet(
        tuple(t.name for t in targets),
        np.array([t.position for t in targets]),
        matrix_to_quat(np.array([t.rotation for t in targets])),
        np.array([t.symmetry for t in targets], dtype=np.int64),
        x0,
    )
