"""Motion primitives: what an assistance plan is made of (pure data).

A plan is a list of primitives carried out one after the other by
:class:`~legws_daemon.autonomy.assistant.Assistant`: a straight-line move of the EE to a
pose (:class:`Move`), a joint-space move to a configuration (:class:`JointMove`), or a
gripper action (:class:`Grip`). The numbers of assistance live here, once.
"""

from __future__ import annotations

from dataclasses import dataclass

from legws_daemon.core.geometry import FloatArray

#: The pre-grasp pose stands this far back along the approach axis, metres ...
PREGRASP_DISTANCE = 0.08
#: ... or, where that is out of reach, these fractions of it (longest first).
APPROACH_FRACTIONS = (1.0, 0.75, 0.5)
#: Height an object is lifted after the grasp, metres.
LIFT_HEIGHT = 0.10
#: A move has arrived within these tolerances (metres, radians).
POSITION_TOLERANCE = 0.004
ROTATION_TOLERANCE = 0.05
#: A joint-space move has arrived when every joint is this close, radians.
JOINT_TOLERANCE = 0.002
#: Seconds for the gripper to close or open.
GRIP_SECONDS = 0.3
#: A joint-space move that makes no progress for this long fails (the envelope stops it
#: where the path would leave it), and an optional move (a lift, the rise before the way
#: home) is cut short, s.
JOINT_PATIENCE = 2.0
#: Targets of carries and of a reset's moves stay this far inside the workspace box, m.
BOX_MARGIN = 0.005


#: How long a move with a joint-space fallback may make no progress before it takes it, s.
FALLBACK_PATIENCE = 2.0


@dataclass(frozen=True, slots=True)
class Move:
    """Move the EE along a straight line to ``position`` with orientation ``rotation``.

    Attributes:
        label: the phase name (status ``phase``, events).
        position: (3,) target, m; rotation: (3, 3) target orientation.
        tolerance: arrival tolerance, m.
        patience: fail after this many active seconds without progress (``None``: only
            the timeout).
        floor: the lowest EE height this move may reach, m: set on the final approach of
            a grasp, whose target may lie below the envelope's fingertip floor (``None``:
            the envelope's floor).
        optional: when it makes no progress (its patience) the plan goes on with the next
            primitive instead of failing (a move that only gives the next one more room).
        fallback: joint angles at the target (the feasibility check's IK): when the
            straight line stalls for :data:`FALLBACK_PATIENCE` (a joint at its limit holds
            the arm short of it), a joint-space move there instead; ``None``: none.
    """

    label: str
    position: FloatArray
    rotation: FloatArray
    tolerance: float = POSITION_TOLERANCE
    patience: float | None = None
    floor: float | None = None
    optional: bool = False
    fallback: FloatArray | None = None


@dataclass(frozen=True, slots=True)
class JointMove:
    """Move the arm in joint space (a straight line between configurations) to ``q``."""

    label: str
    q: FloatArray  # (7,) rad
    tolerance: float = JOINT_TOLERANCE
    patience: float | None = None


@dataclass(frozen=True, slots=True)
class Grip:
    """Close (``closed=True``) or open the gripper, then wait for it."""

    label: str
    closed: bool
    seconds: float = GRIP_SECONDS
    changes: bool = True  # False: the gripper already is so; the step only waits


Primitive = Move | JointMove | Grip


def carry_height(goal: FloatArray, rotation: FloatArray, ceiling: float) -> float:
    """Height to carry toward a goal pose at: :data:`LIFT_HEIGHT` above the higher of the
    goal and its pre-pose (:data:`PREGRASP_DISTANCE` back along the approach axis, the
    rotation's z), at most ``ceiling``."""
    pre = goal - PREGRASP_DISTANCE * rotation[:, 2]
    return float(min(max(goal[2], pre[2]) + LIFT_HEIGHT, ceiling))
