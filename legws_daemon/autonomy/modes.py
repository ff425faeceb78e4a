"""The controller's modes, its sub-states and the transitions between them, in one place.

The reported modes (:class:`Mode`; status ``mode``, tick records):

- ``teleop``: the user drives; the observer infers; a commit starts ``assist``.
- ``assist``: the robot carries out the committed goal's action, or a reset's plan.
- ``idle``: the task is done; nothing moves until ``reset`` or a load.
- ``stopped``: the operator said stop; nothing moves until ``reset`` or a load.
- ``fault``: the robot failed; zero velocity until ``reset`` (or a load) succeeds.
- ``calibrate``: ``legws operator calibrate``: the user drives toward one target at a time
  (teleoperation without an observer, a commit or assistance); ``idle`` after the last.

What the machine holds (:class:`MachineState`) is finer: ``assist`` is one of three
:class:`Activity` values — toward the committed goal (``assist``), a reset's way home
(``reset``), or a reset's way home that began in ``fault`` (``recover``: it ends with a
``recovered`` event, not ``reset``) — and beside the activity it keeps whether a
single-candidate stage may commit by itself (:class:`SingleCommit`: not after an assist
that failed) and what the gripper was last told (:class:`Gripper`).

:data:`TRANSITIONS` lists where each activity may go; every edge left out is one that must
not happen (the comments say why). :class:`ModeMachine` refuses it: a refused transition
is a bug, and it raises.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import StrEnum


class Mode(StrEnum):
    """The reported mode (status ``mode``)."""

    TELEOP = "teleop"
    ASSIST = "assist"
    IDLE = "idle"
    STOPPED = "stopped"
    FAULT = "fault"
    CALIBRATE = "calibrate"


class Activity(StrEnum):
    """What the controller is doing: a :class:`Mode`, with ``assist`` split by what the
    robot moves for."""

    TELEOP = "teleop"
    ASSIST = "assist"  # toward the committed goal
    RESET = "reset"  # a reset's way home (putting back what it holds first)
    RECOVER = "recover"  # a reset's way home that began in fault
    IDLE = "idle"
    STOPPED = "stopped"
    FAULT = "fault"
    CALIBRATE = "calibrate"

    @property
    def mode(self) -> Mode:
        """The mode it reports."""
        return _MODE_OF[self]

    @property
    def going_home(self) -> bool:
        """A reset's way home (``reset`` or ``recover``): no cancel interrupts it."""
        return self in (Activity.RESET, Activity.RECOVER)

    @property
    def moving(self) -> bool:
        """The robot carries out a plan (``assist``, ``reset``, ``recover``): the only
        activities that send grips."""
        return self.mode == Mode.ASSIST


_MODE_OF: dict[Activity, Mode] = {
    Activity.TELEOP: Mode.TELEOP,
    Activity.ASSIST: Mode.ASSIST,
    Activity.RESET: Mode.ASSIST,
    Activity.RECOVER: Mode.ASSIST,
    Activity.IDLE: Mode.IDLE,
    Activity.STOPPED: Mode.STOPPED,
    Activity.FAULT: Mode.FAULT,
    Activity.CALIBRATE: Mode.CALIBRATE,
}


class SingleCommit(StrEnum):
    """Whether a single-candidate stage commits by itself (``auto``) or waits for the
    confirm button (``confirm``: an assist failed and gave control back; no retrying for
    ever on its own). Each single-candidate stage that begins is ``auto`` again."""

    AUTO = "auto"
    CONFIRM = "confirm"


class Gripper(StrEnum):
    """What the gripper was last told: ``unknown`` until the first grip (and again after a
    load or a restart of the task), then ``open`` or ``closed``."""

    UNKNOWN = "unknown"
    OPEN = "open"
    CLOSED = "closed"

    @classmethod
    def of(cls, closed: bool) -> Gripper:
        return cls.CLOSED if closed else cls.OPEN


#: The events that name a reset's assistance (its ``assist`` in warnings, logs): a label
#: only — what the controller does depends on :class:`Activity`, never on this string.
RESET_LABEL = "(reset)"

_A = Activity

