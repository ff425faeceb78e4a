"""Assistance after a commit: a plan of motion primitives the robot carries out itself.

An action (``pick``, ``place``, ...) is a short list of primitives — move the EE to a
pose along a straight line, close or open the gripper, wait — executed one per tick by
:class:`Assistant`. A move is a proportional controller on position, speed-limited; the
orientation target is handed to the adapter as the orientation to hold (it converges with
the adapter's orientation gain). Each primitive has a timeout; a plan that cannot finish
fails and gives control back to the user. All of it is pure math on the measured EE
pose: the loop sends the returned velocity through the adapter's safety clamp.

:class:`CancelDetector` decides when the user takes control back: the cancel button, or
the stick held against the assisted motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from legws_daemon.core.geometry import FloatArray, rotation_angle
from legws_daemon.sim.feasibility import symmetric_rotations

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


@dataclass(frozen=True, slots=True)
class Move:
    """Move the EE to ``position`` with orientation ``rotation`` (3x3)."""

    label: str
    position: FloatArray
    rotation: FloatArray
    tolerance: float = POSITION_TOLERANCE


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
        v = POSITION_GAIN * error
        norm = math.sqrt(float(v @ v))
        if norm > self.speed:
            v *= self.speed / norm
        return AssistStep(v, prim.rotation, None, prim.label)

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
