"""A set of candidate goals (grasp poses) and the end-effector start pose."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from legws_daemon.core.geometry import (
    FloatArray,
    IntArray,
    Pose,
    canonical_sign,
    quat_to_matrix,
)
from legws_daemon.errors import InputError

#: A goal closer than this to the start position cannot be inferred (zero-length horizon).
MIN_GOAL_DISTANCE = 1e-3

#: Most candidate goals of one goal set. The certificate is over all ``M (M - 1)`` ordered
#: pairs (its largest array ``(M, M, 3)``: 8.94 GiB at 20,000 goals) and the commit
#: certificate over ``M x T x M`` (pairs times steps), so the cost grows with ``M^2``. 64 is
#: far above any table a Sawyer serves: its workspace (0.55 x 0.90 m of object centres)
#: holds at most 45 objects 0.12 m apart, and the paper's largest set has 8. At 64 goals
#: ``legws certify --commit`` computes in 0.3 s with an 85 MiB peak at the default
#: resolution (goals on the table, ~200 steps), 1 s and 370 MiB with a goal 4.4 m away
#: (1,760 steps); 2,000 goals used to take 74 s and then fail for memory.
MAX_GOALS = 64


def too_many_goals(m: int) -> str:
    """The one-line reason a set of ``m > MAX_GOALS`` goals is refused."""
    return (
        f"expected at most {MAX_GOALS} goals, got {m} (the certificates' cost grows with the "
        "square of the number of goals)"
    )


@dataclass(frozen=True, slots=True)
class GoalSet:
    """M >= 2 named grasp poses and the EE start pose ``x0``.

    Attributes:
        names: goal names, unique.
        positions: ``(M, 3)`` grasp positions.
        quaternions: ``(M, 4)`` grasp orientations ``[w, x, y, z]``.
        symmetry: ``(M,)`` symmetry orders (see :mod:`legws_daemon.core.geometry`).
        x0: start pose of the end effector.
    """

    names: tuple[str, ...]
    positions: FloatArray
    quaternions: FloatArray
    symmetry: IntArray
    x0: Pose

    def __post_init__(self) -> None:
        m = len(self.names)
        if m < 2:
            raise InputError(f"expected at least 2 goals, got {m}", field="goals")
        if m > MAX_GOALS:
            raise InputError(too_many_goals(m), field="goals")
        if len(set(self.names)) != m:
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise InputError(
                f"goal names must be unique, repeated: {', '.join(dup)}", field="goals"
            )
        pos = np.asarray(self.positions, dtype=np.float64)
        quat = np.asarray(self.quaternions, dtype=np.float64)
        sym = np.asarray(self.symmetry, dtype=np.int64)
        if pos.shape != (m, 3) or not np.all(np.isfinite(pos)):
            raise InputError(f"expected ({m}, 3) finite positions", field="goals.position")
        if quat.shape != (m, 4) or not np.all(np.isfinite(quat)):
            raise InputError(f"expected ({m}, 4) finite quaternions", field="goals.quaternion")
        norms = np.linalg.norm(quat, axis=1)
        if np.any(norms < 1e-9):
            i = int(np.argmin(norms))
            raise InputError("quaternion has zero norm", field=f"goals[{i}].quaternion")
        if sym.shape != (m,) or np.any(sym < 0):
            raise InputError("expected integers >= 0", field="goals.symmetry")
        dist = np.linalg.norm(pos - self.x0.position, axis=1)
        if np.any(dist < MIN_GOAL_DISTANCE):
            i = int(np.argmin(dist))
            raise InputError(
                f"goal '{self.names[i]}' is {dist[i]:.2g} m from x0; a goal must be at least "
                f"{MIN_GOAL_DISTANCE} m from the end-effector start",
                field=f"goals[{i}].position",
            )
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "quaternions", canonical_sign(quat / norms[:, None]))
        object.__setattr__(self, "symmetry", sym)

    @property
    def m(self) -> int:
        return len(self.names)

    @property
    def rotations(self) -> FloatArray:
        return quat_to_matrix(self.quaternions)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(
                f"unknown goal '{name}'; known: {', '.join(self.names)}", field="goal"
            ) from None

    @staticmethod
    def build(
        names: Sequence[str],
        positions: Sequence[Sequence[float]] | FloatArray,
        quaternions: Sequence[Sequence[float]] | FloatArray,
        x0: Pose,
        symmetry: Sequence[int] | IntArray | None = None,
    ) -> GoalSet:
        m = len(names)
        sym = np.ones(m, dtype=np.int64) if symmetry is None else np.asarray(symmetry)
        return GoalSet(
            tuple(names),
            np.asarray(positions, dtype=np.float64),
            np.asarray(quaternions, dtype=np.float64),
            sym.astype(np.int64),
            x0,
        )
