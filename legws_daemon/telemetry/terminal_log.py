"""The log of a long-running command, on the terminal it was started from.

``legws daemon`` and ``legws operator calibrate`` report on the ``legws.*`` loggers (and the
package's own ``legws_daemon.*``). :func:`log_to_terminal` shows those at INFO on standard
error with the command's prefix, and nothing else: a library's INFO chatter (fontTools
subsetting a PDF font, for one) stays below the root logger's WARNING.

The handler looks up ``sys.stderr`` at every record instead of keeping the stream it saw when
it was installed: a command run in-process (a test's ``CliRunner``, a notebook) swaps
``sys.stderr`` and closes its stand-in afterwards, and a handler holding that stand-in would
print "--- Logging error ---" into whatever ran next.
"""

from __future__ import annotations

import logging
import sys
from typing import TextIO

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
    """Show legws's log records at ``level`` and above on stderr as ``"<prefix>: message"``.

    Calling it again replaces the handler it installed before (one line per record, the
    newest prefix); other handlers, the root logger and third-party loggers are left alone.
    Records still propagate to the root logger's handlers (pytest's ``caplog`` sees them).
    """
    formatter = logging.Formatter(f"{prefix}: %(message)s")
    for name in LOGGERS:
        logger = logging.getLogger(name)
        for old in [h for h in logger.handlers if isinstance(h, _CurrentStderr)]:
            logger.removeHandler(old)
        handler = _CurrentStderr()
        handler.setFormatter(formatter)
        logger.addHandler(handler)
        logger.setLevel(level)
