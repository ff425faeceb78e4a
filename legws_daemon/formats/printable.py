"""Text that cannot act on a terminal: the one place text from outside is made printable.

Names and messages reach legws from files (checked on load,
:func:`~legws_daemon.formats.validation.check_text`) but also from zenoh messages (a
daemon's status, events and replies, a joystick's ``source``), recordings, the command
line, device names and library errors. Whatever prints them — an error line, the log on
the terminal, a publisher's status line, a table — passes them through :func:`safe_text`
(one field or line) or :func:`safe_lines` (a block of lines) first, on a terminal and
through a pipe alike.

A character passes unchanged when Python calls it printable (:meth:`str.isprintable`);
every other one is written as Python writes it in a string literal (``\\x1b``, ``\\n``,
``\\u202e``, ``\\udcff``, ``\\U000e0001``):

- C0 and C1 controls and DEL, so ESC and with it every CSI, OSC and DCS sequence (tab,
  carriage return and line feed too: a field stays on its line, a line cannot be
  overwritten);
- the line and paragraph separators (U+2028, U+2029) and the other spaces but the plain
  one;
- format characters (category Cf): the bidirectional controls (U+202A–U+202E,
  U+2066–U+2069, U+200E, U+200F, U+061C), zero-width joiners and spaces, tag characters;
- surrogates (a name decoded with ``surrogateescape``), private-use and unassigned code
  points.

A long text is cut, with an ellipsis, to at most ``limit`` characters after escaping. The
result of either function is its own result again (printable text within the bound comes
back unchanged), so text made safe twice reads the same.

The commands print through :func:`echo` (``click.echo`` of :func:`safe_lines`); JSON they
print needs nothing (``json.dumps`` writes every character outside printable ASCII as a
``\\u`` escape). Log records are shown by :class:`SafeFormatter`: the terminal log, and
what Python prints of a record no handler takes (:func:`guard_last_resort`).

This module imports nothing of legws: :mod:`legws_daemon.errors` uses it.
"""

from __future__ import annotations

import logging
import re
import sys

__all__ = [
    "ELLIPSIS",
    "LIMIT",
    "MESSAGE_LIMIT",
    "SafeFormatter",
    "echo",
    "escape",
    "guard_last_resort",
    "is_safe",
    "safe_lines",
    "safe_text",
    "unsafe",
]

#: Longest field or line :func:`safe_text` returns by default, characters.
LIMIT = 1000
#: Longest message (an error's, a log record's) where a message is made safe, characters.
MESSAGE_LIMIT = 4000
#: What ends a text that was cut.
ELLIPSIS = "…"

#: The escapes Python writes for these (as ``repr`` does); every other one is ``\\xNN``,
#: ``\\uNNNN`` or ``\\UNNNNNNNN``.
_SHORT = {"\t": "\\t", "\n": "\\n", "\r": "\\r"}


def unsafe(char: str) -> bool:
    """Whether the character ``char`` must not reach a terminal as it is.

    Everything but the printable characters: categories Cc, Cf, Cs, Co, Cn, Zl, Zp and the
    spaces (Zs) other than U+0020.
    """
    return not char.isprintable()


def is_safe(text: str) -> bool:
    """Whether ``text`` holds no character :func:`unsafe` finds."""
    return text.isprintable()


def escape(char: str) -> str:
    """The visible escape of one character, as Python writes it in a string literal."""
    short = _SHORT.get(char)
    if short is not None:
        return short
    code = ord(char)
    if code < 0x100:
        return f"\\x{code:02x}"
    if code < 0x10000:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def safe_text(text: str, limit: int | None = LIMIT) -> str:
    """``text`` as one terminal-safe line: every :func:`unsafe` character escaped
    (:func:`escape`), cut with :data:`ELLIPSIS` to at most ``limit`` characters (``None``:
    no bound). Printable text within the bound is returned as it is.

    Only the first ``limit + 1`` characters of ``text`` are read: a name of a million
    characters costs no more than one of a thousand.
    """
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be at least 1, got {limit}")
    if not isinstance(text, str):
        text = str(text)
    head = text if limit is None else text[: limit + 1]
    if len(head) == len(text) and (limit is None or len(text) <= limit) and text.isprintable():
        return text
    pieces: list[str] = []
    size = 0
    for char in head:
        piece = char if char.isprintable() else escape(char)
        if limit is not None and size + len(piece) > limit:
            break
        pieces.append(piece)
        size += len(piece)
    else:
        # every character fitted: then ``head`` was all of ``text`` (limit + 1 characters
        # cannot fit in limit)
        return "".join(pieces)
    assert limit is not None
    while pieces and size + len(ELLIPSIS) > limit:
        size -= len(pieces.pop())
    return "".join(pieces) + ELLIPSIS


#: A terminal control sequence (CSI: colours, cursor moves) as a program's log writes them.
_TERMINAL_SEQUENCE = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def without_terminal_sequences(text: str) -> str:
    """``text`` without its CSI sequences (a library's coloured log line, read back)."""
    return _TERMINAL_SEQUENCE.sub("", text)


def safe_lines(text: str, limit: int | None = LIMIT) -> str:
    """A block of lines (a table, a report) made terminal-safe line by line: each line
    split at ``\\n`` is :func:`safe_text` (so a carriage return, a tab or a line separator
    inside a line is escaped, and each line is cut at ``limit``); the line breaks stay."""
    if text.isprintable() and (limit is None or len(text) <= limit):
        return text
    return "\n".join(safe_text(line, limit) for line in text.split("\n"))


def echo(message: object = "", *, err: bool = False, limit: int | None = LIMIT) -> None:
    """``click.echo`` of ``message`` made terminal-safe line by line (:func:`safe_lines`):
    how a command prints text that holds anything from outside (a name, a path, a message,
    a device's name, a library's error)."""
    import click  # only the commands print

    click.echo(safe_lines(str(message), limit), err=err)


class SafeFormatter(logging.Formatter):
    """A log record as ``"<prefix>: message"`` (the message alone without a prefix), the
    message one terminal-safe line (:data:`MESSAGE_LIMIT`); a traceback or stack the record
    carries after it, its lines each made safe."""

    def __init__(self, prefix: str = "") -> None:
        super().__init__()
        self.prefix = safe_text(prefix)

    def format(self, record: logging.LogRecord) -> str:
        message = safe_text(record.getMessage(), MESSAGE_LIMIT)
        lines = [f"{self.prefix}: {message}" if self.prefix else message]
        if record.exc_info and not record.exc_text:
            record.exc_text = self.formatException(record.exc_info)
        lines += [safe_lines(extra) for extra in (record.exc_text, record.stack_info) if extra]
        return "\n".join(lines)


class _LastResort(logging.Handler):
    """Python's last resort (records of WARNING and above that no handler takes, on the
    ``sys.stderr`` of the moment), each made safe by :class:`SafeFormatter`."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.setFormatter(SafeFormatter())

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except Exception:
            self.handleError(record)


def guard_last_resort() -> None:
    """Make what Python prints of a log record no handler takes (``logging.lastResort``: a
    library's warning, a legws warning in a command without the terminal log) safe, as the
    terminal log is. Idempotent."""
    if not isinstance(logging.lastResort, _LastResort):
        logging.lastResort = _LastResort()
