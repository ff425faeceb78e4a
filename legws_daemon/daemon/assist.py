"""Assistance after a commit: a plan of motion primitives the robot carries out itself.

An action (``pick``, ``place``, ...) is a short list of primitives — move the EE to a
pose along a straight line, close or open the gripper, wait — executed one per tick by
:class:`Assistant`. A move is a proportional controller on position, speed-limited; the
orientation target is handed to the adapter as the orientation to hold (it converges with
the adapter's orientation gain). Each primitive has a timeout; a plan that cannot finish
fails and gives control back to the user. A move may also be given a *patience*: it
then fails as soon as it has made no progress for that long (a joint limit or the
workspace box holds the arm short of the pose), so that the caller can fall back at once
(a reset's put-back falls back to a set-down). All of it is pure math on the measured EE
pose: the loop sends the returned velocity through the adapter's safety clamp.

:class:`CancelDetector` decides when the user takes control back: the cancel button, or
the stick held against the assisted motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from legws_daemon.core.geometry import FloatArray, axis_rotation, rotation_angle
from legws_daemon.robot.feasibility import symmetric_rotations

#: The pre-grasp pose stands this far back along the approach axis, metres.
PREGRASP_DISTANCE = 0.08
#: Height an object is lifted after the grasp, metres.
LIFT_HEIGHT = 0.10
#: Proportional gain of a move, 1/s.
POSITION_GAIN = 2.0
#: A move has arrived within these tolerances (metres, radians).
POSITION_TOLERANCE = 0.004
ROTATION_TOLERANCE = 0.05
#: Seconds for the gripper to close or open.
GRIP_SECONDS = 0.3
#: A primitive that has not finished after this long fails the plan, seconds.
PRIMITIVE_TIMEOUT = 20.0
#: A move with a patience has made progress when it came this much closer (m, rad) ...
STALL_DISTANCE = 0.002
STALL_ANGLE = 0.02
#: ... and the patience of a reset's moves before it lets go of the object, seconds.
STALL_SECONDS = 2.0


@dataclass(frozen=True, slots=True)
class Move:
    """Move the EE to ``position`` with orientation ``rotation`` (3x3)."""

    label: str
    position: FloatArray
    rotation: FloatArray
    tolerance: float = POSITION_TOLERANCE
    #: fail after this many active seconds without progress (None: only the timeout)
    patience: float | None = None


@dataclass(frozen=True, slots=True)
class Grip:
    """Close (``closed=True``) or open the gripper, then wait for it."""

    label: str
    closed: bool
    seconds: float = GRIP_SECONDS
    changes: bool = True  # False: the gripper already is so; the step only waits


Primitive = Move | Grip


@dataclass(frozen=True, slots=True)
class AssistStep:
    """What the assistant wants this tick."""

    velocity: FloatArray  # (3,) EE linear velocity, m/s
    hold: FloatArray | None  # orientation to hold, or None for the current one
    grip: bool | None  # gripper command this tick (None: leave it)
    phase: str
    done: bool = False
    failed: str | None = None


def grasp_rotation(rotation: FloatArray, symmetry: int, current: FloatArray) -> FloatArray:
    """Of a symmetric grasp's equivalent orientations, the one nearest ``current``."""
    return symmetric_rotations(rotation, symmetry, current)[0]


#: Seconds the food stays at the mouth before the gripper lets go.
FEED_SECONDS = 2.0
#: The food is offered this far short of the mouth pose, along the approach axis, m: the
#: person takes the last centimetres (no gripper at the face).
BITE_DISTANCE = 0.04


def pick_plan(
    position: FloatArray, rotation: FloatArray, symmetry: int, current: FloatArray
) -> list[Primitive]:
    """Approach the pre-grasp pose, move in along the approach axis, grasp, lift."""
    R = grasp_rotation(np.asarray(rotation, dtype=np.float64), symmetry, current)
    p = np.asarray(position, dtype=np.float64)
    pre = p - PREGRASP_DISTANCE * R[:, 2]
    lift = p + np.array([0.0, 0.0, LIFT_HEIGHT])
    return [
        Move("approach", pre, R, tolerance=2 * POSITION_TOLERANCE),
        Move("reach", p, R),
        Grip("grasp", closed=True),
        Move("lift", lift, R),
    ]


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


