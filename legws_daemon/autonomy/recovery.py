"""Reset recovery: what the robot does with an object in its gripper when told to reset.

It puts the object back where it took it from (:func:`~legws_daemon.task.actions.
put_back_plan`: the pick reversed, through the motion planner, to the EE pose the gripper
closed at). When that pose is outside the workspace box or has no collision-free IK
solution, or a move of the put-back makes no progress for
:data:`~legws_daemon.autonomy.assistant.STALL_SECONDS`, the object is *set down* instead,
one step further at each failure (a :class:`~legws_daemon.autonomy.events.SetDown` warning
each time): turned back to the orientation it was carried in when the reset began and
lowered over the spot it came from; then straight down where it is, at the orientation it
has; then let go right there. Never from higher than
:data:`~legws_daemon.task.targets.MAX_SET_DOWN_DROP`: rather than that, the reset gives
control back (a warning), or, when no release pose is low enough at all, is refused once
(a person takes the object; the next reset opens the gripper where it is). Every plan ends
with the open gripper and the move home.
"""

from __future__ import annotations

import numpy as np

from legws_daemon.autonomy.assistant import STALL_SECONDS
from legws_daemon.autonomy.events import Emit, SetDown
from legws_daemon.core.geometry import FloatArray, rotation_angle
from legws_daemon.errors import InfeasibleError
from legws_daemon.robot.motion import (
    BOX_MARGIN,
    LIFT_HEIGHT,
    POSITION_TOLERANCE,
    PREGRASP_DISTANCE,
    ROTATION_TOLERANCE,
    Grip,
    Move,
    Primitive,
)
from legws_daemon.task.actions import PlanContext, put_back_plan
from legws_daemon.task.targets import MAX_SET_DOWN_DROP, Held

#: The moves of a put-back and of a set-down before the release: their failure sets the
#: object down (one step further each time).
PUT_BACK_PHASES = ("rise", "carry", "approach", "reach")
SET_DOWN_PHASES = ("turn_back", "over", "lower")


def set_down_plan(
    position: FloatArray,
    rotation: FloatArray,
    release: FloatArray,
    retreat_height: float,
    patience: float | None = None,
) -> list[Primitive]:
    """Set the held object down at the EE position ``release`` and let go, keeping the
    orientation ``rotation`` (no turn, so no wrist limit in the way): over ``release`` at
    the height the EE is at (or above it), straight down, release, straight up to
    ``retreat_height``. The move over ``release`` is left out when the EE is there
    already. ``patience`` goes to the moves before the release.
    """
    p = np.asarray(position, dtype=np.float64)
    R = np.asarray(rotation, dtype=np.float64)
    r = np.asarray(release, dtype=np.float64)
    loose = 2 * POSITION_TOLERANCE
    over = np.array([r[0], r[1], max(float(p[2]), float(r[2]))])
    up = np.array([r[0], r[1], max(float(retreat_height), float(r[2]))])
    plan: list[Primitive] = []
    if float(np.linalg.norm(over - p)) > loose:
        plan.append(Move("over", over, R, loose, patience))
    floor = float(r[2]) - POSITION_TOLERANCE
    plan += [
        Move("lower", r, R, POSITION_TOLERANCE, patience, floor),
        Grip("release", closed=False),
        Move("retreat", up, R, loose),
    ]
    return plan


