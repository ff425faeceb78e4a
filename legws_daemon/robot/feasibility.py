"""Grasp feasibility: IK reachability of the grasp pose, a collision-free configuration,
and a straight approach.

For each grasp the symmetric equivalents of its orientation are tried, nearest to the home
orientation first, from the home configuration and then from a few fixed restarts; a grasp
is feasible when IK reaches one of them within tolerance and, in that configuration, the
robot touches neither the table nor any non-target object (contact with the target itself
is expected: the fingers straddle it), and from that configuration IK also reaches the
pre-grasp pose in front of it along the approach axis
(:data:`~legws_daemon.robot.motion.PREGRASP_DISTANCE`, or a shorter one of
:data:`~legws_daemon.robot.motion.APPROACH_FRACTIONS` of it): the robot can come in
straight, as the motion planner makes it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from legws_daemon.arms import ArmSpec
from legws_daemon.core.geometry import FloatArray, rot_z, rotation_angle
from legws_daemon.core.goals import GoalSet
from legws_daemon.robot.kinematics import solve_ik
from legws_daemon.robot.motion import APPROACH_FRACTIONS, PREGRASP_DISTANCE
from legws_daemon.robot.world import World
from legws_daemon.scene.scene import ObjectPose

#: Samples of a continuous symmetry (symmetry 0) tried by IK.
CONTINUOUS_SAMPLES = 8
#: IK tolerances for a grasp to count as reachable.
TOL_POSITION = 0.005
TOL_ROTATION = 0.05
#: Extra IK starts (deterministic) tried when the start from home does not give a
#: reachable, collision-free configuration: the arm is redundant, and damped least squares
#: from one start finds one of its configurations only.
RESTARTS = 12


def ik_seeds(world: World, q_home: FloatArray) -> list[FloatArray]:
    """``q_home`` first, then :data:`RESTARTS` fixed pseudo-random starts inside the limits."""
    rng = np.random.default_rng(20_240_601)
    lo, hi = world.arm.lower * 0.8, world.arm.upper * 0.8
    return [q_home, *(rng.uniform(lo, hi) for _ in range(RESTARTS))]


@dataclass(frozen=True, slots=True)
class GraspCheck:
    """Feasibility of one grasp.

    Attributes:
        name: the goal (object) name.
        feasible: reachable and collision-free.
        reason: ``"ok"`` or why not (out of reach with the residual, or what it hits).
        q: the arm configuration at the grasp (of the best attempt).
        rotation: the grasp orientation reached: of a symmetric grasp's equivalent
            orientations, the one ``q`` takes (of the best attempt).
    """

    name: str
    feasible: bool
    reason: str
    q: FloatArray
    rotation: FloatArray


def symmetric_rotations(R: FloatArray, symmetry: int, reference: FloatArray) -> list[FloatArray]:
    """The grasp's equivalent orientations, nearest to ``reference`` first."""
    n = symmetry if symmetry > 0 else CONTINUOUS_SAMPLES
    options = [R @ rot_z(2 * np.pi * k / n) for k in range(n)]
    return sorted(options, key=lambda X: float(rotation_angle(reference, X)))


def check_grasps(
    world: World,
    goals: GoalSet,
    q_home: FloatArray,
    layout: Mapping[str, ObjectPose] | None = None,
    names: Sequence[str] | None = None,
) -> dict[str, GraspCheck]:
    """Check every goal of ``goals`` (each named after its object) in the given layout.

    Leaves the arm at ``q_home``.
    """
    if layout:
        world.set_layout(layout)
    out: dict[str, GraspCheck] = {}
    rotations = goals.rotations
    seeds = ik_seeds(world, q_home)
    for i, name in enumerate(names or goals.names):
        out[name] = check_grasp(world, name, goals.positions[i], rotations[i],
                               int(goals.symmetry[i]), goals.x0.rotation, seeds)  # fmt: skip
    world.set_q(q_home)
    return out


def far_enough(spec: ArmSpec, positions: ArrayLike) -> NDArray[np.bool_]:
    """Whether each grasp position ``(..., 3)`` is at least the arm's ``min_reach`` from
    its base's vertical axis (horizontally)."""
    p = np.asarray(positions, dtype=np.float64)
    d = np.hypot(p[..., 0] - spec.mount.x, p[..., 1] - spec.mount.y)
    return np.asarray(d >= spec.min_reach)


def check_grasp(
    world: World,
    name: str,
    position: FloatArray,
    rotation: FloatArray,
    symmetry: int,
    reference: FloatArray,
    seeds: list[FloatArray],
) -> GraspCheck:
    """Check one pose: IK from each seed toward each symmetric equivalent (nearest to
    ``reference`` first), the first reachable, collision-free configuration with a straight
    approach wins. Why not (of the best attempt): it collides, else it has no straight
    approach, else it is out of reach; or, before any IK, it is nearer the arm's base than
    the arm grasps (``min_reach``). Leaves the arm where the last attempt ended."""
    spec = world.spec
    if not far_enough(spec, position):
        d = float(np.hypot(position[0] - spec.mount.x, position[1] - spec.mount.y))
        why = (
            f"too close to the arm's base: {d * 100:.0f} cm from its axis, the {spec.title} "
            f"grasps from {spec.min_reach * 100:.0f} cm"
        )
        return GraspCheck(name, False, why, seeds[0], rotation)
    best_err = np.inf
    best_q = seeds[0]
    best_R = rotation
    reason = ""
    for seed in seeds:
        for R in symmetric_rotations(rotation, symmetry, reference):
            ik = solve_ik(
                world, position, R, seed, tol_position=TOL_POSITION / 5,
                tol_rotation=TOL_ROTATION / 5,
            )  # fmt: skip
            if ik.position_error > TOL_POSITION or ik.rotation_error > TOL_ROTATION:
                err = ik.position_error + 0.1 * ik.rotation_error
                if err < best_err and (not reason or reason.startswith("out of reach")):
                    best_err, best_q, best_R = err, ik.q, R
                    reason = (
                        f"out of reach: IK misses the grasp by {ik.position_error * 100:.1f} cm "
                        f"and {np.degrees(ik.rotation_error):.0f} deg"
                    )
                continue
            hits = world.arm_contacts(ignore=frozenset({name}))
            if hits:
                best_q, best_R = ik.q, R
                reason = f"collides with {hits[0][1]} ({hits[0][0]})"
                continue
            if _approachable(world, position, R, ik.q):
                world.set_q(ik.q)
                return GraspCheck(name, True, "ok", ik.q, R)
            if not reason.startswith("collides"):
                best_q, best_R = ik.q, R
                reason = (
                    f"no straight approach: the pose {PREGRASP_DISTANCE * 100:g} cm in front "
                    "along the approach axis is out of reach"
                )
    return GraspCheck(name, False, reason, best_q, best_R)


#: IK tolerances of the pre-grasp pose (the straight approach corrects what is left), m, rad.
APPROACH_TOL_POSITION = 2e-3
APPROACH_TOL_ROTATION = 2e-2


def _approachable(world: World, position: FloatArray, R: FloatArray, q: FloatArray) -> bool:
    """Whether IK from ``q`` reaches the pre-grasp pose in front of the grasp (at one of
    the approach distances): the arm can come in along the approach axis."""
    for fraction in APPROACH_FRACTIONS:
        pre = position - fraction * PREGRASP_DISTANCE * R[:, 2]
        ik = solve_ik(world, pre, R, q, tol_position=APPROACH_TOL_POSITION,
                      tol_rotation=APPROACH_TOL_ROTATION)  # fmt: skip
        if ik.converged:
            return True
    return False