def place_plan(position: FloatArray, current_rotation: FloatArray) -> list[Primitive]:
    """Carry the held object above ``position``, lower it, release it, retreat upward."""
    return _down_and_up(
        position, current_rotation, "lower", Grip("release", closed=False), "retreat"
    )


def dip_plan(position: FloatArray, current_rotation: FloatArray) -> list[Primitive]:
    """Carry the held food above the bowl, dip it to ``position``, bring it back up."""
    soak = Grip("soak", closed=True, seconds=0.5, changes=False)
    return _down_and_up(position, current_rotation, "dip", soak, "raise")


def feed_plan(
    position: FloatArray, rotation: FloatArray, symmetry: int, current: FloatArray
) -> list[Primitive]:
    """Bring the held food to the mouth along the approach axis, wait, let go, back off."""
    R = grasp_rotation(np.asarray(rotation, dtype=np.float64), symmetry, current)
    p = np.asarray(position, dtype=np.float64)
    pre = p - PREGRASP_DISTANCE * R[:, 2]
    offer = p - BITE_DISTANCE * R[:, 2]
    return [
        Move("approach", pre, R, tolerance=2 * POSITION_TOLERANCE),
        Move("offer", offer, R),
        Grip("wait", closed=True, seconds=FEED_SECONDS, changes=False),
        Grip("release", closed=False),
        Move("back_off", pre, R),
    ]


def return_plan(home_position: FloatArray, home_rotation: FloatArray) -> list[Primitive]:
    """Open the gripper and move back to the home pose."""
    return [
        Grip("open", closed=False),
        Move("home", np.asarray(home_position, np.float64), np.asarray(home_rotation, np.float64)),
    ]


def roll_first(current: FloatArray, target: FloatArray) -> FloatArray:
    """The orientation to roll to about the current approach axis (the EE's z) so that
    what is left to ``target`` is a pure tilt of the approach axis (about an axis
    perpendicular to both approach axes).

    A large turn split this way is two turns of one kind each: a roll, which the wrist's
    last joint does alone, and a tilt.
    """
    R0 = np.asarray(current, dtype=np.float64)
    R1 = np.asarray(target, dtype=np.float64)
    z0, z1 = R0[:, 2], R1[:, 2]
    axis = np.cross(z1, z0)
    s, c = math.sqrt(float(axis @ axis)), float(z0 @ z1)
    if s > 1e-9:
        axis, angle = axis / s, math.atan2(s, c)
    elif c > 0:
        return R1  # the approach axes agree: the roll is all of it
    else:
        axis, angle = R0[:, 0], math.pi  # opposite: tilt about the EE's x
    tilt_back = axis_rotation(axis, angle)  # takes z1 onto z0
    return np.asarray(tilt_back @ R1, dtype=np.float64)


def turn_moves(
    position: FloatArray,
    current: FloatArray,
    target: FloatArray,
    *,
    back: bool = False,
    patience: float | None = None,
) -> list[Move]:
    """Turn in place at ``position`` from ``current`` to ``target`` in two single-axis
    turns: a roll about the current approach axis, then a tilt of it (``roll``,
    ``tilt``); or, ``back``, the reverse order: first tilt the approach axis onto the
    target's, then roll about it (``tilt_back``, ``roll_back``). See :func:`roll_first`.
    """
    p = np.asarray(position, dtype=np.float64)
    R0 = np.asarray(current, dtype=np.float64)
    R1 = np.asarray(target, dtype=np.float64)
    loose = 2 * POSITION_TOLERANCE
    if back:
        mid = roll_first(R1, R0)  # the target's approach axis, a pure tilt away from R0
        return [Move("tilt_back", p, mid, loose, patience), Move("roll_back", p, R1, loose)]
    mid = roll_first(R0, R1)
    return [Move("roll", p, mid, loose, patience), Move("tilt", p, R1, loose, patience)]


