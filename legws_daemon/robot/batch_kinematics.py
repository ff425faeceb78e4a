"""Kinematics of the arm for many configurations at once, in numpy.

The chain from the world to the EE site is read from the compiled MuJoCo model (fixed body
offsets and hinge axes), then forward kinematics, the EE Jacobian and damped least-squares
IK run on stacks of configurations: thousands of IK problems cost about as much as a few
done one at a time. Tested against MuJoCo's own kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, axis_rotation
from legws_daemon.errors import LegwsError
from legws_daemon.robot.kinematics import LIMIT_MARGIN
from legws_daemon.robot.world import World

#: Damping of the IK's least-squares step, as in :func:`~legws_daemon.robot.kinematics.solve_ik`.
IK_DAMPING = 0.05
#: Largest Cartesian step per IK iteration (m, rad), as in ``solve_ik``.
IK_MAX_STEP = (0.05, 0.3)


@dataclass(frozen=True, slots=True)
class _Link:
    """A hinge of the chain from the world to the EE site, after the fixed offset from the
    previous hinge (bodies without joints are folded into the offsets)."""

    pos: FloatArray  # (3,) offset from the previous hinge's frame
    rot: FloatArray  # (3, 3)
    joint: int  # index into the arm's joints
    axis: FloatArray  # (3,) hinge axis in the body frame
    anchor: FloatArray  # (3,) hinge position in the body frame
    q0: float  # qpos0 of the hinge (MuJoCo turns by q - qpos0)

    @property
    def about_z(self) -> bool:
        """A turn about the body's own z axis through its origin (every Sawyer joint; the
        others take the general path)."""
        return bool(np.array_equal(self.axis, [0.0, 0.0, 1.0]) and not self.anchor.any())


def _quat_matrix(q: ArrayLike) -> FloatArray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, dtype=np.float64))
    return out.reshape(3, 3)


def _chain(world: World) -> tuple[list[_Link], FloatArray, FloatArray]:
    """The hinges from the world to the EE site, root first, and the site's fixed offset
    (position, rotation) from the last hinge."""
    m = world.model
    qadr = [int(a) for a in world.arm.qpos]
    site = world.arm.ee_site
    bodies = []
    body = int(m.site_bodyid[site])
    while body != 0:
        bodies.append(body)
        body = int(m.body_parentid[body])
    links: list[_Link] = []
    pos, rot = np.zeros(3), np.eye(3)  # fixed offset accumulated since the last hinge
    for body in reversed(bodies):
        pos, rot = pos + rot @ m.body_pos[body], rot @ _quat_matrix(m.body_quat[body])
        first, count = int(m.body_jntadr[body]), int(m.body_jntnum[body])
        if count > 1:
            raise LegwsError(f"body {m.body(body).name} has more than one joint")
        for j in range(first, first + count):
            adr = int(m.jnt_qposadr[j])
            if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE or adr not in qadr:
                raise LegwsError(f"unexpected joint {m.joint(j).name} in the arm's chain")
            axis, anchor = np.array(m.jnt_axis[j]), np.array(m.jnt_pos[j])
            links.append(_Link(pos, rot, qadr.index(adr), axis, anchor, float(m.qpos0[adr])))
            pos, rot = np.zeros(3), np.eye(3)
    if sorted(lk.joint for lk in links) != list(range(world.dof)):
        raise LegwsError(f"the EE site's chain does not hold the arm's {world.dof} joints")
    site_pos = pos + rot @ m.site_pos[site]
    return links, site_pos, rot @ _quat_matrix(m.site_quat[site])


def _times(R: FloatArray, M: FloatArray) -> FloatArray:
    """``R @ M`` for a stack ``R`` (N, 3, 3) and one ``M`` (3, 3) or (3,): one BLAS call."""
    n = len(R)
    out = R.reshape(3 * n, 3) @ M
    return np.asarray(out.reshape(n, 3, 3) if M.ndim == 2 else out.reshape(n, 3))


class BatchKinematics:
    """Forward kinematics and the EE Jacobian of many configurations at once, in numpy."""

    def __init__(self, world: World) -> None:
        self.links, self.site_pos, self.site_rot = _chain(world)
        self.dof = world.dof

    def forward(self, q: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """EE positions ``(N, 3)``, rotations ``(N, 3, 3)`` and Jacobians ``(N, 6, n)``
        (``n`` the arm's DoF)."""
        n, dof = len(q), self.dof
        p = np.zeros((n, 3))
        R = np.broadcast_to(np.eye(3), (n, 3, 3))
        axes = np.empty((n, dof, 3))
        anchors = np.empty((n, dof, 3))
        for i, lk in enumerate(self.links):
            p = p + (lk.pos if i == 0 else _times(R, lk.pos))
            R = np.broadcast_to(lk.rot, (n, 3, 3)) if i == 0 else _times(R, lk.rot)
            angle = q[:, lk.joint] - lk.q0
            if lk.about_z:
                axes[:, lk.joint] = R[:, :, 2]
                anchors[:, lk.joint] = p
                c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
                turned = np.empty((n, 3, 3))
                turned[:, :, 0] = R[:, :, 0] * c + R[:, :, 1] * s
                turned[:, :, 1] = R[:, :, 1] * c - R[:, :, 0] * s
                turned[:, :, 2] = R[:, :, 2]
                R = turned
            else:
                a = _times(R, lk.anchor) + p
                axes[:, lk.joint] = _times(R, lk.axis)
                anchors[:, lk.joint] = a
                R = R @ axis_rotation(lk.axis, angle)
                p = a - _times(R, lk.anchor)
        ee = p + _times(R, self.site_pos)
        J = np.empty((n, 6, dof))
        r = ee[:, None, :] - anchors
        ax, ay, az = axes[:, :, 0], axes[:, :, 1], axes[:, :, 2]
        J[:, 0] = ay * r[:, :, 2] - az * r[:, :, 1]
        J[:, 1] = az * r[:, :, 0] - ax * r[:, :, 2]
        J[:, 2] = ax * r[:, :, 1] - ay * r[:, :, 0]
        J[:, 3], J[:, 4], J[:, 5] = ax, ay, az
        return ee, _times(R, self.site_rot), J


def batch_rotation_error(R: FloatArray, target: FloatArray) -> FloatArray:
    """Batched :func:`~legws_daemon.robot.kinematics.rotation_error`, ``(N, 3)``."""
    E = target @ R.transpose(0, 2, 1)
    cos = np.clip((np.trace(E, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]], 1)
    s = np.linalg.norm(axis, axis=1)
    out = axis / np.maximum(s, 1e-300)[:, None] * angle[:, None]
    small = s < 1e-9
    if np.any(small):
        for i in np.flatnonzero(small):
            if angle[i] < 1e-6:
                out[i] = 0.0
                continue
            B = (E[i] + np.eye(3)) / 2.0
            k = int(np.argmax(np.diag(B)))
            out[i] = B[:, k] / np.sqrt(max(B[k, k], 1e-12)) * angle[i]
    return np.asarray(out, dtype=np.float64)


def batch_ik(
    world: World,
    positions: FloatArray,
    rotations: FloatArray,
    q0: FloatArray,
    *,
    tol_position: float,
    tol_rotation: float,
    max_iterations: int,
    patience: int = 0,
    kinematics: BatchKinematics | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`~legws_daemon.robot.kinematics.solve_ik` for ``N`` targets at once.

    Args:
        positions: ``(N, 3)`` EE targets; rotations ``(N, 3, 3)``.
        q0: ``(n,)`` seed of every target, or ``(N, n)`` one per target (``n`` the DoF).
        patience: when positive, a target also stops once its error (the larger of the
            position and rotation errors, each relative to its tolerance) has not dropped
            by 1 % for this many iterations: stuck on a joint limit or out of reach.

    Returns:
        configurations ``(N, n)``, position and rotation errors ``(N,)`` at the last
        iterate (as ``solve_ik``: a target stops iterating once within the tolerances).
    """
    kin = kinematics or BatchKinematics(world)
    n = len(positions)
    lower, upper = world.arm.lower, world.arm.upper
    lo, hi = lower + LIMIT_MARGIN, upper - LIMIT_MARGIN
    q_out = np.array(np.broadcast_to(np.clip(q0, lower, upper), (n, world.dof)))
    ep_out = np.full(n, np.inf)
    er_out = np.full(n, np.inf)
    eye = IK_DAMPING**2 * np.eye(6)
    # the state of the targets still iterating, compacted as targets finish
    active = np.arange(n)
    q, P, Rt = q_out.copy(), positions, rotations
    best = np.full(n, np.inf)
    stalled = np.zeros(n, dtype=np.int64)
    for iteration in range(max_iterations + 1):
        ee, R, J = kin.forward(q)
        dp = P - ee
        dr = batch_rotation_error(R, Rt)
        ep, er = np.linalg.norm(dp, axis=1), np.linalg.norm(dr, axis=1)
        going = (ep >= tol_position) | (er >= tol_rotation)
        if patience > 0:
            err = np.maximum(ep / tol_position, er / tol_rotation)
            better = err < 0.99 * best
            best = np.where(better, err, best)
            stalled = np.where(better, 0, stalled + 1)
            going &= stalled < patience
        if iteration == max_iterations:  # errors of the returned configurations
            going[:] = False
        if not going.all():
            done = ~going
            q_out[active[done]], ep_out[active[done]], er_out[active[done]] = (
                q[done],
                ep[done],
                er[done],
            )
            active, q, P, Rt = active[going], q[going], P[going], Rt[going]
            dp, dr, J, ep, er = dp[going], dr[going], J[going], ep[going], er[going]
            best, stalled = best[going], stalled[going]
            if not len(active):
                break
        dp *= np.minimum(1.0, IK_MAX_STEP[0] / np.maximum(ep, 1e-12))[:, None]
        dr *= np.minimum(1.0, IK_MAX_STEP[1] / np.maximum(er, 1e-12))[:, None]
        twist = np.concatenate([dp, dr], axis=1)
        Jt = J.transpose(0, 2, 1)
        dq = (Jt @ np.linalg.solve(J @ Jt + eye, twist[:, :, None]))[:, :, 0]
        q = np.minimum(np.maximum(q + dq, lo), hi)
    return q_out, ep_out, er_out
