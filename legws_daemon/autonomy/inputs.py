"""What the controller gets from the operator each tick, and what it hands back.

:class:`OperatorInput` is one valid joystick sample as the controller uses it (the daemon's
inbox makes it from a validated message; ``legws eval`` makes it from the simulated user).
:class:`Cartesian` and :class:`Joints` are the commands a tick sends through the adapter's
safety envelope; :class:`TickRecord` is everything a tick measured and decided.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from legws_daemon.core.geometry import FloatArray

if TYPE_CHECKING:
    from legws_daemon.autonomy.modes import Mode
    from legws_daemon.hardware.base import RobotState


@dataclass(frozen=True, slots=True)
class OperatorInput:
    """A valid joystick sample.

    Attributes:
        axes: (3,) deflection in the robot base frame, ``|axes| <= 1``.
        confirm: the confirm button (commit the object the hand is at, else the most
            likely goal: :meth:`~legws_daemon.autonomy.decision.Inference.confirmed`).
        cancel: the cancel button (give control back during assistance).
        received: when it arrived, local monotonic seconds.
        seq, stamp: the publisher's sequence number and clock (for traces).
        rotation: (3,) the rotation axes (turn about the base frame's x, y, z), norm <= 1,
            or ``None`` (no turning).
        gripper: the gripper the operator asks for (``True`` closed), or ``None``.
    """

    axes: FloatArray
    confirm: bool = False
    cancel: bool = False
    received: float = 0.0
    seq: int | None = None
    stamp: float | None = None
    rotation: FloatArray | None = None
    gripper: bool | None = None


@dataclass(frozen=True, slots=True)
class Cartesian:
    """An EE velocity command: linear velocity (m/s), the orientation to hold (``None``:
    the current one), and the lowest height it may reach (``None``: the envelope's)."""

    velocity: FloatArray
    hold: FloatArray | None = None
    floor: float | None = None


@dataclass(frozen=True, slots=True)
class Joints:
    """A joint velocity command, rad/s (a joint-space move of assistance)."""

    qdot: FloatArray


Command = Cartesian | Joints


@dataclass(frozen=True, slots=True)
class TickRecord:
    """Everything one tick measured and decided (for status, Rerun and benchmarks)."""

    tick: int
    mode: Mode
    state: RobotState | None
    joystick: FloatArray | None
    command: FloatArray  # (3,) EE velocity sent (to first order for a joint command), m/s
    joints: FloatArray | None  # (7,) joint velocity sent by a joint-space move, rad/s
    posterior: dict[str, float]
    committed: str | None
    phase: str | None
    sample_received: float | None
    sample_seq: int | None
    sample_stamp: float | None  # the publisher's clock
    command_sent: float
    #: who asked for ``command`` (m/s, summing to it): the operator's part and the robot's
    #: (all the robot's in ``assist``; the policy's split before the commit)
    operator_velocity: FloatArray | None = None
    robot_velocity: FloatArray | None = None


def zero() -> Cartesian:
    """No motion: zero velocity, no orientation correction."""
    return Cartesian(np.zeros(3))
