"""Geometric layout constraints (method.md §5) and random feasible layouts, vectorised.

Constraints on the movable objects' centres: inside ``x_range`` × ``y_range``; at least
``min_clearance`` from every other object centre (fixed objects included); at least
``min_home_distance`` from the EE home, measured in the table plane. Grasp reachability
and collisions are checked by the simulator (a later layer), not here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InfeasibleError, InputError
from legws_daemon.scene.scene import Layout, ObjectPose, Scene


@dataclass(frozen=True, slots=True)
class LayoutConstraints:
    """The constraints of one layout problem: which objects move, what stays fixed."""

    names: tuple[str, ...]
    x_range: tuple[float, float]
    y_range: tuple[float, float]
    min_clearance: float
    min_home_distance: float
    home_xy: FloatArray  # (2,)
    fixed_xy: FloatArray  # (F, 2) centres of the objects that do not move
    fixed_names: tuple[str, ...]

    @staticmethod
    def of(scene: Scene, movable: Sequence[str] | None = None) -> LayoutConstraints:
        """Constraints for moving ``movable`` (default: every movable object) in ``scene``."""
        names = tuple(movable) if movable is not None else scene.movable
        scene.check_names(names, "movable objects")
        poses = scene.poses()
        fixed = [n for n in scene.objects if n not in names]
        fixed_xy = np.array([[poses[n].x, poses[n].y] for n in fixed]).reshape(-1, 2)
        ws = scene.workspace
        return LayoutConstraints(
            names=names,
            x_range=ws.x_range,
            y_range=ws.y_range,
            min_clearance=ws.min_clearance,
            min_home_distance=ws.min_home_distance,
            home_xy=np.array(ws.ee_home.position[:2]),
            fixed_xy=fixed_xy,
            fixed_names=tuple(fixed),
        )

    def violation(self, poses: ArrayLike) -> FloatArray:
        """Total constraint violation in metres per layout, ``(B,)``; 0 means feasible.

        Args:
            poses: ``(B, K, 3)`` ``(x, y, yaw)`` of the constrained objects (``self.names``).
        """
        p = np.asarray(poses, dtype=np.float64)
        xy = p[..., :2]
        lo = np.array([self.x_range[0], self.y_range[0]])
        hi = np.array([self.x_range[1], self.y_range[1]])
        bounds = (np.maximum(lo - xy, 0.0) + np.maximum(xy - hi, 0.0)).sum(axis=(1, 2))
        k = xy.shape[1]
        iu = np.triu_indices(k, 1)
        d = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)[:, iu[0], iu[1]]
        clearance = np.maximum(self.min_clearance - d, 0.0).sum(axis=1)
        if len(self.fixed_xy):
            df = np.linalg.norm(xy[:, :, None, :] - self.fixed_xy[None, None], axis=-1)
            clearance += np.maximum(self.min_clearance - df, 0.0).sum(axis=(1, 2))
        dh = np.linalg.norm(xy - self.home_xy, axis=-1)
        home = np.maximum(self.min_home_distance - dh, 0.0).sum(axis=1)
        return np.asarray(bounds + clearance + home, dtype=np.float64)

    def problems(self, layout: Layout) -> list[str]:
        """Human-readable list of violated constraints of one layout (empty if feasible)."""
        out: list[str] = []
        xy = {n: np.array([layout[n].x, layout[n].y]) for n in self.names}
        (x0, x1), (y0, y1) = self.x_range, self.y_range
        for n, p in xy.items():
            if not (x0 <= p[0] <= x1 and y0 <= p[1] <= y1):
                out.append(f"{n} at ({p[0]:.3f}, {p[1]:.3f}) is outside x {x0}..{x1}, y {y0}..{y1}")
            dh = float(np.linalg.norm(p - self.home_xy))
            if dh < self.min_home_distance:
                out.append(f"{n} is {dh:.3f} m from the EE home (< {self.min_home_distance})")
        names = list(self.names)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                d = float(np.linalg.norm(xy[a] - xy[b]))
                if d < self.min_clearance:
                    out.append(f"{a} and {b} are {d:.3f} m apart (< {self.min_clearance})")
            for f, q in zip(self.fixed_names, self.fixed_xy, strict=True):
                d = float(np.linalg.norm(xy[a] - q))
                if d < self.min_clearance:
                    out.append(f"{a} and fixed {f} are {d:.3f} m apart (< {self.min_clearance})")
        return out

    def sample(
        self,
        n: int,
        rng: np.random.Generator,
        *,
        batch: int = 100_000,
        max_draws: int = 20_000_000,
    ) -> FloatArray:
        """``n`` layouts drawn uniformly from the feasible set, ``(n, K, 3)``.

        Positions uniform in the bounds, yaw uniform in ``[-pi, pi)``; a layout with any
        violated constraint is rejected whole, so the result is uniform over the feasible
        set. Objects are drawn one at a time and only for the candidate layouts that are
        still feasible, which makes the rejection cheap without changing the distribution.

        Raises:
            InfeasibleError: when ``max_draws`` candidate layouts yield fewer than ``n``.
        """
        k = len(self.names)
        lo = np.array([self.x_range[0], self.y_range[0]])
        hi = np.array([self.x_range[1], self.y_range[1]])
        c2 = self.min_clearance**2
        found: list[FloatArray] = []
        count = draws = 0
        while count < n:
            if draws >= max_draws:
                raise InfeasibleError(
                    f"found only {count} of {n} feasible layouts of {k} objects in {draws} "
                    f"random draws: the bounds x {self.x_range}, y {self.y_range} cannot hold "
                    f"them with {self.min_clearance} m clearance"
                )
            xy = np.empty((batch, k, 2))
            alive = np.arange(batch)
            draws += batch
            for j in range(k):
                p = rng.uniform(lo, hi, size=(len(alive), 2))
                ok = ((p - self.home_xy) ** 2).sum(axis=1) >= self.min_home_distance**2
                if len(self.fixed_xy):
                    df = ((p[:, None, :] - self.fixed_xy[None]) ** 2).sum(axis=2)
                    ok &= np.all(df >= c2, axis=1)
                if j:
                    dp = ((p[:, None, :] - xy[alive, :j]) ** 2).sum(axis=2)
                    ok &= np.all(dp >= c2, axis=1)
                alive = alive[ok]
                xy[alive, j] = p[ok]
                if not len(alive):
                    break
            if len(alive):
                yaw = rng.uniform(-np.pi, np.pi, size=(len(alive), k, 1))
                found.append(np.concatenate([xy[alive], yaw], axis=2))
                count += len(alive)
        return np.concatenate(found)[:n]

    def to_layout(self, poses: ArrayLike) -> Layout:
        """One row ``(K, 3)`` of poses as a :data:`Layout`."""
        p = np.asarray(poses, dtype=np.float64)
        return {
            n: ObjectPose(float(p[i, 0]), float(p[i, 1]), float(p[i, 2]))
            for i, n in enumerate(self.names)
        }

    def from_layout(self, layout: Layout) -> FloatArray:
        """A :data:`Layout` as a ``(K, 3)`` array in ``self.names`` order."""
        return np.array([[layout[n].x, layout[n].y, layout[n].yaw] for n in self.names])


def require_feasible(scene: Scene, layout: Layout, source: str) -> Layout:
    """``layout`` if the scene's objects satisfy every constraint with it, else an
    :class:`InputError` naming ``source`` and the first violation."""
    problems = LayoutConstraints.of(scene).problems(scene.poses(layout))
    if problems:
        raise InputError(f"infeasible layout: {problems[0]}", source=source)
    return layout
