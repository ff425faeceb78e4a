"""The ``sim`` adapter: the MuJoCo Sawyer stand-in.

Commands move the arm through its differential kinematics (joint speed and position
limits respected). The stand-in behaves like a Cartesian velocity controller with position
feedback: it integrates the commanded velocity into a reference position and corrects the
small first- and second-order errors of the kinematic step toward it, so a zero command is
no motion at all and a component clamped away at a box face does not drift. A zero
velocity with the orientation already held (within :data:`HOLD_TOLERANCE`) moves nothing:
no orientation correction, no null-space drift. The kinematics track a command only to
first order, so a step that would end with the EE outside the envelope (further out than
it was) is cut short where it would leave: the box holds for the arm's real motion, not
only for the command. Joint velocity commands are integrated exactly.

The daemon's loop timer paces it to real time (or runs it as fast as possible when the
profile says ``sim.realtime = false``); ``legws eval`` drives it in simulated time with
its own clock. The gripper is kinematic: closing it attaches the object between the
fingers, which then follows the hand until it opens.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping

import numpy as np
import zenoh

from legws_daemon.core.geometry import (
    FloatArray,
    matrix_to_quat,
    quat_to_matrix,
    rotation_angle,
    yaw_quat,
)
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState, model_state, register
from legws_daemon.robot.kinematics import (
    ORIENTATION_GAIN,
    home_configuration,
    small_rotation_error,
    velocity_step,
)
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import ObjectPose, Scene

#: Closing the gripper grasps the object (of the nearest centre) whose bounding box, grown by
#: this much, holds the grasp point between the fingertips, m.
GRASP_REACH = 0.015
#: Bisection steps cutting a step that would leave the workspace box (2^-20 of a step).
BOX_BISECTIONS = 20
#: A zero velocity with the orientation within this of the one to hold moves nothing, rad.
HOLD_TOLERANCE = 1e-3
#: Gain (1/s) and top speed (m/s) of the correction toward the reference position.
TRACKING_GAIN = 5.0
TRACKING_SPEED = 0.01
#: The reference restarts from the measured position when the arm fell this far behind
#: it (a joint limit held it back): it never winds up, m.
TRACKING_SLACK = 0.01


_EYE = np.eye(3)


def _rotation(hold: object) -> FloatArray:
    """``hold`` as a (3, 3) rotation matrix, or an :class:`InputError`."""
    try:
        R = np.asarray(hold, dtype=np.float64)
    except (TypeError, ValueError):
        R = np.full((3, 3), np.nan)
    if R.shape != (3, 3):
        raise InputError("must be a (3, 3) rotation matrix", field="hold")
    peak = float(np.max(np.abs(R)))  # NaN compares false: refused below
    if not peak <= 1.0 + 1e-6:  # a rotation's entries: no overflow below
        raise InputError("must be a (3, 3) rotation matrix", field="hold")
    off = float(np.max(np.abs(R.T @ R - _EYE)))
    if not off <= 1e-6 or np.linalg.det(R) <= 0.0:
        raise InputError("must be a (3, 3) rotation matrix", field="hold")
    return R


@register("sim")
class SimAdapter(Adapter):
    """The stand-in; the arm starts at the scene's EE home, objects at the scene's layout.

    Args:
        profile, scene, session: as every adapter.
        clock: monotonic seconds for the state's stamps (``legws eval`` passes its
            simulated clock).
    """

    def __init__(
        self,
        profile: ProfileSpec,
        scene: Scene,
        session: zenoh.Session | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(profile, scene, session)
        self.clock = clock
        self.world: World | None = None
        self.q_home: FloatArray | None = None
        self.held: str | None = None
        self._grip_offset: tuple[FloatArray, FloatArray] | None = None
        self._closed = False
        self._reference: FloatArray | None = None
        self._left_at: FloatArray | None = None  # the arm's q after the last tracked step
        self._valid_hold: tuple[bytes, FloatArray] = (b"", np.eye(3))

    def _connect(self) -> None:
        world = World(self.scene, arm=self.profile.arm)
        self.q_home = home_configuration(
            world, self.scene.home.position, self.scene.home.rotation
        ).q
        self.world = world

    def _disconnect(self) -> None:
        self.world = None

    def _world(self) -> World:
        if self.world is None:
            raise LegwsError("the sim adapter is not connected")
        return self.world

    def _kinematics(self) -> World:
        return self._world()

    def _read_state(self) -> RobotState:
        return model_state(self._world(), self.clock(), self._closed)

    def reset_arm(self, q: FloatArray | None = None) -> None:
        """Put the arm at ``q`` (default: home) at once, nothing held (a simulation's
        restart: ``legws eval`` starts every pick from home)."""
        w = self._world()
        if self.held is not None:
            self.grip(False)
        self._closed = False
        target = self.q_home if q is None else np.asarray(q, dtype=np.float64)
        if target is None:
            raise LegwsError("the sim adapter is not connected")
        w.set_q(target)
        self._reference = None

    def _command(
        self, state: RobotState, velocity: FloatArray, hold: FloatArray | None, box: Box
    ) -> None:
        """Move for one period from ``state``; ``hold`` must be a rotation matrix (else an
        :class:`InputError`, nothing moves: a bad orientation target is a bug upstream)."""
        w = self._world()
        R = state.ee_rotation
        target = R if hold is None else self._hold_rotation(hold)
        moving = bool(np.any(velocity))
        if not moving and float(rotation_angle(R, target)) < HOLD_TOLERANCE:
            self._reference = None  # zero is zero: nothing moves, not even the posture
            self._carry()
            return
        p0 = state.ee_position
        ref = self._reference
        moved = self._left_at is None or not np.array_equal(state.q, self._left_at)
        if ref is None or moved or float(np.linalg.norm(ref - p0)) > TRACKING_SLACK:
            ref = p0.copy()  # a new reference: none yet, or the arm was put elsewhere
        correction = TRACKING_GAIN * (ref - p0)
        speed = math.sqrt(float(correction @ correction))
        if speed > TRACKING_SPEED:
            correction *= TRACKING_SPEED / speed
        self._reference = np.clip(ref + velocity * self.dt, box.lower, box.upper)
        rot = ORIENTATION_GAIN * small_rotation_error(R, target)
        q0 = state.q
        velocity_step(w, np.concatenate([velocity + correction, rot]), self.dt, posture=moving)
        self._keep_in_box(q0, p0, box)
        self._left_at = w.q
        self._carry()

    def _hold_rotation(self, hold: object) -> FloatArray:
        """:func:`_rotation` of ``hold``, validated once for a run of ticks that hold the
        same orientation (teleop, one move of assistance)."""
        if isinstance(hold, np.ndarray) and hold.dtype == np.float64 and hold.shape == (3, 3):
            key = hold.tobytes()
            if key == self._valid_hold[0]:
                return self._valid_hold[1]
            R = _rotation(hold)
            self._valid_hold = (key, R.copy())
            return R
        return _rotation(hold)

    def _command_joints(self, state: RobotState, qdot: FloatArray) -> None:
        w = self._world()
        w.set_q(np.clip(state.q + qdot * self.dt, w.arm.lower, w.arm.upper))
        self._reference = None
        self._carry()

    def _halt(self) -> None:
        """Zero velocity: the stand-in does not move."""
        self._reference = None

    def _keep_in_box(self, q0: FloatArray, p0: FloatArray, box: Box) -> None:
        """Cut the step ``q0 -> q`` short where the EE would leave ``box``.

        No axis may end further outside the box than it was at ``p0`` (inside: not outside
        at all). The step is shortened along the joint-space segment (which keeps joint
        limits) by bisection; a step that stays inside costs one check.
        """
        w = self._world()
        lower, upper = box.lower, box.upper
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

    def _grip(self, closed: bool) -> None:
        w = self._world()
        if closed and not self._closed:
            self._closed = True
            p, R = w.ee_position(), w.ee_rotation()
            best, best_d = None, math.inf
            for name in self.scene.objects:
                pos, quat = w.object_pose(name)
                o = self.scene.objects[name]
                half = 0.5 * np.array(extents(o.shape, tuple(o.size)))
                local = quat_to_matrix(quat).T @ (p - pos)  # the grasp point, object frame
                d = float(np.linalg.norm(pos - p))
                if np.all(np.abs(local) <= half + GRASP_REACH) and d < best_d:
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
        w.set_object_pose(name, [pos[0], pos[1], support + half], yaw_quat(yaw))

    def _carry(self) -> None:
        if self.held is None or self._grip_offset is None:
            return
        w = self._world()
        p, R = w.ee_position(), w.ee_rotation()
        offset_p, offset_R = self._grip_offset
        w.set_object_pose(self.held, p + R @ offset_p, matrix_to_quat(R @ offset_R))

    def _object_poses(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        w = self._world()
        return {name: w.object_pose(name) for name in self.scene.objects}

    def _place_objects(self, layout: Mapping[str, ObjectPose]) -> bool:
        w = self._world()
        if self.held in layout:
            self.grip(False)
        w.set_layout(layout)
        return True
