"""The controller's modes and the transitions between them, in one place.

- ``teleop``: the user drives; the observer infers; a commit starts ``assist``.
- ``assist``: the robot carries out the committed goal's action (or a reset's plan).
- ``idle``: the task is done; nothing moves until ``reset`` or a load.
- ``stopped``: the operator said stop; nothing moves until ``reset`` or a load.
- ``fault``: the robot failed; zero velocity until ``reset`` (or a load) succeeds.
- ``calibrate``: ``legws operator calibrate``: the user drives toward one target at a time
  (teleoperation without an observer, a commit or assistance); ``idle`` after the last.

:class:`ModeMachine` refuses any other transition: a refused transition is a bug, and it
raises.
"""

from __future__ import annotations

from enum import StrEnum


class Mode(StrEnum):
    TELEOP = "teleop"
    ASSIST = "assist"
    IDLE = "idle"
    STOPPED = "stopped"
    FAULT = "fault"
    CALIBRATE = "calibrate"


#: Where each mode may go (staying is always allowed).
TRANSITIONS: dict[Mode, frozenset[Mode]] = {
    # commit -> assist; task over -> idle; stop; the robot fails; a calibration begins
    Mode.TELEOP: frozenset({Mode.ASSIST, Mode.IDLE, Mode.STOPPED, Mode.FAULT, Mode.CALIBRATE}),
    # cancelled, failed or done with inference next -> teleop; a single-candidate stage
    # next -> assist (stays); task over -> idle; stop; the robot fails; a reset's way home
    # done during a calibration -> calibrate
    Mode.ASSIST: frozenset({Mode.TELEOP, Mode.IDLE, Mode.STOPPED, Mode.FAULT, Mode.CALIBRATE}),
    # reset -> assist (home); a load -> teleop / assist / idle; stop; the robot fails; a
    # calibration begins
    Mode.IDLE: frozenset({Mode.ASSIST, Mode.TELEOP, Mode.STOPPED, Mode.FAULT, Mode.CALIBRATE}),
    Mode.STOPPED: frozenset({Mode.ASSIST, Mode.TELEOP, Mode.IDLE, Mode.FAULT}),
    Mode.FAULT: frozenset({Mode.ASSIST, Mode.TELEOP, Mode.IDLE, Mode.STOPPED}),
    # the last target reached -> idle; stop; the robot fails (a reset goes home through
    # assist, then the calibration goes on)
    Mode.CALIBRATE: frozenset({Mode.IDLE, Mode.STOPPED, Mode.FAULT}),
}

#: Modes in which nothing may move: the command is zero whatever else is asked.
STILL: frozenset[Mode] = frozenset({Mode.IDLE, Mode.STOPPED, Mode.FAULT})


class ModeMachine:
    """The current mode and the fault that caused ``fault`` (``None`` otherwise)."""

    def __init__(self) -> None:
        self.mode = Mode.TELEOP
        self.fault: str | None = None

    def to(self, mode: Mode) -> None:
        """Change to ``mode``; a transition :data:`TRANSITIONS` does not allow raises."""
        if mode != self.mode and mode not in TRANSITIONS[self.mode]:
            raise AssertionError(f"no transition from {self.mode} to {mode}")
        if mode != Mode.FAULT:
            self.fault = None
        self.mode = mode

    def to_fault(self, reason: str) -> bool:
        """Enter ``fault`` for ``reason``; ``True`` when it was not in ``fault`` yet."""
        first = self.mode != Mode.FAULT
        self.to(Mode.FAULT)
        self.fault = reason
        return first
