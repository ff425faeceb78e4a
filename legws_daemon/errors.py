"""The project's error types: one root, a few kinds the CLI maps to exit codes."""

from __future__ import annotations

from legws_daemon.formats.printable import LIMIT, MESSAGE_LIMIT, safe_text


class LegwsError(Exception):
    """Root of every error legws raises on purpose."""


class InputError(LegwsError):
    """Bad user input: a file, a field, a flag or a message that does not validate.

    The message is one line naming the source (file), the field and what was expected.
    Each part is made terminal-safe (:func:`~legws_daemon.formats.printable.safe_text`):
    a file name from the command line, a name from a message or a library's error text
    may hold escape sequences, line breaks or bidirectional controls, and these are
    written as visible escapes; a part too long is cut with an ellipsis. ``source`` and
    ``field`` keep the safe forms (what ``str()`` starts with).
    """

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.source = safe_text(source, LIMIT) if source is not None else None
        self.field = safe_text(field, LIMIT) if field is not None else None
        parts = [p for p in (self.source, self.field) if p]
        prefix = ": ".join(parts)
        text = safe_text(message, MESSAGE_LIMIT)
        super().__init__(f"{prefix}: {text}" if prefix else text)


class InfeasibleError(LegwsError):
    """A request that cannot be satisfied, e.g. no layout meets the constraints."""


class HardwareError(LegwsError):
    """The robot or its bridge failed: stale state, lost heartbeat, a refused command.

    The daemon answers with a safe stop and a fault event; it keeps publishing status.
    """


class BridgeTimeoutError(HardwareError):
    """The robot-side bridge did not answer within the profile's ``bridge_timeout``."""