def put_back_plan(
    grasp_position: FloatArray,
    grasp_rotation: FloatArray,
    position: FloatArray,
    rotation: FloatArray,
    carry_height: float,
    home_rotation: FloatArray,
    patience: float | None = None,
) -> list[Primitive]:
    """Put the held object back where it was grasped: the pick, reversed.

    From the EE pose now (``position``, ``rotation``): rise straight up to
    ``carry_height`` (if below it); carry the object level, at the orientation it has now,
    to above the pre-grasp pose; there, turn to the grasp orientation in place (a roll,
    then a tilt: :func:`turn_moves`); come straight down to the pre-grasp pose; move in
    along the approach axis to the grasp pose; release; back off along the approach axis;
    rise back to the carry height and turn in place to ``home_rotation`` (a tilt, then a
    roll), ready for a move home at a constant orientation.

    Why so: one straight-line move that also turns by ~2 rad (gripper-down to a side
    grasp, or back) can drive the differential kinematics into a wrist joint limit, after
    which the arm no longer follows the commanded motion. Turning in place, above
    everything, in two single-axis turns avoids that and never sweeps the object low
    through the scene. ``patience`` goes to the moves before the release (see
    :class:`Move`).
    """
    g = np.asarray(grasp_position, dtype=np.float64)
    R = np.asarray(grasp_rotation, dtype=np.float64)
    p = np.asarray(position, dtype=np.float64)
    R_now = np.asarray(rotation, dtype=np.float64)
    pre = g - PREGRASP_DISTANCE * R[:, 2]
    z = max(float(carry_height), float(p[2]))
    loose = 2 * POSITION_TOLERANCE
    plan: list[Primitive] = []
    if z - p[2] > loose:
        plan.append(Move("rise", np.array([p[0], p[1], z]), R_now, loose, patience))
    above = np.array([pre[0], pre[1], z])
    plan += [
        Move("carry", above, R_now, loose, patience),
        *turn_moves(above, R_now, R, patience=patience),
        Move("approach", pre, R, loose, patience),
        Move("reach", g, R, POSITION_TOLERANCE, patience),
        Grip("release", closed=False),
        Move("back_off", pre, R, loose),
        Move("up", above, R, loose),
        *turn_moves(above, R, home_rotation, back=True),
    ]
    return plan


def set_down_plan(
    position: FloatArray,
    rotation: FloatArray,
    release: FloatArray,
    retreat_height: float,
    home_rotation: FloatArray,
    patience: float | None = None,
) -> list[Primitive]:
    """Set the held object down at the EE position ``release`` and let go, keeping the
    orientation ``rotation`` (no turn, so no wrist limit in the way): over ``release``
    at the height the EE is at (or above it), straight down, release, straight up to
    ``retreat_height``, and turn there to ``home_rotation`` (:func:`turn_moves`, back).
    The move over ``release`` is left out when the EE is there already. ``patience``
    goes to the moves before the release.
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
    plan += [
        Move("lower", r, R, POSITION_TOLERANCE, patience),
        Grip("release", closed=False),
        Move("retreat", up, R, loose),
        *turn_moves(up, R, home_rotation, back=True),
    ]
    return plan


def home_move(home_position: FloatArray, home_rotation: FloatArray) -> Move:
    """Back to the home pose, where every stage's inference starts."""
    return Move(
        "home", np.asarray(home_position, np.float64), np.asarray(home_rotation, np.float64)
    )


