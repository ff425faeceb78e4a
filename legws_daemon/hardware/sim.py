"""The ``sim`` adapter: the MuJoCo Sawyer stand-in.

Commands move the arm through its differential kinematics (joint speed and position
limits respected). The kinematics track a command only to first order, so a step that would
end with the EE outside the workspace box (further out than it was) is cut short where it
would leave: the box holds for the arm's real motion, not only for the command. The daemon's
loop timer paces it to real time (or runs it as fast as possible when the profile says
``sim.realtime = false``). The gripper is kinematic: closing it attaches the object between
the fingers, which then follows the hand until it opens.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np
import zenoh

from legws_daemon.core.geometry import FloatArray, matrix_to_quat, quat_to_matrix
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState, register
from legws_daemon.robot.kinematics import home_configuration, small_rotation_error, velocity_step
from legws_daemon.robot.world import World
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import ObjectPose, Scene

#: Gain holding the EE orientation, 1/s.
ORIENTATION_GAIN = 2.0
#: Closing the gripper grasps an object whose centre is this close to the grasp point, m.
GRASP_REACH = 0.05
#: Bisection steps cutting a step that would leave the workspace box (2^-20 of a step).
BOX_BISECTIONS = 20


def _rotation(hold: object) -> FloatArray:
    """``hold`` as a (3, 3) rotation matrix, or an :class:`InputError`."""
    try:
        R = np.asarray(hold, dtype=np.float64)
    except (TypeError, ValueError):
        R = np.full((3, 3), np.nan)
    if (
        R.shape != (3, 3)
        or not np.all(np.isfinite(R))
        or float(np.max(np.abs(R))) > 1.0 + 1e-6  # a rotation's entries: no overflow below
        or not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
        or np.linalg.det(R) <= 0.0
    ):
        raise InputError("must be a (3, 3) rotation matrix", field="hold")
    return R


@register("sim")
class SimAdapter(Adapter):
    """The stand-in; the arm starts at the scene's EE home, objects at the scene's layout."""

    def __init__(
        self, profile: ProfileSpec, scene: Scene, session: zenoh.Session | None = None
    ) -> None:
        super().__init__(profile, scene, session)
        self.world: World | None = None
        self.held: str | None = None
        self._grip_offset: tuple[FloatArray, FloatArray] | None = None
        self._closed = False

    def connect(self) -> None:
        world = World(self.scene)
        home_configuration(world, self.scene.home.position, self.scene.home.rotation)
        self.world = world

    def disconnect(self) -> None:
        self.world = None

    def _world(self) -> World:
        if self.world is None:
            raise LegwsError("the sim adapter is not connected")
        return self.world

    def read_state(self) -> RobotState:
        w = self._world()
        return RobotState(
            w.q, w.ee_position(), matrix_to_quat(w.ee_rotation()), time.monotonic(), self._closed
        )

    def _command(self, velocity: FloatArray, hold: FloatArray | None) -> None:
        """Move for one period; ``hold`` must be a rotation matrix (else an
        :class:`InputError`, nothing moves: a bad orientation target is a bug upstream)."""
        w = self._world()
        if np.any(velocity) or hold is not None:
            R = w.ee_rotation()
            target = R if hold is None else _rotation(hold)
            rot = ORIENTATION_GAIN * small_rotation_error(R, target)
            if np.any(velocity) or float(rot @ rot) > 1e-10:
                q0, p0 = w.q, w.ee_position()
                velocity_step(w, np.concatenate([velocity, rot]), self.dt)
                self._keep_in_box(q0, p0)
        # a zero command without an orientation target moves nothing (no null-space drift)
        self._carry()

    def _keep_in_box(self, q0: FloatArray, p0: FloatArray) -> None:
        """Cut the step ``q0 -> q`` short where the EE would leave the workspace box.

        No axis may end further outside the box than it was at ``p0`` (inside: not outside
        at all). The step is shortened along the joint-space segment (which keeps joint
        limits) by bisection; a step that stays inside costs one check.
        """
        w = self._world()
        lower, upper = self.box.lower, self.box.upper
        allowed = np.maximum(np.maximum(lower - p0, p0 - upper), 0.0)

        def inside(p: FloatArray) -> bool:
            return bool(np.all(np.maximum(lower - p, p - upper) <= allowed))

        if inside(w.ee_position()):
            return
        q1 = w.q
        good, bad = 0.0, 1.0
        for _ in range(BOX_BISECTIONS):
            mid = 0.5 * (good + bad)
            w.set_q(q0 + mid * (q1 - q0))
            if inside(w.ee_position()):
                good = mid
            else:
                bad = mid
        w.set_q(q0 + good * (q1 - q0))

    def grip(self, closed: bool) -> None:
        w = self._world()
        if closed and not self._closed:
            self._closed = True
            p, R = w.ee_position(), w.ee_rotation()
            best, best_d = None, GRASP_REACH
            for name in self.scene.objects:
                pos, quat = w.object_pose(name)
                d = float(np.linalg.norm(pos - p))
                if d < best_d:
                    best, best_d = name, d
            if best is not None:
                pos, quat = w.object_pose(best)
                self.held = best
                # the object's pose in the grasp frame
                self._grip_offset = (R.T @ (pos - p), R.T @ quat_to_matrix(quat))
        elif not closed and self._closed:
            self._closed = False
            if self.held is not None:
                self._settle(self.held)
            self.held = None
            self._grip_offset = None

    def _settle(self, name: str) -> None:
        """A released object drops onto what is below it (the table or another object)."""
        w = self._world()
        pos, quat = w.object_pose(name)
        o = self.scene.objects[name]
        half = extents(o.shape, tuple(o.size))[2] / 2
        support = self.scene.workspace.table_height
        for other in self.scene.objects:
            if other == name:
                continue
            opos, _ = w.object_pose(other)
            ox, oy, oz = extents(
                self.scene.objects[other].shape, tuple(self.scene.objects[other].size)
            )
            top = opos[2] + oz / 2
            inside = abs(pos[0] - opos[0]) <= ox / 2 and abs(pos[1] - opos[1]) <= oy / 2
            if inside and top <= pos[2] - half + 1e-6:
                support = max(support, top)
        # upright again: keep only the yaw of the held pose
        R = quat_to_matrix(quat)
        yaw = float(np.arctan2(R[1, 0], R[0, 0]))
        w.set_object_pose(
            name, [pos[0], pos[1], support + half], [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        )

    def _carry(self) -> None:
        if self.held is None or self._grip_offset is None:
            return
        w = self._world()
        p, R = w.ee_position(), w.ee_rotation()
        offset_p, offset_R = self._grip_offset
        w.set_object_pose(self.held, p + R @ offset_p, matrix_to_quat(R @ offset_R))

    def object_poses(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        w = self._world()
        return {name: w.object_pose(name) for name in self.scene.objects}

    def place_objects(self, layout: Mapping[str, ObjectPose]) -> bool:
        w = self._world()
        if self.held in layout:
            self.grip(False)
        w.set_layout(layout)
        return True

    def link_poses(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        w = self._world()
        if not np.array_equal(q, w.q):
            return super().link_poses(q)
        return w.link_poses()
