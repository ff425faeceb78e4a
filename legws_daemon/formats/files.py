"""Writing files atomically: a reader sees the old file or the new one, never half of one."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from legws_daemon.errors import InputError


def write_atomic(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename.

    The folder must exist. The file gets the usual mode (0666 less the umask). A failure
    leaves no temporary file behind and is an :class:`InputError` naming the path.
    """
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    try:
        with tmp.open("xb") as out:
            out.write(data)
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise InputError(f"cannot write: {err.strerror or err}", source=str(path)) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
