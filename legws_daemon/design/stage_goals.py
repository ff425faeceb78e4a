"""The goals of one task-graph decision as a function of the placed objects' poses, batched.

Each candidate's goal is its target (:func:`legws_daemon.task.targets.target`) with the
EE starting at home: a ``pick`` — the object's grasp, which moves and turns with the
object; a ``place``, ``dip`` or ``feed`` at an object — a point above (or just inside) it,
gripper down, symmetry 0, which moves with the object's centre and ignores its yaw.
Candidates that are not placed (places, fixed objects, objects another stage placed, and
``return`` goals, which go back where the object was picked) keep the target they have
in the base layout: certified, never in the decision vector.

The held object is not known while planning (it is whichever the previous decision
picked), so place and dip heights assume the default held height of
:mod:`~legws_daemon.task.targets`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.design.problem import GoalModel, GoalPoses
from legws_daemon.errors import LegwsError
from legws_daemon.robot.reachability import ReachabilityMap
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.task.actions import action, target
from legws_daemon.task.decisions import DecisionPoint


class TargetGoals(GoalModel):
    """Targets of a decision's candidates, with the ``placed`` objects in the decision vector.

    Args:
        scene: the scene.
        point: the decision point (its candidates are the goals, in order).
        placed: candidates that are movable objects to place (the decision vector's order);
            none may be a ``return`` goal.
        base: poses of every movable object before placing (the goals that stay put take
            their targets from it).
    """

    def __init__(
        self, scene: Scene, point: DecisionPoint, placed: Sequence[str], base: Layout
    ) -> None:
        self.scene = scene
        self.names = point.candidates
        actions, stage_of = point.actions, point.stage_of
        index = {n: k for k, n in enumerate(placed)}
        for n in placed:
            if n not in actions or not action(actions[n]).follows_layout:
                raise LegwsError(f"'{n}' is not a candidate of '{point.label}' that can be placed")
        m = len(self.names)
        self._positions = np.zeros((m, 3))
        self._rotations = np.tile(np.eye(3), (m, 1, 1))
        self.symmetry = np.zeros(m, dtype=np.int64)
        self._pick: list[tuple[int, int]] = []  # (goal, placed object)
        self._lifted: list[tuple[int, int]] = []
        for j, n in enumerate(self.names):
            t = target(scene, base, stage_of[n], actions[n], n)
            self._positions[j], self._rotations[j] = t.position, t.rotation
            self.symmetry[j] = t.symmetry
            if n in index:
                (self._pick if action(actions[n]).takes_object else self._lifted).append(
                    (j, index[n])
                )
        moving = {j for j, _ in (*self._pick, *self._lifted)}
        still = [j for j in range(m) if j not in moving]
        self._anchors = self._positions[still, :2].copy()

    @property
    def anchors(self) -> FloatArray:
        return self._anchors

    def poses(self, objects: FloatArray) -> GoalPoses:
        b = len(objects)
        m = len(self.names)
        positions = np.array(np.broadcast_to(self._positions, (b, m, 3)))
        rotations = np.array(np.broadcast_to(self._rotations, (b, m, 3, 3)))
        if self._pick:
            goals, objs = map(list, zip(*self._pick, strict=True))
            names = [self.names[j] for j in goals]
            pos, rot, _ = self.scene.grasp_batch(names, objects[:, objs])
            positions[:, goals], rotations[:, goals] = pos, rot
        if self._lifted:
            goals, objs = map(list, zip(*self._lifted, strict=True))
            positions[:, goals, :2] = objects[:, objs, :2]
        return GoalPoses(positions, rotations, self.symmetry)

    def unreachable(self, screen: ReachabilityMap, objects: FloatArray) -> FloatArray:
        count = np.zeros(len(objects))
        if self._pick:
            goals, objs = map(list, zip(*self._pick, strict=True))
            names = [self.names[j] for j in goals]
            count += (~screen.screen(self.scene, names, objects[:, objs])).sum(axis=1)
        if self._lifted:
            g = self.poses(objects)
            goals = [j for j, _ in self._lifted]
            ok = screen.lookup(
                "top", g.positions[:, goals], g.rotations[:, goals], self.symmetry[goals]
            )
            count += (~ok).sum(axis=1)
        return count
