"""Streaming Boltzmann-rational observer with the commit rule (method.md section 3).

Per tick the observer keeps only the running path length ``L_t`` and the last position,
so an update is ``O(M)`` and never re-sums the path. The rotation part of
``d(x_t, g)`` is recomputed only when the end-effector orientation changes (it is held
during teleoperation).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.costs import path_costs, posterior
from legws_daemon.core.geometry import FloatArray, quat_to_matrix, se3_distance, symmetric_angle
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError

#: Orientation changes below this (rad) leave the rotation term of ``d(x_t, g)`` as it is: its
#: error is at most ``lambda_R`` times it (4e-6 m at the default), never accumulated.
ROTATION_RESOLUTION = 1e-4
_HALF_COS_RESOLUTION = math.cos(ROTATION_RESOLUTION / 2)


class IntentObserver:
    """Posterior over the goals of a :class:`GoalSet`, updated once per control tick.

    Example:
        >>> obs = IntentObserver(goals, Params())
        >>> p = obs.update(ee_position, ee_quaternion)
        >>> obs.committed  # index of the committed goal, or None
    """

    def __init__(self, goals: GoalSet, params: Params | None = None) -> None:
        self.goals = goals
        self.params = params if params is not None else Params()
        self._goal_pos = goals.positions.copy()
        self._goal_rot = goals.rotations
        self._sym = goals.symmetry
        self._lam = self.params.rotation_weight
        self._beta = self.params.beta
        self._p_thresh = self.params.p_thresh
        self._start_pos = goals.x0.position.copy()
        self._start_quat = goals.x0.quaternion.copy()
        self._dist_start = se3_distance(
            self._start_pos,
            goals.x0.rotation,
            self._goal_pos,
            self._goal_rot,
            self._sym,
            self._lam,
        )
        self._offset, self._scale = self._cost_affine()
        self._goal_list = [tuple(g) for g in self._goal_pos.tolist()]
        self._offset_list = self._offset.tolist()
        self._inv_scale = (1.0 / self._scale).tolist()
        self.reset()

    def _cost_affine(self) -> tuple[FloatArray, FloatArray]:
        """Write both cost forms as ``C = (L + d_now - offset) / scale``."""
        d0 = self._dist_start
        if self.params.cost == "dragan":
            return d0.copy(), np.full_like(d0, float(np.mean(d0)))
        return np.zeros_like(d0), d0.copy()

    def reset(self) -> None:
        """Start a new episode at ``x0`` (path length 0, uniform posterior, no commit)."""
        self._last: tuple[float, ...] = tuple(self._start_pos.tolist())
        self._length = 0.0
        self._ticks = 0
        self._set_rotation(self._start_quat)
        m = self.goals.m
        self._posterior = np.full(m, 1.0 / m)
        self._committed: int | None = None
        self._commit_tick: int | None = None

    @property
    def path_length(self) -> float:
        return self._length

    @property
    def ticks(self) -> int:
        return self._ticks

    @property
    def posterior(self) -> FloatArray:
        return self._posterior.copy()

    @property
    def committed(self) -> int | None:
        """Index of the committed goal, or ``None`` while undecided."""
        return self._committed

    @property
    def commit_tick(self) -> int | None:
        return self._commit_tick

    def update(self, position: ArrayLike, quaternion: ArrayLike | None = None) -> FloatArray:
        """Add one end-effector pose to the path and return the posterior ``(M,)``.

        Args:
            position: EE position ``(3,)``.
            quaternion: EE orientation ``[w, x, y, z]``; ``None`` keeps the last one.

        Raises:
            InputError: for a non-finite position or quaternion (the state is unchanged).
        """
        # Per-tick work is a handful of float operations per goal; plain Python floats beat
        # numpy's per-call overhead at the M of a tabletop (2..16 goals).
        try:
            x, y, z = (float(v) for v in position)  # type: ignore[union-attr, arg-type]
        except (TypeError, ValueError):
            raise InputError(f"expected a position of 3 numbers, got {position!r}") from None
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise InputError(f"expected a finite position, got {position!r}")
        if quaternion is not None:
            q = np.asarray(quaternion, dtype=np.float64)
            if q.tobytes() != self._rot_bytes:
                if q.shape != (4,) or not np.all(np.isfinite(q)) or not np.any(q):
                    raise InputError(f"expected a finite non-zero quaternion, got {quaternion!r}")
                if self._turned(q):
                    self._set_rotation(q)
        lx, ly, lz = self._last
        length = self._length + math.sqrt((x - lx) ** 2 + (y - ly) ** 2 + (z - lz) ** 2)
        here = (x, y, z)
        costs = [
            (length + math.dist(here, g) + r - o) * inv
            for g, r, o, inv in zip(
                self._goal_list, self._rot_list, self._offset_list, self._inv_scale, strict=True
            )
        ]
        best_cost = min(costs)
        beta = self._beta
        weights = [math.exp(-beta * (c - best_cost)) for c in costs]
        total = math.fsum(weights)
        post = np.array(weights) / total
        self._length = length
        self._last = here
        self._posterior = post
        self._ticks += 1
        if self._committed is None:
            best = int(post.argmax())
            if post[best] >= self._p_thresh:
                self._committed = best
                self._commit_tick = self._ticks
        return post

    def _turned(self, q: FloatArray) -> bool:
        """Whether ``q`` is more than :data:`ROTATION_RESOLUTION` from the orientation the
        rotation term was last computed for (a held orientation jitters in its last
        digits every tick; the term is not recomputed for that)."""
        a: list[float] = q.tolist()
        b: list[float] = self._rot_quat.tolist()
        dot = abs(sum(x * y for x, y in zip(a, b, strict=True)))
        norms = math.sqrt(sum(x * x for x in a) * sum(y * y for y in b))
        return dot < norms * _HALF_COS_RESOLUTION

    def _set_rotation(self, q: FloatArray) -> None:
        self._rot_term = self._lam * symmetric_angle(quat_to_matrix(q), self._goal_rot, self._sym)
        self._rot_list = self._rot_term.tolist()
        self._rot_quat = q.copy()
        self._rot_bytes = self._rot_quat.tobytes()


def posterior_of_path(
    goals: GoalSet,
    params: Params,
    positions: ArrayLike,
    quaternion: ArrayLike | None = None,
) -> FloatArray:
    """Posterior at the end of a whole path ``(K, 3)`` (starting after ``x0``), from scratch.

    The reference the streaming observer is tested against: it re-sums the path.
    """
    path = np.vstack([goals.x0.position[None], np.asarray(positions, dtype=np.float64)])
    length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    q = goals.x0.quaternion if quaternion is None else np.asarray(quaternion, dtype=np.float64)
    dist_now = se3_distance(
        path[-1],
        quat_to_matrix(q),
        goals.positions,
        goals.rotations,
        goals.symmetry,
        params.rotation_weight,
    )
    dist_start = se3_distance(
        goals.x0.position,
        goals.x0.rotation,
        goals.positions,
        goals.rotations,
        goals.symmetry,
        params.rotation_weight,
    )
    return posterior(path_costs(length, dist_now, dist_start, params.cost), params.beta)
