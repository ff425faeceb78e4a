"""The layout-design problem (method.md §5): decision vector, objective, penalties, measures.

Decision vector: ``(x, y, yaw)`` of each movable object, normalised to ``[0, 1]``: ``x`` and
``y`` span the workspace bounds, ``yaw`` spans ``[-pi, pi)`` and wraps. Proposals outside
``[0, 1]`` are clipped (positions) or wrapped (yaw), never resampled.

Goals: the grasps of the placed objects by default (:class:`GraspGoals`); a
:class:`GoalModel` generalises them to other goal poses (e.g. a task stage's place or dip
targets) and to goals that stay put (certified, not in the decision vector).

Objective: a score of the goals minus additive penalties, so an infeasible layout always
loses to a feasible one. The score is the slack certificate ``J`` (``objective="slack"``,
method.md §4, the default) or minus the commit objective ``K`` (``objective="commit"``,
method.md §9: the latest certified commit as a fraction of the way; smaller is earlier and
``K <= 1`` certifies every goal's commit) or the estimated commit rate ``R``
(``objective="rate"``: the mean over goals of the chance of a commit on the true goal before
arrival for the robot's speed-clipped user, ``core.commit.commit_chance_batch``; a search
surrogate, not a certificate, for tiers where ``K`` cannot reach 1) or minus the
estimated commit time ``T`` (``objective="time"``: the mean over goals of the noise-free
commit time in seconds, ``core.commit.commit_time_batch``; K is a fraction of the way and
does not see how long the way is). The penalties:

* ``CONSTRAINT_WEIGHT`` per metre of constraint violation (bounds, clearance to every
  other object including fixed ones, distance from the EE home in the table plane);
* ``UNREACHABLE_PENALTY`` per goal the reachability map screens out, and per goal that a
  designed-for operator's nominal never reaches (method.md §10: its K and T are infinite,
  so the score counts as :data:`NOT_REACHED_SCORE`);
* ``INFEASIBLE_OFFSET`` once when any is non-zero.

**Designed for people** (``operators``, method.md §10): every score is computed for each
operator with the robot's clip (``op.motion(params, clip=True)``) and the worst is searched:
J the smallest, K the largest, R the smallest, T the largest over the operators. Without
operators the scores are section 2's user's as above.

The search's K, R and T (and J under operators) come from the compiled kernels of
:mod:`.fast_objectives` (the same definitions as the numpy reference of
:mod:`legws_daemon.core`, to ~1e-12); J for section 2's user stays the numpy
:func:`~legws_daemon.core.certificate.certify_batch` (bit for bit as before).
What a run reports (``summary.json``, ``plan.json``) is computed with the numpy reference.

Measures: mean pairwise distance between the movable objects, and the distance of their
centroid from the workspace centre (goals that stay put count as points too).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.commit import COMMIT_FORMS, clipped_user
from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.design import OBJECTIVES
from legws_daemon.errors import InputError
from legws_daemon.robot.reachability import ReachabilityMap
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.scene import Layout, ObjectPose, Scene

#: Penalty per metre of constraint violation (1 cm costs 1 unit of slack).
CONSTRAINT_WEIGHT = 100.0
#: Penalty per grasp the reachability screen rejects.
UNREACHABLE_PENALTY = 2.0
#: Paid once by every infeasible layout, so that it ranks below every feasible one.
INFEASIBLE_OFFSET = 10.0
#: The searched score of a layout in which a designed-for operator's nominal never reaches
#: some goal (its K and T are infinite; the archive takes finite numbers only).
NOT_REACHED_SCORE = -100.0


@dataclass(frozen=True, slots=True)
class Evaluation:
    """Evaluation of a batch of ``B`` layouts."""

    objective: FloatArray  # (B,) score minus penalties
    certificate: FloatArray  # (B,) J alone
    violation: FloatArray  # (B,) metres of constraint violation
    unreachable: FloatArray  # (B,) grasps screened out
    measures: FloatArray  # (B, 2)
    commit: FloatArray | None = None  # (B,) K, with objective="commit"
    rate: FloatArray | None = None  # (B,) R, with objective="rate"
    time: FloatArray | None = None  # (B,) T in seconds, with objective="time"
    #: (B,) goals some designed-for operator's nominal never reaches (commit, rate, time)
    unreached: FloatArray | None = None

    @property
    def score(self) -> FloatArray:
        """What the search maximises before penalties: J, -K, R or -T."""
        if self.rate is not None:
            return self.rate
        if self.time is not None:
            return -self.time
        return self.certificate if self.commit is None else -self.commit

    @property
    def feasible(self) -> np.ndarray:
        ok = (self.violation == 0.0) & (self.unreachable == 0)
        if self.unreached is not None:
            ok &= self.unreached == 0
        return np.asarray(ok)


@dataclass(frozen=True, slots=True)
class GoalPoses:
    """Goal poses of ``B`` layouts with ``M`` goals each."""

    positions: FloatArray  # (B, M, 3)
    rotations: FloatArray  # (B, M, 3, 3)
    symmetry: IntArray  # (M,)


class GoalModel(ABC):
    """Where the certified goals are, given the poses of the objects being placed.

    Attributes:
        names: the goals, in the certificate's order.
    """

    names: tuple[str, ...]

    @abstractmethod
    def poses(self, objects: FloatArray) -> GoalPoses:
        """Goal poses for placed-object poses ``(B, K, 3)`` (the problem's ``names`` order)."""

    @abstractmethod
    def unreachable(self, screen: ReachabilityMap, objects: FloatArray) -> FloatArray:
        """``(B,)`` number of goals the reachability map screens out."""

    @property
    def anchors(self) -> FloatArray:
        """``(F, 2)`` table-plane positions of the goals that stay put (for the measures)."""
        return np.zeros((0, 2))


class GraspGoals(GoalModel):
    """The default goals: the grasp of every placed object (method.md §5)."""

    def __init__(self, scene: Scene, names: Sequence[str]) -> None:
        self.scene = scene
        self.names = tuple(names)

    def poses(self, objects: FloatArray) -> GoalPoses:
        pos, rot, sym = self.scene.grasp_batch(self.names, objects)
        return GoalPoses(pos, rot, sym)

    def unreachable(self, screen: ReachabilityMap, objects: FloatArray) -> FloatArray:
        ok = screen.screen(self.scene, self.names, objects)
        return np.asarray((~ok).sum(axis=1), dtype=np.float64)


class LayoutProblem:
    """Place ``movable`` objects of ``scene`` so that the candidate goals are legible.

    Args:
        scene: the scene; objects not in ``movable`` stay where ``base`` (or the scene)
            puts them.
        movable: the objects to place (default: the scene's candidate goals).
        params: model parameters of the certificate.
        screen: reachability map used to penalise unreachable goals (``None``: no screen).
        goals: the certified goals (default: the grasps of the movable objects, which
            must then be at least 2).
        base: poses of the objects that stay put (default: the scene file's).
        objective: ``"slack"`` (maximise J), ``"commit"`` (minimise K) or ``"rate"``
            (maximise the estimated commit rate R) or ``"time"`` (minimise the estimated
            commit time T).
        commit_form: the commit slack's form for ``"commit"`` (``core.commit``): the exact
            ``"sum"`` (default: the tightest honest one) or section 9's ``"min"``.
        operators: design for these people (method.md §10, with the robot's clip): the
            worst of them is searched. Empty: section 2's user.
    """

    def __init__(
        self,
        scene: Scene,
        movable: Sequence[str] | None = None,
        params: Params | None = None,
        screen: ReachabilityMap | None = None,
        *,
        goals: GoalModel | None = None,
        base: Mapping[str, ObjectPose] | None = None,
        objective: str = "slack",
        commit_form: str = "sum",
        operators: Sequence[OperatorModel] = (),
    ) -> None:
        if commit_form not in COMMIT_FORMS:
            raise InputError(
                f"unknown commit form {commit_form!r}; known: {', '.join(COMMIT_FORMS)}",
                field="--commit-form",
            )
        self.commit_form = commit_form
        if objective not in OBJECTIVES:
            raise InputError(
                f"unknown objective {objective!r}; known: {', '.join(OBJECTIVES)}",
                field="--objective",
            )
        self.objective = objective
        names = tuple(movable) if movable is not None else scene.goal_names
        if goals is None and len(names) < 2:
            raise InputError(
                f"expected at least 2 movable objects, got {len(names)}", field="--movable"
            )
        if not names:
            raise InputError("expected at least 1 object to place", field="--movable")
        if goals is not None and len(goals.names) < 2:
            raise InputError(f"expected at least 2 goals, got {len(goals.names)}", field="goals")
        if len(set(names)) != len(names):
            raise InputError("an object is named twice", field="--movable")
        self.scene = scene
        constraints = LayoutConstraints.of(scene, names)
        if base is not None:
            poses = scene.poses(base)
            fixed_xy = [[poses[n].x, poses[n].y] for n in constraints.fixed_names]
            constraints = replace(constraints, fixed_xy=np.array(fixed_xy).reshape(-1, 2))
        self.constraints = constraints
        self.names = names
        self.goals = goals if goals is not None else GraspGoals(scene, names)
        self.params = params or Params()
        self.operators = tuple(operators)
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
        anchors = self.goals.anchors
        if len(anchors):
            fixed = np.broadcast_to(anchors, (len(xy), *anchors.shape))
            xy = np.concatenate([xy, fixed], axis=1)
        k = xy.shape[1]
        iu = np.triu_indices(k, 1)
        d = np.linalg.norm(xy[:, :, None] - xy[:, None, :], axis=-1)[:, iu[0], iu[1]]
        centroid = xy.mean(axis=1)
        return np.stack([d.mean(axis=1), np.linalg.norm(centroid - self.centre, axis=1)], axis=1)

    def evaluate(self, x: ArrayLike) -> Evaluation:
        """Objective, certificate, penalties and measures of normalised solutions ``(B, 3K)``."""
        poses = self.decode(x)
        g = self.goals.poses(poses)
        J, K, R, T, unreached = self.scores(g)
        violation = self.constraints.violation(poses)
        if self.screen is not None:
            unreachable = self.goals.unreachable(self.screen, poses)
        else:
            unreachable = np.zeros(len(poses))
        lost = np.zeros(len(poses)) if unreached is None else unreached
        infeasible = (violation > 0) | (unreachable > 0) | (lost > 0)
        ev = Evaluation(np.zeros(len(poses)), J, violation, unreachable, self.measures(poses),
                        K, R, T, unreached)  # fmt: skip
        # the searched score (Evaluation.score: J, -K, R or -T) minus the penalties
        score = np.where(np.isfinite(ev.score), ev.score, NOT_REACHED_SCORE)
        objective = (
            score
            - CONSTRAINT_WEIGHT * violation
            - UNREACHABLE_PENALTY * (unreachable + lost)
            - INFEASIBLE_OFFSET * infeasible
        )
        return replace(ev, objective=objective)

    def scores(
        self, g: GoalPoses
    ) -> tuple[
        FloatArray, FloatArray | None, FloatArray | None, FloatArray | None, FloatArray | None
    ]:
        """``(J, K, R, T, unreached)`` of goal poses ``(B, M)``: J always, the objective's
        score (the others ``None``), and the goals an operator does not reach (``None``
        without operators or for the slack). With operators, the worst over them."""
        from legws_daemon.design.fast_objectives import Objectives  # numba: the search only

        home = self.scene.home
        args = (home.position, home.rotation, g.positions, g.rotations, g.symmetry, self.params)
        fast = Objectives(*args)
        kind, form = self.objective, self.commit_form
        if not self.operators:
            J = certify_batch(*args).objective  # numpy: J as before, whatever is searched
            if kind == "commit":
                return J, fast.commit(form=form).objective, None, None, None
            if kind == "rate":
                return J, None, fast.chance(clipped_user(self.params)).mean(axis=1), None, None
            if kind == "time":
                return J, None, None, fast.time(clipped_user(self.params)).mean(axis=1), None
            return J, None, None, None, None
        per_op: list[FloatArray] = []
        slacks: list[FloatArray] = []
        lost = np.zeros(len(g.positions))
        for op in self.operators:
            user = op.motion(self.params, clip=True)
            if kind == "slack":
                slacks.append(fast.slack(op, user).min(axis=1))
                continue
            slack, value, arrived = fast.scores(kind, op, user, form)
            slacks.append(slack.min(axis=1))
            per_op.append(value.max(axis=1) if kind == "commit" else value.mean(axis=1))
            lost = np.maximum(lost, (arrived == 0).sum(axis=1))
        J = np.min(slacks, axis=0)
        if kind == "slack":
            return J, None, None, None, None
        if kind == "commit":
            return J, np.max(per_op, axis=0), None, None, lost
        if kind == "rate":
            return J, None, np.min(per_op, axis=0), None, lost
        return J, None, None, np.max(per_op, axis=0), lost

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
