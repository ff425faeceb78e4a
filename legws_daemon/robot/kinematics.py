"""Differential kinematics of the arm: damped least squares with joint limits.

One solver serves both uses: a velocity step (teleoperation, autonomous approach) and
inverse kinematics (iterated steps toward a pose). Orientation errors are rotation vectors
in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InfeasibleError
from legws_daemon.robot.world import World

#: Damping of the least-squares solve (m, rad): keeps steps bounded near singularities.
DAMPING = 0.02
#: Joint limits are kept this far inside the hardware range, rad.
LIMIT_MARGIN = 0.02
#: Gain turning the EE toward an orientation it is told to hold, 1/s (the stand-in's and the
#: real arm's Cartesian commands alike).
ORIENTATION_GAIN = 2.0
_DAMPING_EYE = DAMPING**2 * np.eye(6)


def rotation_error(R_current: FloatArray, R_target: FloatArray) -> FloatArray:
    """Rotation vector ``w`` with ``exp([w]) R_current = R_target`` (world frame)."""
    E = R_target @ R_current.T
    cos = np.clip((np.trace(E) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(cos))
    axis = np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    s = np.linalg.norm(axis)
    if s < 1e-9:
        if angle < 1e-6:
            return np.zeros(3)
        # angle near pi: axis from the symmetric part
        B = (E + np.eye(3)) / 2.0
        k = int(np.argmax(np.diag(B)))
        v = B[:, k] / np.sqrt(max(B[k, k], 1e-12))
        return np.asarray(v * angle, dtype=np.float64)
    return np.asarray(axis / s * angle, dtype=np.float64)


def small_rotation_error(R_current: FloatArray, R_target: FloatArray) -> FloatArray:
    """``sin(angle) * axis`` of ``R_target R_current^T``: the rotation error for holding an
    orientation (exact direction, magnitude ~ angle for small errors; cheap per tick)."""
    E = R_target @ R_current.T
    return 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])


def dls_joint_velocity(J: FloatArray, twist: FloatArray, damping: float = DAMPING) -> FloatArray:
    """``qdot = J^T (J J^T + damping^2 I)^-1 twist``."""
    A = J @ J.T
    A[np.diag_indices_from(A)] += damping**2
    return np.asarray(J.T @ np.linalg.solve(A, twist), dtype=np.float64)


@dataclass(frozen=True, slots=True)
class StepResult:
    """What one velocity step did."""

    qdot: FloatArray  # joint velocity applied, rad/s
    scale: float  # 1.0, or < 1 when joint speed limits scaled the motion down
    at_limit: bool  # a joint position limit was reached


def ready_posture(world: World) -> FloatArray:
    """The arm's nominal "ready" posture the redundancy is pulled toward (keeps joints off
    their limits): its description's."""
    return np.array(world.spec.ready_posture)


def posture_pull(world: World, q: FloatArray) -> FloatArray:
    """``POSTURE_GAIN * (ready - q)``, zero for the arm's free joints (the wrist roll
    follows the grasp yaw)."""
    pull = POSTURE_GAIN * (ready_posture(world) - q)
    pull[list(world.spec.free_joints)] = 0.0
    return pull


#: Gain of the null-space pull toward the ready posture, 1/s.
POSTURE_GAIN = 0.5


def velocity_step(world: World, twist: ArrayLike, dt: float, *, posture: bool = True) -> StepResult:
    """Move the arm by the EE twist ``[v (3), w (3)]`` for ``dt`` seconds.

    With ``posture``, the arm's redundancy drifts slowly toward :func:`ready_posture` in the
    exact null space of the EE task (it does not move the EE to first order). The joint
    velocity is then scaled down uniformly (direction kept) to respect the joint speed
    limits, and joint positions are clamped inside the limits.
    """
    J = world.jacobian()
    q = world.q
    pull = posture_pull(world, q) if posture else np.zeros(world.dof)
    tw = np.asarray(twist, dtype=np.float64)
    lo, hi = world.arm.lower + LIMIT_MARGIN, world.arm.upper - LIMIT_MARGIN
    qdot = _redundant_solve(J, tw, pull)
    q_next = q + qdot * dt
    blocked = ((q_next < lo) & (qdot < 0)) | ((q_next > hi) & (qdot > 0))
    any_blocked = bool(blocked.any())
    if any_blocked:
        # joints that would pass a limit stop there; the others take over their share
        free = ~blocked
        qdot = np.zeros(world.dof)
        qdot[free] = _redundant_solve(J[:, free], tw, pull[free])
    ratio = float((np.abs(qdot) / world.arm.speed_limits).max())
    scale = 1.0 if ratio <= 1.0 else 1.0 / ratio
    if scale != 1.0:
        qdot = qdot * scale
    q = q + qdot * dt
    clamped = np.minimum(np.maximum(q, lo), hi)
    world.set_q(clamped)
    return StepResult(qdot, scale, any_blocked or bool((clamped != q).any()))


