"""The layout-design problem (method.md §5): decision vector, objective, penalties, measures.

Decision vector: ``(x, y, yaw)`` of each movable object, normalised to ``[0, 1]``: ``x`` and
``y`` span the workspace bounds, ``yaw`` spans ``[-pi, pi)`` and wraps. Proposals outside
``[0, 1]`` are clipped (positions) or wrapped (yaw), never resampled.

Objective: the certificate ``J`` of the candidate goals' grasps minus additive penalties,
so an infeasible layout always loses to a feasible one:

* ``CONSTRAINT_WEIGHT`` per metre of constraint violation (bounds, clearance to every
  other object including fixed ones, distance from the EE home in the table plane);
* ``UNREACHABLE_PENALTY`` per grasp the reachability map screens out;
* ``INFEASIBLE_OFFSET`` once when either is non-zero.

Measures: mean pairwise distance between the movable objects, and the distance of their
centroid from the workspace centre.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.sim.reachability import ReachabilityMap

#: Penalty per metre of constraint violation (1 cm costs 1 unit of slack).
CONSTRAINT_WEIGHT = 100.0
#: Penalty per grasp the reachability screen rejects.
UNREACHABLE_PENALTY = 2.0
#: Paid once by every infeasible layout, so that it ranks below every feasible one.
INFEASIBLE_OFFSET = 10.0


@dataclass(frozen=True, slots=True)
class Evaluation:
    """Evaluation of a batch of ``B`` layouts."""

    objective: FloatArray  # (B,) J minus penalties
    certificate: FloatArray  # (B,) J alone
    violation: FloatArray  # (B,) metres of constraint violation
    unreachable: FloatArray  # (B,) grasps screened out
    measures: FloatArray  # (B, 2)

    @property
    def feasible(self) -> np.ndarray:
        return np.asarray((self.violation == 0.0) & (self.unreachable == 0))


class LayoutProblem:
    """Place ``movable`` objects of ``scene`` so that the candidate goals are legible.

    Args:
        scene: the scene; objects not in ``movable`` stay where the scene puts them.
        movable: the objects to place (default: the scene's candidate goals).
        params: model parameters of the certificate.
        screen: reachability map used to penalise unreachable grasps (``None``: no screen).

    The candidate goals certified are the movable objects.
    """

    def __init__(
        self,
        scene: Scene,
        movable: Sequence[str] | None = None,
        params: Params | None = None,
        screen: ReachabilityMap | None = None,
    ) -> None:
        names = tuple(movable) if movable is not None else scene.goal_names
        if len(names) < 2:
            raise InputError(
                f"expected at least 2 movable objects, got {len(names)}", field="--movable"
            )
        if len(set(names)) != len(names):
            raise InputError("an object is named twice", field="--movable")
        self.scene = scene
        self.constraints = LayoutConstraints.of(scene, names)
        self.names = names
        self.params = params or Params()
        self.screen = screen
        ws = scene.workspace
        self._lo = np.array([ws.x_range[0], ws.y_range[0], -np.pi])
        self._span = np.array(
            [ws.x_range[1] - ws.x_range[0], ws.y_range[1] - ws.y_range[0], 2 * np.pi]
        )
        self.centre = np.array([sum(ws.x_range) / 2, sum(ws.y_range) / 2])

    @property
    def dim(self) -> int:
        return 3 * len(self.names)

    def decode(self, x: ArrayLike) -> FloatArray:
        """Normalised solutions ``(B, 3K)`` to poses ``(B, K, 3)``; clips x, y and wraps yaw."""
        u = np.asarray(x, dtype=np.float64).reshape(-1, len(self.names), 3)
        u = u.copy()
        u[..., :2] = np.clip(u[..., :2], 0.0, 1.0)
        u[..., 2] = np.mod(u[..., 2], 1.0)
        return np.asarray(self._lo + u * self._span, dtype=np.float64)

    def encode(self, poses: ArrayLike) -> FloatArray:
        """Poses ``(B, K, 3)`` to normalised solutions ``(B, 3K)``."""
        p = np.asarray(poses, dtype=np.float64).copy()
        p[..., 2] = np.mod(p[..., 2] + np.pi, 2 * np.pi) - np.pi
        u = (p - self._lo) / self._span
        return np.asarray(u.reshape(len(u), -1), dtype=np.float64)

    def measures(self, poses: FloatArray) -> FloatArray:
        """Mean pairwise distance and centroid offset from the workspace centre, ``(B, 2)``."""
        xy = poses[..., :2]
        k = xy.shape[1]
        iu = np.triu_indices(k, 1)
        d = np.linalg.norm(xy[:, :, None] - xy[:, None, :], axis=-1)[:, iu[0], iu[1]]
        centroid = xy.mean(axis=1)
        return np.stack([d.mean(axis=1), np.linalg.norm(centroid - self.centre, axis=1)], axis=1)

    def evaluate(self, x: ArrayLike) -> Evaluation:
        """Objective, certificate, penalties and measures of normalised solutions ``(B, 3K)``."""
        poses = self.decode(x)
        sc = self.scene
        pos, rot, sym = sc.grasp_batch(self.names, poses)
        J = certify_batch(sc.home.position, sc.home.rotation, pos, rot, sym, self.params).objective
        violation = self.constraints.violation(poses)
        if self.screen is not None:
            unreachable = (~self.screen.screen(sc, self.names, poses)).sum(axis=1).astype(float)
        else:
            unreachable = np.zeros(len(poses))
        infeasible = (violation > 0) | (unreachable > 0)
        objective = (
            J
            - CONSTRAINT_WEIGHT * violation
            - UNREACHABLE_PENALTY * unreachable
            - INFEASIBLE_OFFSET * infeasible
        )
        return Evaluation(objective, J, violation, unreachable, self.measures(poses))

    def layout(self, solution: ArrayLike) -> Layout:
        """One normalised solution as a :data:`Layout` of the movable objects."""
        return self.constraints.to_layout(self.decode(solution)[0])

    def measure_ranges(
        self, rng: np.random.Generator, samples: int = 10_000
    ) -> list[tuple[float, float]]:
        """5th and 95th percentiles of the measures over uniformly random layouts."""
        m = self.measures(self.decode(rng.uniform(size=(samples, self.dim))))
        lo, hi = np.percentile(m, 5, axis=0), np.percentile(m, 95, axis=0)
        return [(float(lo[i]), float(hi[i])) for i in range(2)]
