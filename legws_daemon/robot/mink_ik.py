"""Joint velocities for an EE twist from mink's differential IK: a QP with exact limits.

Each call solves one small quadratic program (mink, solver daqp) for the joint displacement
``dq * dt`` of one control period:

- a ``FrameTask`` on the ``ee`` site, whose target is the pose the twist reaches in ``dt``
  (position ``p + v dt``, orientation ``exp([w] dt) R``, both in the world frame);
- a low-weight ``PostureTask`` toward a posture (default the arm's
  :func:`~legws_daemon.robot.kinematics.ready_posture`, its free joints held where they
  are), moved a fraction ``POSTURE_GAIN * dt`` of the way per call: it resolves the arm's
  redundancy and is the only regularisation;
- a ``ConfigurationLimit`` ``LIMIT_MARGIN`` inside the joint range (a joint covers at most
  95 % of its remaining distance to that band per period) and a ``VelocityLimit`` at
  the arm's speed limits (its description's): hard constraints, so the answer tracks
  the twist as well as the limits allow, up to the small posture weight (unlike
  :func:`~legws_daemon.robot.kinematics.velocity_step`, which stops a joint that would pass
  its limit and scales the whole motion down uniformly for the speed limits).

A joint already outside the margin band (e.g. at its hardware stop) is not driven further
out and not pulled back in: the band is widened to its current angle for that call, so
``dq = 0`` is always feasible and the QP never becomes infeasible because of the state.

This serves the real arm (:mod:`legws_daemon.hardware.bridge`), ~110 µs per call. The
stand-in keeps the hand-written damped least-squares step, ~30 µs, because it runs tens of
thousands of times per evaluation.
"""

from __future__ import annotations

import math

import mink
import mujoco
import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InfeasibleError, InputError, LegwsError
from legws_daemon.robot.kinematics import LIMIT_MARGIN, POSTURE_GAIN, ready_posture
from legws_daemon.robot.world import World

#: Weights of the EE position (1/m) and orientation (1/rad) errors in the QP objective.
POSITION_COST = 1.0
ORIENTATION_COST = 1.0
#: Weight of the posture task (1/rad). It is the QP's only regularisation: it acts like a
#: damped least-squares damping of this size in the task's range (0.02 would match
#: :data:`~legws_daemon.robot.kinematics.DAMPING` and track no better than ``velocity_step``),
#: while its pull in the null space does not depend on it. 0.005 tracks the twist to ~0.2 %
#: (median) away from limits and lets the speed limits bound the motion near singularities.
POSTURE_COST = 0.005
#: mink's extra Levenberg-Marquardt damping on the whole Hessian (negligible on purpose).
DAMPING = 1e-12
#: The QP backend (qpsolvers name); daqp was the fastest measured (dependencies.md).
SOLVER = "daqp"


