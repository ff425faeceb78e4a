"""Autonomous approach: after a commit the robot moves itself to the grasp pose.

A Cartesian proportional controller on position and orientation, speed-limited, through the
same differential kinematics as teleoperation. Of a symmetric grasp's equivalent
orientations the one nearest the current EE orientation is the target.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.robot.feasibility import symmetric_rotations
from legws_daemon.robot.kinematics import rotation_error, solve_ik, velocity_step
from legws_daemon.robot.world import JOINT_SPEED_LIMITS, World

#: Speed of the autonomous approach, m/s, and its angular speed, rad/s.
APPROACH_SPEED = 0.10
APPROACH_ANGULAR_SPEED = 0.8
#: The pre-grasp pose stands this far back along the approach axis, metres.
PREGRASP_DISTANCE = 0.08
#: Proportional gains, 1/s.
POSITION_GAIN = 2.0
ROTATION_GAIN = 2.0


@dataclass(frozen=True, slots=True)
class ApproachResult:
    reached: bool
    position_error: float
    rotation_error: float
    seconds: float


def approach_twist(
    world: World, position: FloatArray, rotation: FloatArray, speed: float = APPROACH_SPEED
) -> tuple[FloatArray, float, float]:
    """The twist of one approach tick and the current position / rotation errors."""
    dp = position - world.ee_position()
    dr = rotation_error(world.ee_rotation(), rotation)
    ep, er = math.sqrt(float(dp @ dp)), math.sqrt(float(dr @ dr))
    v = POSITION_GAIN * dp
    w = ROTATION_GAIN * dr
    v *= min(1.0, speed / max(float(np.linalg.norm(v)), 1e-12))
    w *= min(1.0, APPROACH_ANGULAR_SPEED / max(float(np.linalg.norm(w)), 1e-12))
    return np.concatenate([v, w]), ep, er


def approach(
    world: World,
    position: ArrayLike,
    rotation: ArrayLike,
    symmetry: int = 1,
    *,
    dt: float = 0.05,
    speed: float = APPROACH_SPEED,
    tol_position: float = 0.002,
    tol_rotation: float = 0.02,
    timeout: float = 30.0,
    q_grasp: ArrayLike | None = None,
) -> ApproachResult:
    """Drive the EE to the grasp pose (any symmetric equivalent).

    Two phases, as a motion planner would: a joint-space move to a pre-grasp pose
    ``PREGRASP_DISTANCE`` back along the approach axis (joint speeds at most half their
    limits), then a straight Cartesian move along the approach axis at up to ``speed``.
    ``q_grasp`` (e.g. from the feasibility check) seeds the pre-grasp IK.
    """
    target_p = np.asarray(position, dtype=np.float64)
    options = symmetric_rotations(
        np.asarray(rotation, dtype=np.float64), symmetry, world.ee_rotation()
    )
    start = world.q
    seed = start if q_grasp is None else np.asarray(q_grasp, dtype=np.float64)
    pre_q = None
    target_R = options[0]
    for R in options:
        pre_p = target_p - PREGRASP_DISTANCE * R[:, 2]
        ik = solve_ik(world, pre_p, R, seed, tol_position=1e-3, tol_rotation=1e-2)
        if ik.converged:
            pre_q, target_R = ik.q, R
            break
    world.set_q(start)
    t = 0.0
    if pre_q is not None:
        step = 0.5 * JOINT_SPEED_LIMITS * dt
        while t < timeout:
            delta = pre_q - world.q
            if np.all(np.abs(delta) < 1e-9):
                break
            frac = min(1.0, float(np.min(step / np.maximum(np.abs(delta), 1e-12))))
            world.set_q(world.q + frac * delta)
            t += dt
    ep = er = math.inf
    while t < timeout:
        twist, ep, er = approach_twist(world, target_p, target_R, speed)
        if ep < tol_position and er < tol_rotation:
            return ApproachResult(True, ep, er, t)
        velocity_step(world, twist, dt)
        t += dt
    return ApproachResult(False, ep, er, t)
