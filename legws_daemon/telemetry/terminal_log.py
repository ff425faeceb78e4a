"""The log of a long-running command, on the terminal it was started from.

``legws daemon`` and ``legws operator calibrate`` report on the ``legws.*`` loggers (and the
package's own ``legws_daemon.*``). :func:`log_to_terminal` shows those at INFO on standard
error with the command's prefix, and nothing else: a library's INFO chatter (fontTools
subsetting a PDF font, for one) stays below the root logger's WARNING.

The handler looks up ``sys.stderr`` at every record instead of keeping the stream it saw when
it was installed: a command run in-process (a test's ``CliRunner``, a notebook) swaps
``sys.stderr`` and closes its stand-in afterwards, and a handler holding that stand-in would
print "--- Logging error ---" into whatever ran next.

A record's message is made terminal-safe (:func:`~legws_daemon.formats.printable.safe_text`)
and kept on its line: a goal name, a joystick's ``source`` or a library's error text the
daemon logs may hold escape sequences, bidirectional controls or line breaks, and these
are written as visible escapes, on a terminal or through a pipe alike. A traceback the
record carries (``log.exception``) keeps its lines, each made safe.
"""

from __future__ import annotations

import logging
import sys
from typing import TextIO

from legws_daemon.formats.printable import SafeFormatter

__all__ = ["LOGGERS", "log_to_terminal"]

#: the loggers legws reports on
LOGGERS = ("legws", "legws_daemon")


class _CurrentStderr(logging.StreamHandler):  # type: ignore[type-arg]
    """A stream handler on whatever ``sys.stderr`` is when a record comes."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self) -> TextIO:
        return sys.stderr

    @stream.setter
    def stream(self, _value: TextIO) -> None:  # StreamHandler.__init__ assigns it
        pass


def log_to_terminal(prefix: str, level: int = logging.INFO) -> None:
    """Show legws's log records at ``level`` and above on stderr as ``"<prefix>: message"``,
    the message one terminal-safe line.

    Calling it again replaces the handler it installed before (one line per record, the
    newest prefix); other handlers, the root logger and third-party loggers are left alone.
    Records still propagate to the root logger's handlers (pytest's ``caplog`` sees them).
    """
    formatter = SafeFormatter(prefix)
    for name in LOGGERS:
        logger = logging.getLogger(name)
        for old in [h for h in logger.handlers if isinstance(h, _CurrentStderr)]:
            logger.removeHandler(old)
        handler = _CurrentStderr()
        handler.setFormatter(formatter)
        logger.addHandler(handler)
        logger.setLevel(level)