class MinkVelocityIK:
    """Joint velocities realising an EE twist, from mink's QP with exact joint limits.

    Built once per kinematic model; tasks, limits and buffers are reused by every call.
    Not thread-safe (one configuration, one set of buffers): use one per control thread.

    Args:
        world: the compiled scene (its model, the arm's ``n`` joints, the ``ee`` site). Only
            the model is used: this object has its own ``MjData``, so ``world`` is not moved.
        posture: joint angles (n,) the redundancy is pulled toward (default the arm's ready
            posture; the entries of its free joints are ignored: those are held where they
            are).
        posture_cost: weight of the posture task, see :data:`POSTURE_COST`.
        margin: the joint position limits are kept this far inside the model's range, rad.

    Raises:
        LegwsError: the model's degrees of freedom are not exactly the arm's joints, in
            order, or an argument is out of range.
    """

    def __init__(
        self,
        world: World,
        *,
        posture: ArrayLike | None = None,
        posture_cost: float = POSTURE_COST,
        margin: float = LIMIT_MARGIN,
        speed_limits: ArrayLike | None = None,
    ) -> None:
        model = world.model
        arm = world.arm
        _N = self._n = world.dof
        self._free = list(world.spec.free_joints)
        if posture is None:
            posture = ready_posture(world)
        if speed_limits is None:
            speed_limits = arm.speed_limits
        if (
            model.nq != _N
            or model.nv != _N
            or not np.array_equal(arm.qpos, np.arange(_N))
            or not np.array_equal(arm.dof, np.arange(_N))
        ):
            raise LegwsError(
                f"the mink IK needs the arm's {_N} joints to be the model's only degrees of "
                f"freedom, in order; got nq={model.nq}, nv={model.nv}, arm qpos addresses "
                f"{arm.qpos.tolist()}"
            )
        target = np.asarray(posture, dtype=np.float64)
        if target.shape != (_N,) or not np.all(np.isfinite(target)):
            raise LegwsError(f"posture must be {_N} finite joint angles, got {target.tolist()}")
        if not (math.isfinite(posture_cost) and posture_cost > 0.0):
            raise LegwsError(f"posture_cost must be finite and > 0, got {posture_cost}")
        lower = np.asarray(arm.lower, dtype=np.float64) + margin
        upper = np.asarray(arm.upper, dtype=np.float64) - margin
        if not (math.isfinite(margin) and margin >= 0.0 and np.all(lower < upper)):
            raise LegwsError(f"margin must be >= 0 and leave every joint a range, got {margin}")

        self.configuration = mink.Configuration(model)
        self.site = model.site(arm.ee_site).name
        self._site_id = int(arm.ee_site)
        self._frame = mink.FrameTask(
            self.site, "site", position_cost=POSITION_COST, orientation_cost=ORIENTATION_COST
        )
        self._posture = mink.PostureTask(model, cost=posture_cost)
        self._position_limit = mink.ConfigurationLimit(model, min_distance_from_limits=margin)
        speeds = np.asarray(speed_limits, dtype=np.float64)
        if speeds.shape != (_N,) or not np.all(np.isfinite(speeds)) or np.any(speeds <= 0):
            raise LegwsError(f"speed_limits must be {_N} positive rad/s, got {speeds.tolist()}")
        self._velocity_limit = mink.VelocityLimit(
            model,
            {
                world.prefix + j: float(v)
                for j, v in zip(world.spec.joint_names, speeds, strict=True)
            },
        )
        self._tasks = [self._frame, self._posture]
        self._limits = [self._position_limit, self._velocity_limit]
        #: The margin band: joint limits the answer keeps to (rad).
        self.lower = lower
        self.upper = upper
        #: Joint speed limits the answer keeps to (rad/s).
        self.speed_limits = speeds
        # ConfigurationLimit reads its bounds from these arrays on every call; they are
        # widened in place to the current angle of a joint outside the band
        self._band_lower: FloatArray = self._position_limit.lower
        self._band_upper: FloatArray = self._position_limit.upper
        self._posture_target = target.copy()
        self._target = np.empty(7)  # [qw, qx, qy, qz, x, y, z]
        self._quat = np.empty(4)
        self._turn = np.empty(4)

    def joint_velocity(self, q: ArrayLike, twist: ArrayLike, dt: float) -> FloatArray:
        """Joint velocities (n,), rad/s, moving the EE by ``twist`` for ``dt`` seconds.

        Args:
            q: the arm's joint angles (n,), rad.
            twist: EE linear velocity (3,) m/s then angular velocity (3,) rad/s, world frame.
            dt: the control period, s.

        Returns:
            ``dq`` with ``|dq| <= speed_limits`` and ``q + dq * dt`` inside the margin band
            (a joint already outside it does not move further out). Exactly zero for a zero
            twist: a zero command moves nothing, not even toward the posture.

        Raises:
            InputError: ``q`` or ``twist`` has the wrong shape or a non-finite entry, or
                ``dt`` is not a positive finite number (a non-finite command is a bug
                upstream: it is refused, never turned into a motion or silently into zero).
            InfeasibleError: the QP solver found no solution (not expected: ``dq = 0`` is
                always feasible).
        """
        _N = self._n
        q = np.asarray(q, dtype=np.float64)
        tw = np.asarray(twist, dtype=np.float64)
        if q.shape != (_N,) or not np.isfinite(q).all():
            raise InputError(f"must be {_N} finite joint angles, got {q.tolist()}", field="q")
        if tw.shape != (6,) or not np.isfinite(tw).all():
            raise InputError(
                f"must be 6 finite numbers [v (m/s), w (rad/s)], got {tw.tolist()}", field="twist"
            )
        if not (math.isfinite(dt) and dt > 0.0):
            raise InputError(f"must be a positive finite period (s), got {dt}", field="dt")
        if not tw.any():
            return np.zeros(_N)

        cfg = self.configuration
        cfg.update(q)
        self._set_frame_target(tw, dt)
        # the free joints (the wrist roll) are held, not pulled
        self._posture_target[self._free] = q[self._free]
        self._posture.set_target(self._posture_target)
        self._posture.gain = min(1.0, POSTURE_GAIN * dt)
        lo = np.minimum(self.lower, q, out=self._band_lower)
        hi = np.maximum(self.upper, q, out=self._band_upper)
        try:
            v = mink.solve_ik(cfg, self._tasks, dt, SOLVER, damping=DAMPING, limits=self._limits)
        except mink.NoSolutionFound:
            raise InfeasibleError(
                f"the IK QP ({SOLVER}) found no joint velocity at q={np.round(q, 4).tolist()} "
                f"for twist {np.round(tw, 4).tolist()}, dt={dt:g}"
            ) from None
        if not np.isfinite(v).all():
            raise InfeasibleError(f"the IK QP ({SOLVER}) returned non-finite {v.tolist()}")
        # the solver's answer meets the limits up to its tolerance; these make them exact
        low = np.maximum(-self.speed_limits, (lo - q) / dt)
        high = np.minimum(self.speed_limits, (hi - q) / dt)
        return np.asarray(np.minimum(np.maximum(v, low), high), dtype=np.float64)

    def _set_frame_target(self, twist: FloatArray, dt: float) -> None:
        """The FrameTask target: the site's pose moved by ``twist`` for ``dt`` seconds."""
        data = self.configuration.data
        i = self._site_id
        target = self._target
        mujoco.mju_mat2Quat(self._quat, data.site_xmat[i])
        w = twist[3:]
        speed = math.hypot(w[0], w[1], w[2])
        if speed > 0.0:
            mujoco.mju_axisAngle2Quat(self._turn, w / speed, speed * dt)
            mujoco.mju_mulQuat(target[:4], self._turn, self._quat)  # world-frame rotation
        else:
            target[:4] = self._quat
        target[4:] = data.site_xpos[i] + twist[:3] * dt
        self._frame.set_target(mink.SE3(wxyz_xyz=target))
