"""The one motion planner of assistance: IK of the goal pose, a joint-space move to the
pose in front of it, a straight move in.

Every approach the robot makes by itself — a pick after a commit, feeding, putting an
object back (a task's ``return`` or a reset) — and every grasp ``legws eval`` counts as
feasible come from here:

1. the feasibility check of the goal pose (:func:`~legws_daemon.robot.feasibility.
   check_grasp`: IK toward each symmetric equivalent from fixed seeds, the first
   collision-free configuration wins; cached per pose);
2. straight up to a carry height (``rise``), a joint-space move to the pose above the
   pre-pose (``carry``: :class:`~legws_daemon.robot.motion.JointMove`, so no wrist limit
   can stop it halfway, unlike a Cartesian move that also turns by ~2 rad), straight down
   to the pre-pose ``distance`` back along the approach axis;
3. a straight Cartesian move in, allowed below the envelope's fingertip floor down to the
   goal itself.

The joint-space move is checked before it is planned: at points of its straight line in
joint space (at least :data:`PATH_SAMPLES`, at most :data:`PATH_STEP` apart in every
joint) the fingertips stay above the table, the EE inside the workspace box, and the arm
touches nothing but the goal's object. Its end configuration is the one nearest the arm's
own that reaches the pose above, the pre-pose and the goal (touching nothing but the
target there); else one from the feasibility check's configuration or from fixed seeds; a
higher carry height, a via configuration and a shorter approach are tried when nothing
else passes, and last the way in from home, after a joint-space move home. The way home
goes straight up to the home height first. Every joint-space move is checked again when it
begins, from where the arm really is (:meth:`joint_path`), and fails after
:data:`JOINT_PATIENCE` without progress.

The planner works on its own twin of the robot's kinematic model (:meth:`World.twin`), so
planning never moves the robot's model, and it checks collisions against the layout it was
last given.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Mapping
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation, Slerp

from legws_daemon.core.geometry import FloatArray, Pose, rotation_angle
from legws_daemon.errors import InfeasibleError
from legws_daemon.robot.feasibility import GraspCheck, check_grasp, ik_seeds
from legws_daemon.robot.gripper import FINGERTIP_CLEARANCE, floor_height
from legws_daemon.robot.kinematics import home_configuration, solve_ik
from legws_daemon.robot.motion import (
    APPROACH_FRACTIONS,
    BOX_MARGIN,
    JOINT_PATIENCE,
    LIFT_HEIGHT,
    POSITION_TOLERANCE,
    PREGRASP_DISTANCE,
    ROTATION_TOLERANCE,
    JointMove,
    Move,
    Primitive,
    carry_height,
)
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.scene import ObjectPose

#: What a feasible goal is (a cached optimisation or plan made under another notion is
#: made again): IK, collisions, a straight approach, a clear way from home.
FEASIBILITY = "ik+collisions+approach+way-from-home+box-clearance"
#: IK tolerances of the poses on the way (the straight moves correct what is left), m, rad.
PRE_TOL_POSITION = 2e-3
PRE_TOL_ROTATION = 2e-2
#: Extra carry heights tried when the joint-space move is not clear at the first, m.
HIGHER = (0.0, LIFT_HEIGHT, 2 * LIFT_HEIGHT)
#: Fixed IK seeds tried after the arm's own and the feasibility check's configurations.
EXTRA_SEEDS = 4
#: A via configuration of a joint-space move stands this far below the box's ceiling, m.
VIA_MARGIN = 0.05
#: A via closer than this to either end of its move, in every joint, is no via (the arm is
#: there already; passing it changes nothing), rad.
VIA_MIN_STEP = 0.02
#: Points checked along a joint-space move (its ends included).
PATH_SAMPLES = 12
#: ... and at most this far apart in every joint, rad.
PATH_STEP = 0.05
#: A joint-space move keeps the fingertips at least this far above the table (the envelope
#: keeps 5 mm; the prediction by samples gets this margin), m.
PATH_CLEARANCE = 0.01
#: ... and inside the box's faces at least this far (or as far as its ends are, when they
#: are closer): a line that grazes a face (0.03 mm inside, as checked from the plan's
#: configurations; the arm's own line starts where the move before it ended, within its
#: tolerance) is cut to nothing there by the envelope, and the arm stalls on the face, m.
PATH_BOX_CLEARANCE = 0.0005
#: ... and a line the arm is to take later, from where an earlier move really ends (a via's
#: line onward, a withdrawal's): planned with more room, so that the arm, arriving within
#: its tolerance, finds it clear again when it is checked from there, m.
LATER_BOX_CLEARANCE = 0.002
#: Where a sample comes this close to the clearance of a face, m, the line is checked at
#: this many points more between it and its neighbours (the EE may swing several cm between
#: samples; a tangent to a face would pass between them unseen).
PATH_REFINE_DISTANCE = 0.01
PATH_REFINE = 8
#: A withdrawal's turn in place is made in steps of at most this angle, rad.
TURN_STEP = 0.35
#: Carries' arrivals kept for a withdrawal back the way the arm came.
MAX_ARRIVALS = 8
#: How far a withdrawal (:meth:`MotionPlanner.withdraw`) may go toward the other end of a
#: blocked joint-space move, as fractions of the horizontal way, the farthest first.
WITHDRAW_FRACTIONS = (1.0, 0.75, 0.5, 0.25)


class MotionPlanner:
    """Plans assistance motions on ``world`` (a twin of the robot's model: it is moved).

    Args:
        world: the planner's own kinematic model of the robot and its scene.
        home: the EE home pose; its IK is :attr:`q_home`, where every stage starts.
        box: the workspace box (of the hardware profile) the arm's moves stay in.

    Raises:
        InfeasibleError: the home pose is out of the arm's reach.
    """

    def __init__(self, world: World, home: Pose, box: Box) -> None:
        self.world = world
        self.box = box
        self.home_rotation = home.rotation
        self.home_position = home.position
        self.q_home = home_configuration(world, home.position, home.rotation).q
        self._seeds = ik_seeds(world, self.q_home)
        self._checks: dict[tuple[str, bytes, bytes, int], GraspCheck] = {}
        self._layout: dict[str, ObjectPose] = {}
        self._table = world.scene.workspace.table_height
        #: where the carries of the latest plans arrived (joint angles): a way the arm came,
        #: the last resort of a withdrawal (:meth:`withdraw`)
        self.arrivals: list[FloatArray] = []

    def set_layout(self, layout: Mapping[str, ObjectPose]) -> None:
        """The objects stand at ``layout`` now (collisions are checked against it; the
        checks made in another layout are forgotten)."""
        if dict(layout) == self._layout:
            return
        self._layout = dict(layout)
        self.world.set_layout(layout)
        self._checks.clear()

    def check(
        self,
        name: str,
        position: ArrayLike,
        rotation: ArrayLike,
        symmetry: int,
        hint: FloatArray | None = None,
    ) -> GraspCheck:
        """The feasibility check of the pose ``(position, rotation)`` (any of its
        ``symmetry`` equivalents) for the object or place ``name`` (contact with it is
        expected), cached until the layout changes.

        Args:
            hint: a configuration to try first (e.g. where the arm held the object).
        """
        p = np.asarray(position, dtype=np.float64)
        R = np.asarray(rotation, dtype=np.float64)
        key = (name, p.tobytes(), R.tobytes(), int(symmetry))
        found = self._checks.get(key)
        if found is None:
            seeds = self._seeds if hint is None else [np.asarray(hint, np.float64), *self._seeds]
            found = check_grasp(self.world, name, p, R, int(symmetry), self.home_rotation, seeds)
            if found.feasible:
                found = self._from_home(found, p)
            self.world.set_q(self.q_home)
            self._checks[key] = found
        return found

    def _from_home(self, check: GraspCheck, position: FloatArray) -> GraspCheck:
        """``check``, infeasible when no way in passes from the home configuration (where
        every stage starts): e.g. a link would sweep through an object on the way."""
        w = self.world
        w.set_q(self.q_home)
        start = (w.ee_position(), w.ee_rotation())
        ceiling = float(self.box.upper[2]) - BOX_MARGIN
        try:
            self.approach(
                check, position, start=start, q=self.q_home, box=self.box,
                carry_height=carry_height(position, check.rotation, ceiling),
            )  # fmt: skip
        except InfeasibleError as err:
            return replace(check, feasible=False, reason=f"no clear way from home: {err}")
        return check

    def approach(
        self,
        check: GraspCheck,
        position: ArrayLike,
        *,
        start: tuple[FloatArray, FloatArray],
        q: FloatArray,
        carry_height: float,
        box: Box,
        distance: float = PREGRASP_DISTANCE,
        labels: tuple[str, str] = ("approach", "reach"),
        patience: float | None = None,
    ) -> list[Primitive]:
        """The way in to ``position`` at the orientation ``check`` reached (see the module
        docstring): ``rise`` (when below the carry height), ``carry``, ``labels[0]`` (down
        to the pre-pose, when above it), ``labels[1]`` (in). When no way passes from where
        the arm is, it goes ``home`` first (a checked joint-space move) and takes the way in
        from there, which the feasibility check found.

        Args:
            check: the feasibility check of the goal pose (:meth:`check`).
            position: where the EE goes in to (the grasp, or a point short of it).
            start: the EE pose now; q: the joint angles now.
            carry_height: the first height tried for the joint-space move.
            box: the workspace box the moves stay in.
            distance: of the pre-pose back along the approach axis, m.
            labels: phase names of the move down to the pre-pose and of the move in.
            patience: of every move (see :class:`~legws_daemon.robot.motion.Move`).

        Raises:
            InfeasibleError: the goal pose failed the feasibility check (its reason), or
                no way in passes the checks.
        """
        if not check.feasible:
            raise InfeasibleError(f"'{check.name}': {check.reason}")
        R = check.rotation
        goal = np.asarray(position, dtype=np.float64)
        p, R_now = start
        q = np.asarray(q, dtype=np.float64)
        ignore = frozenset({check.name})
        # the check's configuration, where the move in ends when it is at the check's pose:
        # the reach's joint-space fallback (a straight line held short at a joint limit)
        self.world.set_q(check.q)
        at_check = float(np.linalg.norm(self.world.ee_position() - goal)) < POSITION_TOLERANCE
        fallback = check.q.copy() if at_check else None
        why = "nothing tried"
        path_why = ""  # the first joint-space move found blocked (what matters most)
        try:
            for fraction in APPROACH_FRACTIONS:
                pre = _off_the_faces(goal - fraction * distance * R[:, 2], goal, box)
                for extra in HIGHER:
                    z = min(max(float(carry_height), float(pre[2])) + extra, box.upper[2])
                    z = max(z, float(pre[2]))
                    rise = np.array([p[0], p[1], max(z, float(p[2]))])
                    q_start = self._near(rise, R_now, q) if rise[2] > p[2] else q
                    above = np.array([pre[0], pre[1], z])
                    ways: list[FloatArray] = []
                    for way in self._ways(q_start, check.q, above, pre, goal, R, ignore):
                        if isinstance(way, str):
                            why = way
                            continue
                        blocked = self._blocked(q_start, way, box, ignore)
                        if blocked is None:
                            return self._moves(p, R_now, rise, [way], pre, goal, R, labels,
                                               patience, fallback)  # fmt: skip
                        path_why = path_why or f"the joint-space move to it {blocked}"
                        ways.append(way)
                    for way in ways:  # not straight: through a configuration between
                        via = self._via(q_start, way, R_now, R, box, ignore)
                        if via is not None:
                            return self._moves(p, R_now, rise, [via, way], pre, goal, R,
                                               labels, patience, fallback)  # fmt: skip
            if not np.array_equal(q, self.q_home):  # the way in from home, going home first
                back = self.joint_path(q, self.q_home, box, frozenset({check.name}))
                w = self.world
                w.set_q(self.q_home)
                moves = self.approach(
                    check, goal, start=(w.ee_position(), w.ee_rotation()), q=self.q_home,
                    carry_height=carry_height, box=box, distance=distance, labels=labels,
                    patience=patience,
                )  # fmt: skip
                stall = JOINT_PATIENCE if patience is None else patience
                return [
                    *(JointMove("home", v, patience=stall) for v in back),
                    JointMove("home", self.q_home.copy(), patience=stall),
                    *moves,
                ]
        except InfeasibleError:
            pass
        finally:
            self.world.set_q(self.q_home)
        raise InfeasibleError(f"no way in to '{check.name}': {path_why or why}")

    def home(
        self, plan: list[Primitive], start: tuple[FloatArray, FloatArray], box: Box
    ) -> list[Primitive]:
        """Back to the home configuration after ``plan`` (which starts at the EE pose
        ``start``): straight up to the home height (``up``, when below it), then a
        joint-space move (``home``), whose path :meth:`joint_path` checks when it begins."""
        position, rotation = start
        for prim in plan:  # where the plan ends
            if isinstance(prim, Move):
                position, rotation = prim.position, prim.rotation
            elif isinstance(prim, JointMove):
                self.world.set_q(prim.q)
                position, rotation = self.world.ee_position(), self.world.ee_rotation()
                self.world.set_q(self.q_home)
        home = JointMove("home", self.q_home.copy(), patience=JOINT_PATIENCE)
        loose = 2 * POSITION_TOLERANCE
        z = min(max(float(self.home_position[2]), float(position[2])), float(box.upper[2]))
        if z - float(position[2]) <= loose:
            return [home]
        # straight up to the home height first: the joint-space move then starts clear of
        # the table (and is checked again from where the arm really is when it begins); a
        # rise the arm cannot complete (a wrist at its limit) is cut short, not a failure
        up = np.array([position[0], position[1], z])
        return [Move("up", up, rotation, loose, JOINT_PATIENCE, optional=True), home]

    def joint_path(
        self, q0: FloatArray, q1: FloatArray, box: Box, ignore: frozenset[str] = frozenset()
    ) -> list[FloatArray]:
        """Configurations to pass on the way ``q0 -> q1`` in joint space: none when the
        straight line is clear, else one via configuration (see :meth:`_via`).

        Called when a joint-space move begins, from where the arm really is (a Cartesian
        move before it may end in another configuration than the plan's IK predicted).

        Raises:
            InfeasibleError: neither the straight line nor one through a via is clear.
        """
        q0 = np.asarray(q0, dtype=np.float64)
        q1 = np.asarray(q1, dtype=np.float64)
        try:
            blocked = self._blocked(q0, q1, box, ignore)
            if blocked is None:
                return []
            via = self._via(q0, q1, self._rotation_at(q0), self._rotation_at(q1), box, ignore)
        finally:
            self.world.set_q(self.q_home)
        if via is None:
            raise InfeasibleError(f"no clear joint-space path: the straight one {blocked}")
        return [via]

    def withdraw(
        self, q0: FloatArray, q1: FloatArray, box: Box, ignore: frozenset[str] = frozenset()
    ) -> list[Move] | None:
        """Straight Cartesian moves that make the joint-space move ``q0 -> q1`` possible
        when :meth:`joint_path` finds none (the EE at the box's edge, where every joint line
        swings it out; a wrist far from ``q1``'s, whose joint line sweeps the fingers
        through a neighbour): from the EE at ``q0``, at its height and orientation, toward
        the EE at ``q1`` (horizontally; :data:`WITHDRAW_FRACTIONS` of the way, the farthest
        first), to the first point whose configuration has a clear way to ``q1``; failing
        that, all the way to the EE at ``q1`` and there a turn in place to its orientation
        (the joint move that is left only settles the arm); failing that, back to where a
        recent carry arrived (:meth:`_back`). ``None`` when none is reachable. The moves
        are optional (cut short where the arm stalls) and the joint move is checked again
        from where they really end."""
        q0 = np.asarray(q0, dtype=np.float64)
        q1 = np.asarray(q1, dtype=np.float64)
        if np.allclose(q0, q1, atol=1e-6):
            return None  # there already: nothing to withdraw from
        w = self.world
        try:
            w.set_q(q0)
            p0, R0 = w.ee_position(), w.ee_rotation()
            w.set_q(q1)
            p1 = w.ee_position()
            # at the other end's height when higher (a rise cut short at a wrist limit may
            # go on diagonally), else at its own
            heights = dict.fromkeys([max(float(p0[2]), float(p1[2])), float(p0[2])])
            R1 = self._rotation_at(q1)
            for z in (float(np.clip(h, box.lower[2], box.upper[2])) for h in heights):
                start = np.array([p0[0], p0[1], z])
                toward = np.array([p1[0], p1[1], z]) - start
                for fraction in WITHDRAW_FRACTIONS:
                    target = np.clip(start + fraction * toward, box.lower, box.upper)
                    if float(np.linalg.norm(target - p0)) < 2 * POSITION_TOLERANCE:
                        continue  # already there
                    q = self._near(target, R0, q0)
                    if q is q0:
                        continue  # out of reach at this orientation
                    if (
                        self._blocked(q, q1, box, ignore, LATER_BOX_CLEARANCE) is None
                        or self._via(q, q1, R0, R1, box, ignore) is not None
                    ):
                        return [self._withdrawal(target, R0)]
            turned = self._turn_there(q0, p1, R0, R1, q1, box, ignore)
            return turned if turned is not None else self._back(q1, box, ignore)
        finally:
            w.set_q(self.q_home)

    def _back(self, q1: FloatArray, box: Box, ignore: frozenset[str]) -> list[Move] | None:
        """Back the way the arm came: to the pose where a recent carry arrived (the latest
        first), from which a joint line to ``q1`` is clear — an arm that reached its grasp
        on another IK branch than home's (near the base) returns to the branch it knows."""
        w = self.world
        for q in reversed(self.arrivals):
            if self._blocked(q, q1, box, ignore, LATER_BOX_CLEARANCE) is not None:
                continue
            w.set_q(q)
            p, R = w.ee_position().copy(), w.ee_rotation().copy()
            if box.contains(p):
                return [self._withdrawal(p, R)]
        return None

    @staticmethod
    def _withdrawal(target: FloatArray, rotation: FloatArray) -> Move:
        return Move("withdraw", np.asarray(target, dtype=np.float64), rotation.copy(),
                    2 * POSITION_TOLERANCE, JOINT_PATIENCE, optional=True)  # fmt: skip

    def _turn_there(
        self,
        q0: FloatArray,
        p1: FloatArray,
        R0: FloatArray,
        R1: FloatArray,
        q1: FloatArray,
        box: Box,
        ignore: frozenset[str],
    ) -> list[Move] | None:
        """To the EE position at ``q1`` keeping the orientation, then a turn there to
        ``R1``, when both poses are reachable in turn and the rest has a clear way."""
        angle = float(rotation_angle(R0, R1))
        if not box.contains(p1) or angle < ROTATION_TOLERANCE:
            return None  # no turn to make (the straight withdrawal was tried already)
        q = self._near(p1, R0, q0)
        if q is q0:
            return None
        moves = [self._withdrawal(p1, R0)]
        # the turn in steps of at most TURN_STEP, each solved from the last (a far turn in
        # one solve misses from an arm whose wrist stands far from home's)
        steps = max(1, math.ceil(angle / TURN_STEP))
        turns = Rotation.from_matrix(np.stack([R0, R1]))
        path = Slerp([0.0, 1.0], turns)(np.linspace(0.0, 1.0, steps + 1)[1:]).as_matrix()
        for R in path:
            q_next = self._near(p1, R, q)
            if q_next is q:
                return None
            q = q_next
            moves.append(self._withdrawal(p1, R))
        if self._blocked(q, q1, box, ignore, LATER_BOX_CLEARANCE) is not None:
            return None
        return moves

    def _rotation_at(self, q: FloatArray) -> FloatArray:
        self.world.set_q(q)
        return self.world.ee_rotation()

    # --- pieces ---------------------------------------------------------------------
    def _moves(
        self,
        p: FloatArray,
        R_now: FloatArray,
        rise: FloatArray,
        joints: list[FloatArray],
        pre: FloatArray,
        goal: FloatArray,
        R: FloatArray,
        labels: tuple[str, str],
        patience: float | None,
        fallback: FloatArray | None = None,
    ) -> list[Primitive]:
        loose = 2 * POSITION_TOLERANCE
        moves: list[Primitive] = []
        if rise[2] - float(p[2]) > loose:
            moves.append(Move("rise", rise, R_now, loose, patience))
        stall = JOINT_PATIENCE if patience is None else patience
        moves += [JointMove("carry", q, patience=stall) for q in joints]
        q_above = joints[-1]
        self.arrivals = [*self.arrivals[-(MAX_ARRIVALS - 1) :], q_above.copy()]
        self.world.set_q(q_above)
        if float(np.linalg.norm(self.world.ee_position() - pre)) > loose:
            moves.append(Move(labels[0], pre, R, loose, patience))
        floor = float(goal[2]) - POSITION_TOLERANCE
        moves.append(Move(labels[1], goal, R, POSITION_TOLERANCE, patience, floor,
                          fallback=fallback))  # fmt: skip
        return moves

    def _ways(
        self,
        q_start: FloatArray,
        q_goal: FloatArray,
        above: FloatArray,
        pre: FloatArray,
        goal: FloatArray,
        R: FloatArray,
        ignore: frozenset[str],
    ) -> Iterator[FloatArray | str]:
        """Configurations above the pre-pose to move to in joint space (or why not): from
        the arm's own configuration forward (above, pre-pose, goal); from the feasibility
        check's goal configuration backward (pre-pose, above); forward from a few fixed
        seeds."""
        yield self._forward(q_start, above, pre, goal, R, ignore)
        try:
            yield self._solve(above, R, self._solve(pre, R, q_goal))
        except _IKMissError as miss:
            yield str(miss)
        for seed in self._seeds[1 : 1 + EXTRA_SEEDS]:
            yield self._forward(seed, above, pre, goal, R, ignore)

    def _forward(
        self,
        seed: FloatArray,
        above: FloatArray,
        pre: FloatArray,
        goal: FloatArray,
        R: FloatArray,
        ignore: frozenset[str],
    ) -> FloatArray | str:
        """From ``seed``: the configuration above the pre-pose, if the pre-pose and the
        goal follow from it by IK and the goal's configuration touches nothing but
        ``ignore``; else why not."""
        w = self.world
        try:
            q_above = self._solve(above, R, seed)
            q_goal = self._solve(goal, R, self._solve(pre, R, q_above))
        except _IKMissError as miss:
            return str(miss)
        w.set_q(q_goal)
        hits = w.arm_contacts(ignore=ignore)
        if hits:
            return f"at the goal the arm touches {hits[0][1]} ({hits[0][0]})"
        return q_above

    def _via(
        self,
        q0: FloatArray,
        q1: FloatArray,
        R0: FloatArray,
        R1: FloatArray,
        box: Box,
        ignore: frozenset[str],
    ) -> FloatArray | None:
        """A configuration ``q`` with clear straight joint-space lines ``q0 -> q -> q1``:
        up at the top of the workspace box above either end (at its orientation), above
        the middle of the way, the home configuration, or one of the fixed seeds; ``None``
        when none is clear."""
        w = self.world
        top = float(box.upper[2]) - VIA_MARGIN
        ends = []
        for q, R in ((q0, R0), (q1, R1)):
            w.set_q(q)
            ends.append((w.ee_position(), R, q))
        w.set_q(0.5 * (q0 + q1))
        middle = w.ee_position()
        candidates: list[tuple[FloatArray, FloatArray, FloatArray]] = [
            (np.array([p[0], p[1], top]), R, q) for p, R, q in ends
        ]
        candidates.append((np.array([middle[0], middle[1], top]), R1, 0.5 * (q0 + q1)))
        for position, R, seed in candidates:
            q = self._near(position, R, seed)
            if q is seed:
                continue  # out of reach
            if self._apart(q, q0, q1) and self._clear(q0, q, q1, box, ignore):
                return q
        for q in self._seeds:  # the home configuration first, then the fixed seeds
            if self._apart(q, q0, q1) and self._clear(q0, q, q1, box, ignore):
                return q
        return None

    @staticmethod
    def _apart(q: FloatArray, q0: FloatArray, q1: FloatArray) -> bool:
        """Whether ``q`` is a via of ``q0 -> q1`` at all: at least :data:`VIA_MIN_STEP` from
        each end in some joint. (Above an end already at the box's ceiling the IK lands on
        that end: its line to the other end can then pass the check by a hair where the
        straight one did not, and the arm, already there, would be sent to it for ever.)"""
        return bool(
            np.max(np.abs(q - q0)) >= VIA_MIN_STEP and np.max(np.abs(q - q1)) >= VIA_MIN_STEP
        )

    def _clear(
        self, q0: FloatArray, q: FloatArray, q1: FloatArray, box: Box, ignore: frozenset[str]
    ) -> bool:
        """Whether both straight joint-space lines ``q0 -> q -> q1`` are clear (the second
        with :data:`LATER_BOX_CLEARANCE`: it is checked again from where the arm reaches
        ``q``)."""
        return (
            self._blocked(q0, q, box, ignore) is None
            and self._blocked(q, q1, box, ignore, LATER_BOX_CLEARANCE) is None
        )

    def _blocked(
        self,
        q0: FloatArray,
        q1: FloatArray,
        box: Box,
        ignore: frozenset[str],
        clearance: float = PATH_BOX_CLEARANCE,
    ) -> str | None:
        """Why the straight joint-space line ``q0 -> q1`` is not clear, or ``None``.

        What is already so at ``q0`` does not count against the line (the arm may stand in
        an object's model after teleoperation, or low after a grasp): the line must not
        bring the fingertips lower, nor the EE further out of the box, than at ``q0``, nor
        touch anything else. Inside, it keeps :data:`PATH_BOX_CLEARANCE` from every face of
        the box, or as much as its ends have when that is less.
        """
        w = self.world
        w.set_q(q1)
        inside1 = _inside(w.ee_position(), box)
        w.set_q(q0)
        p0 = w.ee_position()
        floor0 = floor_height(w.ee_rotation(), self._table) - FINGERTIP_CLEARANCE
        inside0 = _inside(p0, box)
        # the least distance inside each face (negative: outside) the line may come to
        need = np.minimum(np.minimum(inside0, np.maximum(inside1, 0.0)), clearance)
        need = need - 1e-6
        below0 = max(floor0 + PATH_CLEARANCE - float(p0[2]), 0.0) + 1e-9
        ignore = ignore | {other for _, other in w.arm_contacts(ignore=ignore)}
        steps = max(PATH_SAMPLES, int(np.ceil(float(np.max(np.abs(q1 - q0))) / PATH_STEP)) + 1)
        samples = np.linspace(0.0, 1.0, steps)
        near_before = float(np.min(inside0 - need)) < PATH_REFINE_DISTANCE
        for before, s in itertools.pairwise(samples):
            q = q0 + s * (q1 - q0)
            w.set_q(q)
            p = w.ee_position().copy()
            inside = _inside(p, box)
            near = float(np.min(inside - need)) < PATH_REFINE_DISTANCE
            if near or near_before:  # close to a face: between the samples too
                for t in np.linspace(before, s, PATH_REFINE + 1)[1:-1]:
                    w.set_q(q0 + t * (q1 - q0))
                    why = _box_why(_inside(w.ee_position(), box), need, clearance)
                    if why is not None:
                        return why
                w.set_q(q)
            near_before = near
            why = _box_why(inside, need, clearance)
            if why is not None:
                return why
            floor = floor_height(w.ee_rotation(), self._table) - FINGERTIP_CLEARANCE
            if floor + PATH_CLEARANCE - float(p[2]) > below0:
                return f"brings the fingertips within {PATH_CLEARANCE * 100:g} cm of the table"
            hits = w.arm_contacts(ignore=ignore)
            if hits:
                return f"touches {hits[0][1]} ({hits[0][0]})"
        return None

    def _near(self, position: FloatArray, rotation: FloatArray, q: FloatArray) -> FloatArray:
        """IK of a pose from ``q`` (``q`` itself when it does not converge)."""
        try:
            return self._solve(position, rotation, q)
        except _IKMissError:
            return q

    def _solve(self, position: FloatArray, rotation: FloatArray, seed: FloatArray) -> FloatArray:
        """IK of a pose from ``seed`` (the world is left anywhere), or :class:`_IKMissError`."""
        ik = solve_ik(
            self.world, position, rotation, seed,
            tol_position=PRE_TOL_POSITION, tol_rotation=PRE_TOL_ROTATION,
        )  # fmt: skip
        if not ik.converged:
            raise _IKMissError(
                f"IK misses the pose at {np.round(position, 3).tolist()} by "
                f"{ik.position_error * 100:.1f} cm and {np.degrees(ik.rotation_error):.0f} deg"
            )
        return ik.q


def _inside(p: FloatArray, box: Box) -> FloatArray:
    """How far ``p`` stands inside each face of ``box`` (negative: outside), the lower
    faces' x, y, z, then the upper faces'."""
    return np.concatenate([p - box.lower, box.upper - p])


def _box_why(inside: FloatArray, need: FloatArray, clearance: float) -> str | None:
    """Why a point of a joint-space line with these distances inside the box's faces
    (:func:`_inside`) is not clear of them, or ``None``."""
    if np.all(inside >= need):
        return None
    if np.any(inside < np.minimum(need, 0.0)):
        return "leaves the workspace box"
    return f"comes within {clearance * 1000:g} mm of the workspace box"


def _off_the_faces(pre: FloatArray, goal: FloatArray, box: Box) -> FloatArray:
    """``pre`` moved toward ``goal`` until it stands :data:`BOX_MARGIN` inside the box's side
    faces, when it is on one — closer to it than that, inside or out — and ``goal`` stands
    inside the margin; else ``pre`` itself. The move down to a pre-pose on a face runs along
    it, where every step of the differential IK that strays a fraction of a millimetre out
    is cut to nothing by the box: the arm stalls there (the cereal box grasped from the side
    next to the base). A pre-pose farther out is left to the joint-space check, which
    refuses the way to it."""
    lo, hi = box.lower[:2], box.upper[:2]
    p, g = pre[:2], goal[:2]
    if np.any(g < lo + BOX_MARGIN) or np.any(g > hi - BOX_MARGIN):
        return pre
    on = (np.abs(p - lo) < BOX_MARGIN) | (np.abs(p - hi) < BOX_MARGIN)
    if not np.any(on):
        return pre
    t = 0.0  # the first point of the segment pre -> goal inside the margin (goal is)
    for k in np.flatnonzero(on):
        edge = lo[k] + BOX_MARGIN if abs(p[k] - lo[k]) < BOX_MARGIN else hi[k] - BOX_MARGIN
        t = max(t, float((edge - p[k]) / (g[k] - p[k])))
    return np.asarray(pre + t * (goal - pre), dtype=np.float64)


class _IKMissError(InfeasibleError):
    """An IK solve that did not converge (the planner tries another way)."""


def stand_in_planner(world: World) -> MotionPlanner:
    """A planner on ``world`` in the workspace box of the ``sim`` hardware profile: the
    feasibility ``legws eval``, ``legws optimize`` and ``legws plan`` judge layouts by."""
    from legws_daemon.formats.profile import load_profile_named

    return MotionPlanner(world, world.scene.home, Box.of(load_profile_named("sim").workspace))
