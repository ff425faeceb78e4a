"""The project's error types: one root, a few kinds the CLI maps to exit codes."""

from __future__ import annotations


class LegwsError(Exception):
    """Root of every error legws raises on purpose."""


class InputError(LegwsError):
    """Bad user input: a file, a field, a flag or a message that does not validate.

    The message is one line naming the source (file), the field and what was expected.
    """

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.source = source
        self.field = field
        parts = [p for p in (source, field) if p]
        prefix = ": ".join(parts)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class InfeasibleError(LegwsError):
    """A request that cannot be satisfied, e.g. no layout meets the constraints."""


class HardwareError(LegwsError):
    """The robot or its bridge failed: stale state, lost heartbeat, a refused command.

    The daemon answers with a safe stop and a fault event; it keeps publishing status.
    """


class BridgeTimeoutError(HardwareError):
    """The robot-side bridge did not answer within the profile's ``bridge_timeout``."""
