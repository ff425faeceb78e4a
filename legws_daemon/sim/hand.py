"""The simulated operator who finishes a pick by hand: teleoperation without assistance.

With ``assist = "none"`` nothing commits, so ``legws eval`` needs a user who grasps: this
one steers like the simulated user of method.md §2 (or an operator model of §10: the same
:class:`~legws_daemon.joystick.sim_user.SimUser`, the same noise) but to the *pre-grasp* —
:data:`PRE_GRASP` back along the grasp's approach axis (less where that would leave the
workspace box) — then turns the gripper in place to the grasp's orientation (the rotation
axes, proportional: full deflection beyond :data:`TURN_FULL`; the nearest of the grasp's
symmetric orientations), the stick holding the pre-grasp (the arm drifts while it turns),
then steers in along the approach to the grasp position, closes the gripper there and
pushes straight up until the object is lifted (the protocol's completion). Each step
starts once the last is reached within :data:`~legws_daemon.joystick.sim_user.ARRIVED`
(and :data:`TURNED`); it is what the assistance's plan does, done with the stick. (Turning
on the way, as a hurried person might, drove the arm into its wrist limits on the desk's
side grasps: the differential IK cannot follow; turning in place at the pre-grasp does.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from legws_daemon.core.geometry import FloatArray, axis_rotation, rotation_angle
from legws_daemon.joystick.sim_user import ARRIVED, SimUser, UserAction
from legws_daemon.robot.motion import BOX_MARGIN
from legws_daemon.safety.envelope import Box
from legws_daemon.task.targets import Target

#: The pre-grasp: this far back along the approach axis from the grasp position, m (or
#: less: the largest of these fractions of it that stays inside the workspace box).
PRE_GRASP = 0.08
PRE_FRACTIONS = (1.0, 0.75, 0.5, 0.25, 0.0)
#: The turn is done within this angle, rad; a larger one is turned at full deflection
#: from :data:`TURN_FULL` on (proportionally below it).
TURNED = 0.05
TURN_FULL = 0.3
#: Samples of a grasp with any turn about its approach (symmetry 0).
ANY_TURN_SAMPLES = 36


def nearest_grasp(target: Target, rotation: FloatArray) -> FloatArray:
    """Of the orientations the grasp allows (its symmetry about the approach axis), the one
    nearest ``rotation``."""
    n = target.symmetry if target.symmetry > 0 else ANY_TURN_SAMPLES
    axis = target.rotation[:, 2]
    options = [axis_rotation(axis, 2 * math.pi * k / n) @ target.rotation for k in range(n)]
    angles = [float(rotation_angle(rotation, R)) for R in options]
    return np.asarray(options[int(np.argmin(angles))], dtype=np.float64)


@dataclass
class HandUser:
    """A :class:`SimUser` that finishes the pick of ``target`` itself (module docstring).

    Attributes:
        step: ``approach`` (to the pre-grasp), ``turn`` (in place), ``in`` (along the
            approach), ``grip`` (the gripper button, one tick), ``lift`` (up), in order.
    """

    user: SimUser
    target: Target
    box: Box | None = None  # the workspace box the pre-grasp must lie in
    step: str = "approach"
    _grip: FloatArray | None = field(default=None, repr=False)
    _pre: FloatArray | None = field(default=None, repr=False)

    def pre_grasp(self) -> FloatArray:
        """Back along the approach axis from the grasp: :data:`PRE_GRASP`, or the largest
        of :data:`PRE_FRACTIONS` of it inside the box (the EE cannot leave it)."""
        if self._pre is None:
            t = self.target
            for fraction in PRE_FRACTIONS:
                pre = t.position - fraction * PRE_GRASP * t.rotation[:, 2]
                if self.box is None or self.box.contains(pre, -BOX_MARGIN):
                    break
            self._pre = np.asarray(pre, dtype=np.float64)
        return self._pre

    def act(self, position: FloatArray, rotation: FloatArray, now: float) -> UserAction:
        """This tick's stick, rotation axes and gripper button at the EE pose."""
        t = self.target
        if self._grip is None:
            self._grip = nearest_grasp(t, rotation)
        turn = self._turn(rotation)
        pre = self.pre_grasp()
        if self.step == "approach":
            if float(np.linalg.norm(pre - position)) < ARRIVED:
                self.step = "turn"
            else:
                return UserAction(self.user.steer(t.name, pre, position, now))
        if self.step == "turn":
            if not np.any(turn):
                self.step = "in"
            else:  # in place: the stick holds the pre-grasp while the gripper turns
                off = float(np.linalg.norm(pre - position)) >= ARRIVED
                axes = self.user.steer(t.name, pre, position, now) if off else np.zeros(3)
                return UserAction(axes, rotation=turn)
        if self.step == "in":
            if float(np.linalg.norm(t.position - position)) < ARRIVED:
                self.step = "grip"
            else:
                axes = self.user.steer(t.name, t.position, position, now)
                return UserAction(axes, rotation=turn)
        if self.step == "grip":
            self.step = "lift"
            return UserAction(np.zeros(3), gripper=True)
        return UserAction(np.array([0.0, 0.0, 1.0]), gripper=True)

    def _turn(self, rotation: FloatArray) -> FloatArray:
        """The rotation axes toward the grasp's orientation (zero once within TURNED)."""
        assert self._grip is not None
        rotvec = Rotation.from_matrix(self._grip @ np.asarray(rotation).T).as_rotvec()
        angle = float(np.linalg.norm(rotvec))
        if angle < TURNED:
            return np.zeros(3)
        return np.asarray(rotvec / angle * min(1.0, angle / TURN_FULL), dtype=np.float64)
