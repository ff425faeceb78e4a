"""Finishing a ``.rrd`` file: a footer (rerun's manifest of every chunk) added at the end.

The daemon writes ``save:`` recordings *without* a footer. Rerun's file writer keeps the
manifest of every chunk in memory until it writes the footer at the very end, so over a
long session the daemon grows by ~1.5 MiB a minute (the 10-minute soak: +7.5 % after the
first load, against a flat resident set without it). At close the file is finished with
``rerun rrd optimize``, which writes a footer and compacts the chunks (the file shrinks),
into a temporary file in the same folder that then replaces the original atomically: a
reader sees the raw stream or the finished file, never a half-written one.

A raw file is still a valid rerun stream (the viewer opens it); it only lacks the
manifest, which ``rerun rrd verify`` requires and which speeds up random access. When
finishing fails or takes too long the raw file is kept, and the error says how to finish
it by hand: ``legws recording finish FILE``.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

#: Seconds ``rerun rrd optimize`` may take at close. It reads the whole file: ~1.7 s for a
#: 48 MiB recording (6 minutes at 50 Hz) on the 2-core development machine.
FINISH_TIMEOUT = 60.0
#: The first bytes of an ``.rrd`` stream of this rerun's protocol.
RRD_MAGIC = b"RRF2"


def rerun_cli() -> str:
    """The ``rerun`` executable shipped with the installed rerun-sdk (the one this process
    logs with, so the file's protocol version matches)."""
    spec = importlib.util.find_spec("rerun_cli")  # the rerun-sdk wheel's bundled binary
    if spec is not None and spec.origin is not None:
        exe = Path(spec.origin).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
        if exe.is_file():
            return str(exe)
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.exists() else (shutil.which("rerun") or "rerun")


def finish(
    path: Path | str, timeout: float = FINISH_TIMEOUT, *, tolerant: bool = False
) -> str | None:
    """Add the footer to a ``.rrd`` written without one (compacting it on the way).

    Args:
        path: the recording; it is replaced atomically, or left as it was.
        timeout: seconds the rewrite may take.
        tolerant: read past damage (a file cut off by a crash) instead of failing.

    Returns:
        ``None`` when the file was finished, else the problem in one line (the raw file is
        kept unchanged).
    """
    p = Path(path)
    if not p.is_file():
        return f"{p}: no such file"
    try:
        with p.open("rb") as f:
            magic = f.read(len(RRD_MAGIC))
    except OSError as err:
        return f"cannot read {p}: {err.strerror or err}"
    if magic != RRD_MAGIC:
        return f"{p} is not a rerun recording (it does not start with {RRD_MAGIC!r})"
    tmp = p.with_name(f".{p.name}.{os.getpid()}.finishing")
    cmd = [rerun_cli(), "rrd", "optimize", "--output", str(tmp), str(p)]
    if tolerant:
        cmd.insert(3, "--continue-on-error")
    try:
        # its own session: a second Ctrl-C on the terminal does not cut the rewrite short
        out = subprocess.run(
            cmd, capture_output=True, text=True, timeout=timeout, start_new_session=True
        )
    except subprocess.TimeoutExpired:
        _remove(tmp)
        return f"finishing {p} took over {timeout:g} s; the raw file is kept"
    except OSError as err:
        _remove(tmp)
        return f"cannot run {cmd[0]}: {err.strerror or err}"
    if out.returncode != 0 or not tmp.is_file() or tmp.stat().st_size == 0:
        _remove(tmp)
        lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
        why = " ".join(lines[-1].split()) if lines else f"exit {out.returncode}"
        return f"finishing {p} failed ({why}); the raw file is kept"
    try:
        os.replace(tmp, p)
    except OSError as err:
        _remove(tmp)
        return f"finishing {p} failed ({err.strerror or err}); the raw file is kept"
    return None


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()