@dataclass
class Assistant:
    """Executes a plan one tick at a time.

    Args:
        plan: the primitives, in order.
        speed: top EE speed of moves, m/s.
        dt: control period, s.
        target: the name of what the plan acts on (for events and logs).
    """

    plan: list[Primitive]
    speed: float
    dt: float
    target: str = ""
    index: int = 0
    elapsed: float = 0.0
    _gripped: bool = field(default=False, repr=False)
    # progress of the current move: best distance and angle since the last progress, and
    # the active seconds since then
    _best: tuple[float, float] | None = field(default=None, repr=False)
    _still: float = field(default=0.0, repr=False)

    @property
    def gripper_acted(self) -> bool:
        """Whether a gripper step of the plan has completed (an object was taken or let go)."""
        return any(isinstance(p, Grip) and p.changes for p in self.plan[: self.index])

    @property
    def finished(self) -> bool:
        return self.index >= len(self.plan)

    @property
    def phase(self) -> str:
        return self.plan[self.index].label if not self.finished else "done"

    def step(self, position: FloatArray, rotation: FloatArray, active: bool = True) -> AssistStep:
        """One tick from the measured EE pose.

        Args:
            position, rotation: measured EE pose.
            active: ``False`` pauses the plan (no valid input: the deadman holds the
                robot); the time of a paused tick does not count toward timeouts.
        """
        zero = np.zeros(3)
        if self.finished:
            return AssistStep(zero, None, None, "done", done=True)
        prim = self.plan[self.index]
        if not active:
            hold = prim.rotation if isinstance(prim, Move) else None
            return AssistStep(zero, hold, None, prim.label)
        self.elapsed += self.dt
        if self.elapsed > PRIMITIVE_TIMEOUT + (prim.seconds if isinstance(prim, Grip) else 0):
            return AssistStep(
                zero,
                None,
                None,
                prim.label,
                failed=f"'{prim.label}' timed out after {PRIMITIVE_TIMEOUT:g} s",
            )
        if isinstance(prim, Grip):
            if self.elapsed >= prim.seconds:
                return self._advance(zero, None, prim.closed, prim.label, position, rotation)
            return AssistStep(zero, None, prim.closed, prim.label)
        error = prim.position - np.asarray(position, dtype=np.float64)
        dist = math.sqrt(float(error @ error))
        angle = float(rotation_angle(np.asarray(rotation, dtype=np.float64), prim.rotation))
        if dist < prim.tolerance and angle < ROTATION_TOLERANCE:
            return self._advance(zero, prim.rotation, None, prim.label, position, rotation)
        if prim.patience is not None and self._stalled(dist, angle, prim.patience):
            return AssistStep(
                zero,
                None,
                None,
                prim.label,
                failed=f"'{prim.label}' made no progress for {prim.patience:g} s",
            )
        v = POSITION_GAIN * error
        norm = math.sqrt(float(v @ v))
        if norm > self.speed:
            v *= self.speed / norm
        return AssistStep(v, prim.rotation, None, prim.label)

    def _stalled(self, dist: float, angle: float, patience: float) -> bool:
        """Whether the move has come no closer (by :data:`STALL_DISTANCE` or
        :data:`STALL_ANGLE`) for ``patience`` active seconds."""
        best = self._best
        if best is None or dist < best[0] - STALL_DISTANCE or angle < best[1] - STALL_ANGLE:
            self._best = (dist, angle)
            self._still = 0.0
            return False
        self._still += self.dt
        return self._still >= patience - 1e-9

    def _advance(
        self,
        velocity: FloatArray,
        hold: FloatArray | None,
        grip: bool | None,
        label: str,
        position: FloatArray,
        rotation: FloatArray,
    ) -> AssistStep:
        self.index += 1
        self.elapsed = 0.0
        self._best = None
        self._still = 0.0
        return AssistStep(velocity, hold, grip, label, done=self.finished)


#: Cancel when the stick points against the assisted motion (cosine below this) ...
CANCEL_COSINE = -0.3
#: ... with at least this deflection ...
CANCEL_DEFLECTION = 0.5
#: ... for this long, seconds.
CANCEL_SECONDS = 0.4


class CancelDetector:
    """The user takes control back: cancel button, or the stick held against the motion."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self._against = 0.0

    def reset(self) -> None:
        self._against = 0.0

    def update(
        self, axes: FloatArray | None, assist_velocity: FloatArray, button: bool
    ) -> str | None:
        """Returns the reason to cancel (``button`` or ``opposed``), or ``None``."""
        if button:
            return "button"
        if axes is None:
            return None  # no input: the deadman pauses; it does not count either way
        u = np.asarray(axes, dtype=np.float64)
        un = math.sqrt(float(u @ u))
        vn = math.sqrt(float(assist_velocity @ assist_velocity))
        if (
            un >= CANCEL_DEFLECTION
            and vn > 1e-6
            and float(u @ assist_velocity) / (un * vn) < (CANCEL_COSINE)
        ):
            self._against += self.dt
        else:
            self._against = 0.0
        return "opposed" if self._against >= CANCEL_SECONDS - 1e-9 else None