#: Regularisation of the null-space projector: small enough that the projection is exact
#: to first order, large enough to stay finite at a singularity.
_PROJECTOR_EYE = 1e-9 * np.eye(6)


def _redundant_solve(J: FloatArray, twist: FloatArray, posture: FloatArray) -> FloatArray:
    """``J+ twist + (I - J# J) posture``: the damped ``J+ = J^T (J J^T + l^2 I)^-1`` for the
    task, the (nearly) undamped ``J#`` for the null-space projector.

    The damped projector would not be a projector: ``J (I - J+ J) posture`` is
    ``l^2 (J J^T + l^2 I)^-1 J posture``, a drift of the EE of up to centimetres a second
    near a singular direction, with a zero command.
    """
    JJt = J @ J.T
    task = J.T @ np.linalg.solve(JJt + _DAMPING_EYE, twist)
    if not posture.any():
        return np.asarray(task, dtype=np.float64)
    null = posture - J.T @ np.linalg.solve(JJt + _PROJECTOR_EYE, J @ posture)
    return np.asarray(task + null, dtype=np.float64)


def home_configuration(world: World, position: ArrayLike, rotation: ArrayLike) -> IKResult:
    """IK of the EE home pose, the solution nearest the arm's :func:`ready_posture` of a
    few seeds (the ready posture and the description's ``home_seeds``)."""
    ready = ready_posture(world)
    seeds = [ready, *(np.array(s) for s in world.spec.home_seeds)]
    best: IKResult | None = None
    for seed in seeds:
        r = solve_ik(world, position, rotation, seed, tol_position=1e-4, tol_rotation=1e-4)
        if r.converged and (
            best is None or np.linalg.norm(r.q - ready) < np.linalg.norm(best.q - ready)
        ):
            best = r
    if best is None:
        raise InfeasibleError("the EE home pose is out of the arm's reach")
    world.set_q(best.q)
    return best


@dataclass(frozen=True, slots=True)
class IKResult:
    q: FloatArray
    position_error: float
    rotation_error: float
    converged: bool


def solve_ik(
    world: World,
    position: ArrayLike,
    rotation: ArrayLike,
    q0: ArrayLike,
    *,
    tol_position: float = 1e-3,
    tol_rotation: float = 1e-2,
    max_iterations: int = 200,
) -> IKResult:
    """Iterate damped least-squares steps from ``q0`` toward an EE pose, within joint limits.

    Leaves the world at the returned configuration.
    """
    target_p = np.asarray(position, dtype=np.float64)
    target_R = np.asarray(rotation, dtype=np.float64)
    world.set_q(np.clip(np.asarray(q0, dtype=np.float64), world.arm.lower, world.arm.upper))
    lo, hi = world.arm.lower + LIMIT_MARGIN, world.arm.upper - LIMIT_MARGIN
    ep = er = np.inf
    for _ in range(max_iterations):
        dp = target_p - world.ee_position()
        dr = rotation_error(world.ee_rotation(), target_R)
        ep, er = float(np.linalg.norm(dp)), float(np.linalg.norm(dr))
        if ep < tol_position and er < tol_rotation:
            return IKResult(world.q, ep, er, True)
        # bounded Cartesian step for a well-behaved linearisation
        dp *= min(1.0, 0.05 / max(ep, 1e-12))
        dr *= min(1.0, 0.3 / max(er, 1e-12))
        dq = dls_joint_velocity(world.jacobian(), np.concatenate([dp, dr]), damping=0.05)
        world.set_q(np.clip(world.q + dq, lo, hi))
    return IKResult(world.q, ep, er, False)