#: Where each activity may go (staying is always allowed). Left out on purpose:
#:
#: - into ``assist`` from anything but ``teleop``: a goal is assisted only after a commit,
#:   and a commit is made only in ``teleop`` (a single-candidate stage that comes next goes
#:   through ``teleop`` too, even when it commits at once). Not from ``idle`` (the task is
#:   done: only a reset or a load), ``stopped`` or ``fault`` (nothing moves until the
#:   operator's reset), ``calibrate`` (nothing is committed in a calibration), nor from a
#:   reset's way home (it ends in a new task's first stage, in ``teleop``);
#: - into ``reset`` from ``fault``: a reset that begins in fault is a recovery
#:   (``recover``); into ``recover`` from anything but ``fault``, for the same reason;
#: - out of ``stopped`` and ``fault`` into any motion but the operator's reset (the only
#:   way out of them that moves the robot: home first); a load may leave them for ``teleop``
#:   or ``idle`` (the robot stopped, the task restarted);
#: - into ``calibrate`` from ``assist`` (the assistance is dropped first: the user drives
#:   again, in ``teleop``), ``stopped`` or ``fault`` (reset first); from a reset's way home
#:   only once it is home, during a calibration (the calibration goes on);
#: - out of ``calibrate`` into ``teleop`` or ``assist``: loads are refused during a
#:   calibration, which ends in ``idle`` (or is stopped, fails, or is reset).
TRANSITIONS: dict[Activity, frozenset[Activity]] = {
    # a commit; a reset; the task over (a load, a restart); stop; the robot fails; a
    # calibration begins
    _A.TELEOP: frozenset({_A.ASSIST, _A.RESET, _A.IDLE, _A.STOPPED, _A.FAULT, _A.CALIBRATE}),
    # cancelled, failed, or done with the next stage's inference next (a load too) ->
    # teleop; the task over -> idle; a reset; stop; the robot fails
    _A.ASSIST: frozenset({_A.TELEOP, _A.IDLE, _A.RESET, _A.STOPPED, _A.FAULT}),
    # home: the new task's first stage (teleop), or it is over (idle), or back to the
    # calibration under way; failed with nothing to fall back to -> teleop; a load; a
    # reset again; stop; the robot fails
    _A.RESET: frozenset({_A.TELEOP, _A.IDLE, _A.CALIBRATE, _A.STOPPED, _A.FAULT}),
    # as ``reset``; a reset again during it is a plain reset (it did not begin in fault)
    _A.RECOVER: frozenset({_A.TELEOP, _A.IDLE, _A.CALIBRATE, _A.RESET, _A.STOPPED, _A.FAULT}),
    # a reset goes home; a load -> teleop / idle; stop; the robot fails; a calibration
    # begins
    _A.IDLE: frozenset({_A.RESET, _A.TELEOP, _A.STOPPED, _A.FAULT, _A.CALIBRATE}),
    # the operator's reset goes home; a load -> teleop / idle; the robot fails
    _A.STOPPED: frozenset({_A.RESET, _A.TELEOP, _A.IDLE, _A.FAULT}),
    # the operator's reset recovers (goes home); a load -> teleop / idle; stop
    _A.FAULT: frozenset({_A.RECOVER, _A.TELEOP, _A.IDLE, _A.STOPPED}),
    # the last target reached -> idle; stop; the robot fails; a reset goes home (the reach
    # under way dropped), then the calibration goes on
    _A.CALIBRATE: frozenset({_A.IDLE, _A.STOPPED, _A.FAULT, _A.RESET}),
}

#: Modes in which nothing may move: the command is zero whatever else is asked.
STILL: frozenset[Mode] = frozenset({Mode.IDLE, Mode.STOPPED, Mode.FAULT})


@dataclass(frozen=True, slots=True)
class MachineState:
    """Everything the machine holds: the activity, the fault that caused ``fault``
    (``None`` otherwise), the single-candidate commit permission and the gripper."""

    activity: Activity = Activity.TELEOP
    fault: str | None = None
    single: SingleCommit = SingleCommit.AUTO
    gripper: Gripper = Gripper.UNKNOWN

    @property
    def mode(self) -> Mode:
        return self.activity.mode


class ModeMachine:
    """The controller's :class:`MachineState`, changed only through its transitions."""

    def __init__(self) -> None:
        self.state = MachineState()

    @property
    def mode(self) -> Mode:
        return self.state.mode

    @property
    def activity(self) -> Activity:
        return self.state.activity

    @property
    def fault(self) -> str | None:
        return self.state.fault

    @property
    def gripper(self) -> Gripper:
        return self.state.gripper

    @property
    def single(self) -> SingleCommit:
        return self.state.single

    def to(self, activity: Activity) -> None:
        """Change to ``activity``; a transition :data:`TRANSITIONS` does not allow raises,
        and so does ``fault`` (entered only with its reason: :meth:`to_fault`)."""
        if activity == Activity.FAULT:
            raise AssertionError("no transition to fault without its reason (to_fault)")
        self._go(activity, None)

    def to_fault(self, reason: str) -> bool:
        """Enter ``fault`` for ``reason``; ``True`` when it was not in ``fault`` yet."""
        first = self.state.activity != Activity.FAULT
        self._go(Activity.FAULT, reason)
        return first

    def _go(self, activity: Activity, fault: str | None) -> None:
        now = self.state.activity
        if activity != now and activity not in TRANSITIONS[now]:
            raise AssertionError(f"no transition from {now} to {activity}")
        self.state = dataclasses.replace(self.state, activity=activity, fault=fault)

    def may_commit(self, *, single: bool, confirmed: bool) -> None:
        """A commit is about to be made: only in ``teleop``, and one of a single candidate
        without the confirm button only while :class:`SingleCommit` is ``auto``; anything
        else raises."""
        if self.state.activity != Activity.TELEOP:
            raise AssertionError(f"a commit in {self.state.activity}")
        if single and not confirmed and self.state.single != SingleCommit.AUTO:
            raise AssertionError("a single candidate committed without the confirm button")

    def single_stage(self) -> None:
        """A single-candidate stage begins: it may commit by itself."""
        self.state = dataclasses.replace(self.state, single=SingleCommit.AUTO)

    def give_back(self) -> None:
        """An assist (or its plan) failed: ``teleop``, and a single-candidate stage waits
        for the confirm button from now on."""
        self.to(Activity.TELEOP)
        self.state = dataclasses.replace(self.state, single=SingleCommit.CONFIRM)

    def gripped(self, closed: bool) -> None:
        """The gripper was told to close (``True``) or open by a plan: only in its
        activities (the operator's button: :meth:`gripped_by_hand`)."""
        if not self.state.activity.moving:
            raise AssertionError(f"a grip in {self.state.activity}")
        self.state = dataclasses.replace(self.state, gripper=Gripper.of(closed))

    def gripped_by_hand(self, closed: bool) -> None:
        """The operator's gripper button closed (``True``) or opened the gripper: only in
        ``teleop`` (teleoperation: the person grasps)."""
        if self.state.activity != Activity.TELEOP:
            raise AssertionError(f"a hand grip in {self.state.activity}")
        self.state = dataclasses.replace(self.state, gripper=Gripper.of(closed))

    def forget_gripper(self) -> None:
        """The gripper is not known any more (a load, a restart of the task)."""
        self.state = dataclasses.replace(self.state, gripper=Gripper.UNKNOWN)
