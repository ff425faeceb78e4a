"""Assistance after a commit: a plan of motion primitives, carried out one tick at a time.

A plan (:mod:`legws_daemon.robot.motion`) is a list of straight-line EE moves, joint-space
moves and gripper actions. :class:`Assistant` turns the current primitive and the measured
state into this tick's command: a Cartesian move is a proportional controller on position,
speed-limited, with the target orientation handed to the adapter as the one to hold; a
joint-space move is a proportional controller on the joint angles at up to
:data:`JOINT_SPEED_FRACTION` of the joint speed limits (the adapter's envelope bounds the
EE's speed too). Each primitive has a timeout; a plan that cannot finish fails and gives
control back to the user. A move may also be given a *patience*: it then fails as soon as
it has made no progress for that long (a joint limit or the workspace box holds the arm
short of it), so that the caller can fall back at once (a reset's put-back falls back to a
set-down); an *optional* move that stalls is cut short instead and the plan goes on from
where the arm stopped. All of it is pure math on the measured state: the loop sends the
command through the adapter's safety envelope.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from legws_daemon.arms import DEFAULT_ARM, arm
from legws_daemon.autonomy.inputs import Cartesian, Command, Joints, zero
from legws_daemon.core.geometry import FloatArray, rotation_angle
from legws_daemon.errors import InfeasibleError
from legws_daemon.robot.motion import (
    FALLBACK_PATIENCE,
    ROTATION_TOLERANCE,
    Grip,
    JointMove,
    Move,
    Primitive,
)

#: Proportional gain of a Cartesian move, 1/s.
POSITION_GAIN = 2.0
#: Proportional gain of a joint-space move, 1/s, and the share of the joint speed limits
#: it may use.
JOINT_GAIN = 4.0
JOINT_SPEED_FRACTION = 0.5
#: A primitive that has not finished after this long fails the plan, seconds.
PRIMITIVE_TIMEOUT = 20.0
#: A move with a patience has made progress when it came this much closer (m, rad; rad
#: in joint space) ...
STALL_DISTANCE = 0.002
STALL_ANGLE = 0.02
STALL_JOINTS = 0.01
#: ... and the patience of a reset's moves before it lets go of the object, seconds.
STALL_SECONDS = 2.0
#: Withdrawals before one joint-space move at most (the second from where the first ended).
MAX_WITHDRAWALS = 2
#: Vias passed on the way to one joint-space target at most (each is planned from where the
#: arm really is; one more means the planner leads the arm round in a circle: a failure).
MAX_VIAS = 3


@dataclass(frozen=True, slots=True)
class AssistStep:
    """What the assistant wants this tick."""

    command: Command
    grip: bool | None  # gripper command this tick (None: leave it)
    phase: str
    done: bool = False
    failed: str | None = None


@dataclass
class Assistant:
    """Executes a plan one tick at a time.

    Args:
        plan: the primitives, in order.
        speed: top EE speed of Cartesian moves, m/s.
        dt: control period, s.
        target: the name of what the plan acts on (for events and logs).
        path: checks a joint-space move when it begins (see the attribute).
        joint_speed_limits: the arm's joint speed limits, rad/s (default the default arm's).
    """

    plan: list[Primitive]
    speed: float
    dt: float
    target: str = ""
    #: checks a joint-space move from where the arm is when it begins: the configurations
    #: to pass on the way (none: straight), or an InfeasibleError (the move fails)
    path: Callable[[FloatArray, FloatArray], list[FloatArray]] | None = None
    #: when ``path`` finds no way: Cartesian moves to make first (the joint move is then
    #: checked again from where they end), or ``None`` (the move fails)
    withdraw: Callable[[FloatArray, FloatArray], list[Move] | None] | None = None
    joint_speed_limits: FloatArray = field(
        default_factory=lambda: np.array(arm(DEFAULT_ARM).speed_limits)
    )
    index: int = 0
    elapsed: float = 0.0
    _entered: int = field(default=-1, repr=False)
    # withdrawals made before each joint move (at most MAX_WITHDRAWALS)
    _withdrawn: dict[int, int] = field(default_factory=dict, repr=False)
    # vias passed before each joint move (at most MAX_VIAS)
    _vias: dict[int, int] = field(default_factory=dict, repr=False)
    # progress of the current move: best distances since the last progress, and the
    # active seconds since then
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

    def step(
        self, q: FloatArray, position: FloatArray, rotation: FloatArray, active: bool = True
    ) -> AssistStep:
        """One tick from the measured state.

        Args:
            q, position, rotation: measured joint angles and EE pose.
            active: ``False`` pauses the plan (no valid input: the deadman holds the
                robot); the time of a paused tick does not count toward timeouts.
        """
        if self.finished:
            return AssistStep(zero(), None, "done", done=True)
        prim = self.plan[self.index]
        if not active:
            return AssistStep(zero(), None, prim.label)
        self.elapsed += self.dt
        if self.elapsed > PRIMITIVE_TIMEOUT + (prim.seconds if isinstance(prim, Grip) else 0):
            error = f"'{prim.label}' timed out after {PRIMITIVE_TIMEOUT:g} s"
            return AssistStep(zero(), None, prim.label, failed=error)
        match prim:
            case Grip():
                if self.elapsed >= prim.seconds:
                    return self._advance(prim.closed)
                return AssistStep(zero(), prim.closed, prim.label)
            case Move():
                return self._move(prim, position, rotation)
            case JointMove():
                return self._joint_move(prim, q, position, rotation)

    def _move(self, prim: Move, position: FloatArray, rotation: FloatArray) -> AssistStep:
        error = prim.position - np.asarray(position, dtype=np.float64)
        dist = math.sqrt(float(error @ error))
        angle = float(rotation_angle(np.asarray(rotation, dtype=np.float64), prim.rotation))
        if dist < prim.tolerance and angle < ROTATION_TOLERANCE:
            return self._advance(None)
        if prim.fallback is not None and self._stalled((dist, angle), FALLBACK_PATIENCE):
            # held short of its target (a joint at its limit): the joint-space way there
            self.plan[self.index] = JointMove(prim.label, prim.fallback, patience=prim.patience)
            self._entered, self._best, self._still = -1, None, 0.0
            return AssistStep(zero(), None, prim.label)
        if prim.patience is not None and self._stalled((dist, angle), prim.patience):
            if prim.optional:
                return self._advance(None)  # it only gave room: go on from here
            return self._stall(prim.label, prim.patience)
        v = POSITION_GAIN * error
        norm = math.sqrt(float(v @ v))
        if norm > self.speed:
            v *= self.speed / norm
        return AssistStep(Cartesian(v, prim.rotation, prim.floor), None, prim.label)

    def _joint_move(
        self, prim: JointMove, q: FloatArray, position: FloatArray, rotation: FloatArray
    ) -> AssistStep:
        if self._entered != self.index and self.path is not None:
            self._entered = self.index
            try:
                vias = self.path(np.asarray(q, dtype=np.float64), prim.q)
            except InfeasibleError as err:
                moves = None
                made = self._withdrawn.get(id(prim), 0)
                if self.withdraw is not None and made < MAX_WITHDRAWALS:
                    moves = self.withdraw(np.asarray(q, dtype=np.float64), prim.q)
                if not moves:
                    return AssistStep(zero(), None, prim.label, failed=f"'{prim.label}': {err}")
                # in from the box's edge first, in straight lines; the joint move is checked
                # again from where they really end (the arm's own path there is not the
                # planner's IK: at most MAX_WITHDRAWALS times, then a refusal fails it)
                self._withdrawn[id(prim)] = made + 1
                self.plan[self.index : self.index] = moves
                self._entered = -1
                return self._move(moves[0], position, rotation)
            if vias:  # pass them first, as moves of the same phase
                made = self._vias.get(id(prim), 0) + len(vias)
                if made > MAX_VIAS:
                    error = f"'{prim.label}': still no clear way after {MAX_VIAS} vias"
                    return AssistStep(zero(), None, prim.label, failed=error)
                self._vias[id(prim)] = made
                passes = [JointMove(prim.label, v, prim.tolerance, prim.patience) for v in vias]
                self.plan[self.index : self.index] = passes
                self._entered = self.index  # the via's own line is the one just checked
                prim = passes[0]
        delta = prim.q - np.asarray(q, dtype=np.float64)
        worst = float(np.max(np.abs(delta)))
        if worst < prim.tolerance:
            return self._advance(None)
        if prim.patience is not None and self._stalled((worst, 0.0), prim.patience):
            return self._stall(prim.label, prim.patience)
        qdot = min(JOINT_GAIN, 1.0 / self.dt) * delta
        ratio = float(np.max(np.abs(qdot) / (JOINT_SPEED_FRACTION * self.joint_speed_limits)))
        if ratio > 1.0:
            qdot /= ratio  # the same straight line in joint space, slower
        return AssistStep(Joints(qdot), None, prim.label)

    def _stall(self, label: str, patience: float) -> AssistStep:
        error = f"'{label}' made no progress for {patience:g} s"
        return AssistStep(zero(), None, label, failed=error)

    def _stalled(self, now: tuple[float, float], patience: float) -> bool:
        """Whether the move has come no closer (by :data:`STALL_DISTANCE` or
        :data:`STALL_ANGLE`; :data:`STALL_JOINTS` in joint space) for ``patience``
        active seconds."""
        best = self._best
        step = STALL_JOINTS if isinstance(self.plan[self.index], JointMove) else STALL_DISTANCE
        if best is None or now[0] < best[0] - step or now[1] < best[1] - STALL_ANGLE:
            self._best = now
            self._still = 0.0
            return False
        self._still += self.dt
        return self._still >= patience - 1e-9

    def _advance(self, grip: bool | None) -> AssistStep:
        label = self.plan[self.index].label
        self.index += 1
        self.elapsed = 0.0
        self._best = None
        self._still = 0.0
        return AssistStep(zero(), grip, label, done=self.finished)
