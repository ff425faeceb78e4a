"""The actions of a task graph as objects: what each aims at, how the robot carries it
out, and what it does to the task run.

``pick`` takes an object at its grasp; ``place`` lets the held object go above a container
or surface; ``dip`` dips held food into a bowl and keeps it; ``feed`` offers held food at
the mouth pose and lets go; ``return`` puts the held object back where it was taken. Each
is one :class:`TaskAction` with

- :meth:`~TaskAction.target`: the pose the observer infers over and assistance moves to;
- :meth:`~TaskAction.plan`: the assistance after a commit (the controller adds the move
  home), built with the one motion planner (:mod:`legws_daemon.robot.planner`) where the
  robot approaches something;
- :meth:`~TaskAction.apply`: its effect on the run (what is held, what is used up).

:func:`action` looks one up by its name in a task graph; there is no other dispatch and no
default.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol, TypedDict

import numpy as np

from legws_daemon.core.geometry import FloatArray, quat_to_matrix
from legws_daemon.errors import InputError
from legws_daemon.robot.motion import (
    BOX_MARGIN,
    JOINT_PATIENCE,
    LIFT_HEIGHT,
    POSITION_TOLERANCE,
    PREGRASP_DISTANCE,
    Grip,
    Move,
    Primitive,
    carry_height,
)
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.task.graph import ACTIONS, Action
from legws_daemon.task.targets import (
    DIP_DEPTH,
    DOWN,
    DROP_CLEARANCE,
    Held,
    Target,
    held_above_grasp,
    top_of,
)

if TYPE_CHECKING:  # the planner needs MuJoCo; reading a task graph does not
    from legws_daemon.robot.feasibility import GraspCheck
    from legws_daemon.robot.planner import MotionPlanner

#: Seconds the food stays at the mouth before the gripper lets go.
FEED_SECONDS = 2.0
#: The food is offered this far short of the mouth pose, along the approach axis, m: the
#: person takes the last centimetres (no gripper at the face).
BITE_DISTANCE = 0.04
#: Seconds food stays in the bowl at a dip.
SOAK_SECONDS = 0.5


class Run(Protocol):
    """What an action changes in a task run (:class:`~legws_daemon.task.runner.TaskRun`)."""

    held: str | None
    consumed: set[str]
    picked_from: dict[str, ObjectPose]


@dataclass(frozen=True, slots=True)
class PlanContext:
    """What a plan starts from.

    Attributes:
        position, rotation: the EE pose now; q: the joint angles now.
        planner: the motion planner (on the robot's model, in the current layout).
        held: what the gripper holds, as it was taken (``None``: nothing known).
        box: the adapter's workspace box.
    """

    position: FloatArray
    rotation: FloatArray
    q: FloatArray
    planner: MotionPlanner
    held: Held | None
    box: Box

    @property
    def ceiling(self) -> float:
        """The highest EE height a carry may use, m."""
        return float(self.box.upper[2]) - BOX_MARGIN

    def way_in(self, goal: FloatArray, check: GraspCheck) -> WayIn:
        """Where the planner's approach to ``goal`` starts and the height it carries at."""
        return {
            "start": (self.position, self.rotation),
            "q": self.q,
            "carry_height": carry_height(goal, check.rotation, self.ceiling),
            "box": self.box,
        }

    def home_after(self, plan: list[Primitive]) -> list[Primitive]:
        """The way home at the end of ``plan``."""
        return self.planner.home(plan, (self.position, self.rotation), self.box)


class WayIn(TypedDict):
    start: tuple[FloatArray, FloatArray]
    q: FloatArray
    carry_height: float
    box: Box


class TaskAction:
    """One kind of action (see the module docstring)."""

    name: ClassVar[Action]
    #: The action needs a held object (True) or an empty gripper (False).
    needs_held: ClassVar[bool]
    #: The gripper holds something after it (True), nothing (False), or as before (None).
    holds_after: ClassVar[bool | None]
    #: Its goal is an object's grasp, and the object is used up once done (a pick: the
    #: object must be movable, and is not a candidate again).
    takes_object: ClassVar[bool] = False
    #: Its candidates may be places of the scene (a place or a feed), not only objects.
    at_places: ClassVar[bool] = False
    #: Its goal moves with its candidate's pose in the layout (a layout design can place
    #: it); a return's goal is where the held object was taken, whatever the layout.
    follows_layout: ClassVar[bool] = True

    def available(self, goal: str, run: Run) -> bool:
        """Whether ``goal`` is a candidate of this action in the run's state now."""
        return not (self.takes_object and goal in run.consumed)

    def target(
        self,
        scene: Scene,
        layout: Mapping[str, ObjectPose],
        stage: str,
        name: str,
        held: str | None = None,
        picked_from: Mapping[str, ObjectPose] | None = None,
    ) -> Target:
        """The goal pose of candidate ``name`` (an object, or a place of the scene)."""
        places = {p.name: p for p in scene.spec.places}
        if name in places:
            p = places[name]
            R = quat_to_matrix(np.array(p.quaternion))
            return Target(name, stage, self.name, np.array(p.position), R, p.symmetry)
        return self._object_target(scene, scene.poses(dict(layout)), stage, name, held, picked_from)

    def _object_target(
        self,
        scene: Scene,
        poses: Mapping[str, ObjectPose],
        stage: str,
        name: str,
        held: str | None,
        picked_from: Mapping[str, ObjectPose] | None,
    ) -> Target:
        """The goal pose at an object (above it, gripper down, any yaw: place)."""
        position = top_of(scene, name, poses[name]) + np.array(
            [0.0, 0.0, held_above_grasp(scene, held) + DROP_CLEARANCE]
        )
        return Target(name, stage, self.name, position, DOWN.copy(), 0)

    def plan(self, target: Target, ctx: PlanContext) -> list[Primitive]:
        """The assistance that carries the action out (the move home follows)."""
        raise NotImplementedError

    def apply(self, run: Run, goal: str, layout: Layout) -> None:
        """Its effect on the run, once it is done."""
        if self.holds_after is False:
            run.held = None


def _down_and_up(
    position: FloatArray, rotation: FloatArray, down: str, at: Grip, up: str
) -> list[Primitive]:
    """Carry above ``position``, go down to it, do ``at`` there, come back up."""
    p = np.asarray(position, dtype=np.float64)
    R = np.asarray(rotation, dtype=np.float64)
    above = p + np.array([0.0, 0.0, LIFT_HEIGHT])
    return [
        Move("carry", above, R, tolerance=2 * POSITION_TOLERANCE),
        Move(down, p, R),
        at,
        Move(up, above, R),
    ]


def _grasp_target(name: str, stage: str, action: Action, scene: Scene, pose: ObjectPose) -> Target:
    arr = np.array([[[pose.x, pose.y, pose.yaw]]])
    pos, rot, sym = scene.grasp_batch([name], arr)
    return Target(name, stage, action, pos[0, 0], rot[0, 0], int(sym[0]))


class Pick(TaskAction):
    """Take the object: in to its grasp, close the gripper, lift it."""

    name = "pick"
    needs_held = False
    holds_after = True
    takes_object = True

    def _object_target(
        self,
        scene: Scene,
        poses: Mapping[str, ObjectPose],
        stage: str,
        name: str,
        held: str | None,
        picked_from: Mapping[str, ObjectPose] | None,
    ) -> Target:
        return _grasp_target(name, stage, self.name, scene, poses[name])

    def plan(self, target: Target, ctx: PlanContext) -> list[Primitive]:
        planner = ctx.planner
        check = planner.check(target.name, target.position, target.rotation, target.symmetry)
        lift = target.position + np.array([0.0, 0.0, LIFT_HEIGHT])
        lift[2] = min(lift[2], ctx.ceiling)
        return [
            *planner.approach(check, target.position, **ctx.way_in(target.position, check)),
            Grip("grasp", closed=True),
            # a lift a wrist limit holds short (a tall box grasped at its side) goes on home
            # from where it stopped: the way home rises first anyway
            Move("lift", lift, check.rotation, patience=JOINT_PATIENCE, optional=True),
        ]

    def apply(self, run: Run, goal: str, layout: Layout) -> None:
        run.held = goal
        run.consumed.add(goal)
        if goal in layout:
            run.picked_from[goal] = layout[goal]


class Place(TaskAction):
    """Carry the held object above the container or surface, lower it, let go, retreat."""

    name = "place"
    needs_held = True
    holds_after = False
    at_places = True

    def plan(self, target: Target, ctx: PlanContext) -> list[Primitive]:
        release = Grip("release", closed=False)
        return _down_and_up(target.position, ctx.rotation, "lower", release, "retreat")


class Dip(TaskAction):
    """Dip the held food just below the bowl's rim and bring it back up."""

    name = "dip"
    needs_held = True
    holds_after = None

    def _object_target(
        self,
        scene: Scene,
        poses: Mapping[str, ObjectPose],
        stage: str,
        name: str,
        held: str | None,
        picked_from: Mapping[str, ObjectPose] | None,
    ) -> Target:
        below = held_above_grasp(scene, held) - DIP_DEPTH
        position = top_of(scene, name, poses[name]) + np.array([0.0, 0.0, below])
        return Target(name, stage, self.name, position, DOWN.copy(), 0)

    def plan(self, target: Target, ctx: PlanContext) -> list[Primitive]:
        soak = Grip("soak", closed=True, seconds=SOAK_SECONDS, changes=False)
        return _down_and_up(target.position, ctx.rotation, "dip", soak, "raise")


class Feed(TaskAction):
    """Bring the held food in along the mouth pose's approach axis to just short of it,
    wait, let go, back off."""

    name = "feed"
    needs_held = True
    holds_after = False
    at_places = True

    def plan(self, target: Target, ctx: PlanContext) -> list[Primitive]:
        planner = ctx.planner
        check = planner.check(target.name, target.position, target.rotation, target.symmetry)
        R = check.rotation
        offer = target.position - BITE_DISTANCE * R[:, 2]
        back = PREGRASP_DISTANCE - BITE_DISTANCE
        way = ctx.way_in(target.position, check)
        return [
            *planner.approach(check, offer, distance=back, labels=("approach", "offer"), **way),
            Grip("wait", closed=True, seconds=FEED_SECONDS, changes=False),
            Grip("release", closed=False),
            Move("back_off", offer - back * R[:, 2], R),
        ]


class Return(TaskAction):
    """Put the held object back where it was taken: the pick, reversed."""

    name = "return"
    needs_held = True
    holds_after = False
    follows_layout = False

    def available(self, goal: str, run: Run) -> bool:
        return goal == run.held  # only the object in the gripper goes back

    def _object_target(
        self,
        scene: Scene,
        poses: Mapping[str, ObjectPose],
        stage: str,
        name: str,
        held: str | None,
        picked_from: Mapping[str, ObjectPose] | None,
    ) -> Target:
        origin = (picked_from or {}).get(name, poses[name])
        return _grasp_target(name, stage, self.name, scene, origin)

    def plan(self, target: Target, ctx: PlanContext) -> list[Primitive]:
        held = ctx.held if ctx.held is not None and ctx.held.name == target.name else None
        if held is not None:
            return put_back_plan(held.name, held.position, held.rotation, ctx, hint=held.q)
        check = ctx.planner.check(target.name, target.position, target.rotation, target.symmetry)
        return put_back_plan(target.name, target.position, check.rotation, ctx)


def put_back_plan(
    name: str,
    grasp: FloatArray,
    rotation: FloatArray,
    ctx: PlanContext,
    *,
    hint: FloatArray | None = None,
    patience: float | None = None,
) -> list[Primitive]:
    """Put the held ``name`` back at the grasp pose ``(grasp, rotation)`` it was taken at.

    From the EE pose now: rise straight up to the carry height (if below it); a joint-space
    move to above the pre-grasp pose at that height and straight down to it (the motion
    planner: no turn along a straight line, so no wrist limit on the way); in to the grasp
    pose; release; back off along the approach axis. ``patience`` goes to the moves before
    the release.

    Raises:
        InfeasibleError: the grasp pose or the way to it has no collision-free IK solution.
    """
    g = np.asarray(grasp, dtype=np.float64)
    R = np.asarray(rotation, dtype=np.float64)
    check = ctx.planner.check(name, g, R, 1, hint=hint)
    pre = g - PREGRASP_DISTANCE * check.rotation[:, 2]
    return [
        *ctx.planner.approach(check, g, **ctx.way_in(g, check), patience=patience),
        Grip("release", closed=False),
        Move("back_off", pre, check.rotation, 2 * POSITION_TOLERANCE),
    ]


_BY_NAME: dict[str, TaskAction] = {a.name: a for a in (Pick(), Place(), Dip(), Feed(), Return())}
assert set(_BY_NAME) == set(ACTIONS)


def action(name: str) -> TaskAction:
    """The action called ``name`` in a task graph; unknown names list the known ones."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise InputError(
            f"unknown action {name!r}; known: {', '.join(ACTIONS)}", field="action"
        ) from None


def target(
    scene: Scene,
    layout: Mapping[str, ObjectPose],
    stage: str,
    action_name: str,
    name: str,
    held: str | None = None,
    picked_from: Mapping[str, ObjectPose] | None = None,
) -> Target:
    """The goal pose of candidate ``name`` for the action ``action_name`` in ``layout``."""
    return action(action_name).target(scene, layout, stage, name, held, picked_from)