class Recovery:
    """Plans resets for one scene and robot.

    Args:
        table_height: the table's height, m.
        emit: receives the :class:`SetDown` warnings.

    Release poses stay inside the workspace box of the plan's context.
    """

    def __init__(self, table_height: float, emit: Emit) -> None:
        self.table_height = table_height
        self._emit = emit
        #: a reset was refused: the next one lets go where it is
        self.drop_asked = False
        self._carried: FloatArray = np.eye(3)  # the EE orientation the reset began at
        self._fallbacks = 0  # how many times the running reset fell back

    def begin(self, ctx: PlanContext, held: Held | None) -> list[Primitive]:
        """The plan of a reset from the EE pose of ``ctx``, holding ``held`` (or nothing).

        Raises:
            InfeasibleError: it holds an object it can set down nowhere without dropping
                it from higher than ``MAX_SET_DOWN_DROP`` (refused once: a person takes it
                from the gripper, and the next reset opens the gripper where it is).
        """
        self._carried = ctx.rotation
        self._fallbacks = 0
        plan: list[Primitive] | None = None
        if held is not None:
            plan, reason = self._put_back(ctx, held)
            if plan is None:
                self._fallbacks = 1
                plan = self._set_down(ctx, held, over=True)
                if plan is not None:
                    self._warn(held, "reset", reason)
            if plan is None and not self.drop_asked:
                self.drop_asked = True
                raise InfeasibleError(
                    f"the robot holds '{held.name}' and cannot set it down within the "
                    f"workspace box: take it from the gripper, then reset again (the gripper "
                    f"opens where it is)"
                )
        self.drop_asked = False
        if plan is None:  # nothing held (or a person has taken it): open, go home
            return [Grip("open", closed=False), *ctx.home_after([])]
        return [*plan, *ctx.home_after(plan)]

    def fallback(
        self, ctx: PlanContext, held: Held | None, phase: str, error: str
    ) -> list[Primitive] | None:
        """A move of the reset failed before the release: the plan that sets the held
        object down instead, one step further each time, or ``None`` (nothing more to
        fall back to)."""
        if held is None or phase not in (*PUT_BACK_PHASES, *SET_DOWN_PHASES):
            return None
        self._fallbacks += 1
        plan: list[Primitive] | None = None
        if self._fallbacks == 1:
            plan = self._set_down(ctx, held, over=True)
        elif self._fallbacks == 2:
            plan = self._set_down(ctx, held, over=False)
        elif self._fallbacks == 3:
            plan = self._set_down(ctx, held, over=False, here=True)
        if plan is None:
            return None
        self._warn(held, phase, error)
        return [*plan, *ctx.home_after(plan)]

    def _put_back(self, ctx: PlanContext, held: Held) -> tuple[list[Primitive] | None, str]:
        """The put-back plan, or ``None`` and why not."""
        g, R = held.position, held.rotation
        pre = g - PREGRASP_DISTANCE * R[:, 2]
        if not (
            ctx.box.contains(g, POSITION_TOLERANCE)
            and ctx.box.contains(pre, 2 * POSITION_TOLERANCE)
        ):
            return None, "the grasp pose is outside the workspace box"
        try:
            plan = put_back_plan(held.name, g, R, ctx, hint=held.q, patience=STALL_SECONDS)
        except InfeasibleError as err:
            return None, str(err)
        return plan, ""

    @staticmethod
    def _in_box(p: FloatArray, ctx: PlanContext) -> FloatArray:
        """``p`` moved inside the workspace box, ``BOX_MARGIN`` from its faces."""
        lo, hi = ctx.box.lower + BOX_MARGIN, ctx.box.upper - BOX_MARGIN
        return np.asarray(np.clip(p, lo, hi), np.float64)

    def _set_down(
        self, ctx: PlanContext, held: Held, *, over: bool, here: bool = False
    ) -> list[Primitive] | None:
        """A plan that sets ``held`` down (the move home follows).

        ``over``: first turn back (in place) to the orientation the object was carried in
        when the reset began, then set it down at that orientation with its centre over
        the spot it came from. Otherwise at the orientation it has now: straight below the
        EE, or (``here``) released right where the EE is. ``None`` when the object's bottom
        would be more than ``MAX_SET_DOWN_DROP`` above the table at the release.
        """
        p = np.asarray(ctx.position, dtype=np.float64)
        R_now = ctx.rotation
        R = self._carried if over else R_now
        table = self.table_height
        # over the spot it came from, or straight below where the object is now
        spot = held.set_down_position(R, table, None if over else p + R_now @ held.center)
        release = p if here else self._in_box(spot, ctx)
        if held.bottom(release, R) - table > MAX_SET_DOWN_DROP:
            return None
        retreat = min(float(release[2]) + LIFT_HEIGHT, ctx.ceiling)
        patience = None if here else STALL_SECONDS
        plan: list[Primitive] = []
        if float(rotation_angle(R_now, R)) >= ROTATION_TOLERANCE:
            plan.append(Move("turn_back", p, R, 2 * POSITION_TOLERANCE, patience))
        return plan + set_down_plan(p, R, release, retreat, patience)

    def _warn(self, held: Held, phase: str, reason: str) -> None:
        self._emit(SetDown(held.name, phase, reason))
