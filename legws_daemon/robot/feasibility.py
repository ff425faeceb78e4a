"""Grasp feasibility: IK reachability of the grasp pose and a collision-free configuration.

For each grasp the symmetric equivalents of its orientation are tried, nearest to the home
orientation first, from the home configuration and then from a few fixed restarts; a grasp
is feasible when IK reaches one of them within tolerance and, in that configuration, the
robot touches neither the table nor any non-target object (contact with the target itself
is expected: the fingers straddle it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from legws_daemon.core.geometry import FloatArray, rot_z, rotation_angle
from legws_daemon.core.goals import GoalSet
from legws_daemon.robot.kinematics import solve_ik
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
    """

    name: str
    feasible: bool
    reason: str
    q: FloatArray


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
        out[name] = _check_one(world, name, goals.positions[i], rotations[i],
                               int(goals.symmetry[i]), goals.x0.rotation, seeds)  # fmt: skip
    world.set_q(q_home)
    return out


def _check_one(
    world: World,
    name: str,
    position: FloatArray,
    rotation: FloatArray,
    symmetry: int,
    reference: FloatArray,
    seeds: list[FloatArray],
) -> GraspCheck:
    best_err = np.inf
    best_q = seeds[0]
    reason = ""
    for seed in seeds:
        for R in symmetric_rotations(rotation, symmetry, reference):
            ik = solve_ik(
                world, position, R, seed, tol_position=TOL_POSITION / 5,
                tol_rotation=TOL_ROTATION / 5,
            )  # fmt: skip
            if ik.position_error > TOL_POSITION or ik.rotation_error > TOL_ROTATION:
                err = ik.position_error + 0.1 * ik.rotation_error
                if err < best_err and not reason.startswith("collides"):
                    best_err, best_q = err, ik.q
                    reason = (
                        f"out of reach: IK misses the grasp by {ik.position_error * 100:.1f} cm "
                        f"and {np.degrees(ik.rotation_error):.0f} deg"
                    )
                continue
            hits = world.arm_contacts(ignore=frozenset({name}))
            if not hits:
                return GraspCheck(name, True, "ok", ik.q)
            best_q = ik.q
            reason = f"collides with {hits[0][1]} ({hits[0][0]})"
    return GraspCheck(name, False, reason, best_q)
