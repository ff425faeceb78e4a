"""The controller's modes and the transitions between them, in one place.

- ``teleop``: the user drives; the observer infers; a commit starts ``assist``.
- ``assist``: the robot carries out the committed goal's action (or a reset's plan).
- ``idle``: the task is done; nothing moves until ``reset`` or a load.
- ``stopped``: the operator said stop; nothing moves until ``reset`` or a load.
- ``fault``: the robot failed; zero velocity until ``reset`` (or a load) succeeds.

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


#: Where each mode may go (staying is always allowed).
TRANSITIONS: dict[Mode, frozenset[Mode]] = {
    # commit -> assist; task over -> idle; stop; the robot fails
    Mode.TELEOP: frozenset({Mode.ASSIST, Mode.IDLE, Mode.STOPPED, Mode.FAULT}),
    # cancelled, failed or done with inference next -> teleop; a single-candidate stage
    # next -> assist (stays); task over -> idle; stop; the robot fails
    Mode.ASSIST: frozenset({Mode.TELEOP, Mode.IDLE, Mode.STOPPED, Mode.FAULT}),
    # reset -> assist (home); a load -> teleop / assist / idle; stop; the robot fails
    Mode.IDLE: frozenset({Mode.ASSIST, Mode.TELEOP, Mode.STOPPED, Mode.FAULT}),
    Mode.STOPPED: frozenset({Mode.ASSIST, Mode.TELEOP, Mode.IDLE, Mode.FAULT}),
    Mode.FAULT: frozenset({Mode.ASSIST, Mode.TELEOP, Mode.IDLE, Mode.STOPPED}),
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
