"""Files the user names: read within a size limit, written without harming anything else.

Reading (:func:`read_limited`): only regular files are read. A device, FIFO, socket or
folder is refused before it is opened (a FIFO would block, ``/dev/zero`` never ends); a
file larger than the limit of its kind (:data:`LIMITS`) is refused before reading, and a
file that grows while it is read is cut off at the limit and refused. No reader of the
CLI or the daemon reads more than these limits.

Writing (:func:`write_atomic`, :func:`open_output`, :func:`output_folder`): an output path
may name a regular file (replaced) or nothing (created). Anything else — a character or
block device, a FIFO, a socket, a folder where a file is expected, a file where a folder
is expected — is refused in one line and left as it is.

Symbolic links are **followed**, as a shell redirection follows them: writing to a link
replaces its target (atomically, in the target's folder, keeping the target's permission
bits) and the link stays a link. A link to a device is refused like the device; a
dangling link creates its target. A link is the user's own statement of where the data
goes; refusing it would break the common lab set-up of a results folder linked to a
bigger disk.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType

from legws_daemon.errors import InputError

KiB = 1024
MiB = 1024 * KiB

#: Largest size, in bytes, of each kind of file legws reads. Each is at least ten times
#: the largest real file of its kind (the shipped scenes and task graphs are 1-3 KiB, a
#: plan of the feeding graph 9 KiB, an optimiser's elites 0.4 MiB) and small enough that
#: parsing it takes well under a second and a few tens of MiB. The line formats are read
#: a line at a time and held parsed: a joystick log of 32 MiB is two hours at 20 Hz
#: (155,000 messages of ~220 bytes, ~2 s to validate), a teleoperation trace of 32 MiB
#: 250,000 ticks (~3 s, ~80 MiB).
LIMITS: dict[str, int] = {
    "scene": 256 * KiB,
    "layout": 256 * KiB,
    "goal set": 1 * MiB,
    "task graph": 256 * KiB,
    "plan": 4 * MiB,
    "hardware profile": 256 * KiB,
    "input mapping": 256 * KiB,
    "zenoh config": 256 * KiB,
    "joystick log": 32 * MiB,
    "elites": 8 * MiB,
    "summary": 4 * MiB,
    "reachability map": 256 * MiB,
    "robot model file": 64 * MiB,
    "picture": 64 * MiB,
    "cache file": 64 * MiB,
    "recording": 64 * 1024 * MiB,
    "password file": 64 * KiB,
    "certificate": 256 * KiB,
    "camera calibration": 64 * KiB,
    "teleoperation trace": 32 * MiB,
    "operator": 64 * KiB,
    "study protocol": 256 * KiB,
    "study population": 256 * KiB,
    "study schedule": 64 * MiB,
    "study session": 64 * MiB,
    "study table": 256 * MiB,
    "text": 1 * MiB,
}
#: Longest line of a file read line by line (:func:`read_lines`): a trace's tick is ~100
#: bytes.
MAX_LINE = 64 * KiB

_CHUNK = 1 * MiB


_KINDS = {
    stat.S_IFREG: "regular file",
    stat.S_IFDIR: "folder",
    stat.S_IFCHR: "character device",
    stat.S_IFBLK: "block device",
    stat.S_IFIFO: "FIFO",
    stat.S_IFSOCK: "socket",
    stat.S_IFLNK: "symbolic link",
}


def file_kind(mode: int) -> str:
    """What a file of this ``st_mode`` is, in words (``"character device"``...)."""
    return _KINDS.get(stat.S_IFMT(mode), "special file")


def _size(n: int) -> str:
    if n >= MiB:
        return f"{n / MiB:.0f} MiB" if n % MiB == 0 else f"{n / MiB:.1f} MiB"
    if n >= KiB:
        return f"{n / KiB:.0f} KiB" if n % KiB == 0 else f"{n / KiB:.1f} KiB"
    return f"{n} bytes"


def limit_of(kind: str) -> int:
    """The size limit of a kind of file (:data:`LIMITS`)."""
    try:
        return LIMITS[kind]
    except KeyError:
        raise ValueError(f"no size limit for files of kind {kind!r}") from None


def _cannot(err: OSError, path: Path, verb: str = "read") -> InputError:
    if isinstance(err, FileNotFoundError):
        return InputError("no such file", source=str(path))
    if isinstance(err, NotADirectoryError):
        return InputError("a part of the path is not a folder", source=str(path))
    return InputError(f"cannot {verb}: {err.strerror or err}", source=str(path))


def regular_file(path: Path, kind: str = "text") -> os.stat_result:
    """The ``stat`` of ``path`` when it is a regular file within the limit of ``kind``.

    Raises:
        InputError: one line naming the path: missing, not a regular file, or too large.
    """
    try:
        st = os.stat(path)
    except (OSError, ValueError) as err:  # ValueError: a NUL byte in the path
        if isinstance(err, ValueError):
            raise InputError("the path holds a NUL character", source=repr(str(path))) from None
        raise _cannot(err, path) from None
    _check_regular(st, path, kind)
    return st


def _check_regular(st: os.stat_result, path: Path, kind: str) -> None:
    if stat.S_ISDIR(st.st_mode):
        raise InputError("is a folder, expected a file", source=str(path))
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"is a {file_kind(st.st_mode)}, expected a regular file", source=str(path))
    limit = limit_of(kind)
    if st.st_size > limit:
        raise InputError(
            f"is {_size(st.st_size)}, more than the {_size(limit)} allowed for a {kind} file",
            source=str(path),
        )


def read_limited(path: Path, kind: str = "text") -> bytes:
    """The bytes of a regular file of ``kind`` no larger than its limit (:data:`LIMITS`).

    A device, FIFO or socket is refused before it is opened (checked again on the open
    file, which is opened non-blocking so a FIFO swapped in between cannot block); a file
    that grows past the limit while it is read is refused.
    """
    path = Path(path)
    regular_file(path, kind)
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as err:
        raise _cannot(err, path) from None
    try:
        _check_regular(os.fstat(fd), path, kind)
        limit = limit_of(kind)
        parts: list[bytes] = []
        total = 0
        while total <= limit:
            chunk = os.read(fd, min(_CHUNK, limit + 1 - total))
            if not chunk:
                break
            parts.append(chunk)
            total += len(chunk)
    except OSError as err:
        raise _cannot(err, path) from None
    finally:
        os.close(fd)
    if total > limit:
        raise InputError(
            f"grew beyond the {_size(limit)} allowed for a {kind} file while it was read",
            source=str(path),
        )
    return b"".join(parts)


def read_lines(path: Path, kind: str = "text") -> Iterator[tuple[int, str]]:
    """``(line number, text)`` of each line of a regular UTF-8 file of ``kind``, read as it
    goes (never the whole file at once: memory stays at one chunk), with the checks of
    :func:`read_limited`; a line longer than :data:`MAX_LINE` is refused, naming it.

    Raises:
        InputError: one line naming the file (and the line where that is the problem).
    """
    path = Path(path)
    regular_file(path, kind)
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as err:
        raise _cannot(err, path) from None
    try:
        _check_regular(os.fstat(fd), path, kind)
        limit = limit_of(kind)
        total, number, rest = 0, 0, b""
        while True:
            try:
                chunk = os.read(fd, _CHUNK)
            except OSError as err:
                raise _cannot(err, path) from None
            total += len(chunk)
            if total > limit:
                raise InputError(
                    f"grew beyond the {_size(limit)} allowed for a {kind} file while it was read",
                    source=str(path),
                )
            lines = (rest + chunk).split(b"\n")
            rest = lines.pop() if chunk else b""
            if len(rest) > MAX_LINE:
                raise InputError(
                    f"line {number + len(lines) + 1} is longer than {_size(MAX_LINE)}",
                    source=str(path),
                )
            for raw in lines:
                number += 1
                if len(raw) > MAX_LINE:
                    raise InputError(f"line {number} is longer than {_size(MAX_LINE)}",
                                     source=str(path))  # fmt: skip
                try:
                    yield number, raw.decode("utf-8")
                except UnicodeDecodeError:
                    raise InputError(f"line {number}: not UTF-8 text", source=str(path)) from None
            if not chunk:
                return
    finally:
        os.close(fd)


# --- writing -------------------------------------------------------------------------


def output_path(path: Path) -> Path:
    """Where writing ``path`` goes: the path itself, or the target of a symbolic link.

    The result is a regular file or nothing yet, in an existing folder.

    Raises:
        InputError: one line when the path (or its link's target) is a device, FIFO,
            socket or folder, or its folder does not exist.
    """
    path = Path(path)
    if "\0" in str(path):
        raise InputError("the path holds a NUL character", source=repr(str(path)))
    real = Path(os.path.realpath(path))
    try:
        st = os.stat(real)
    except FileNotFoundError:
        parent = real.parent
        if not parent.is_dir():
            what = "does not exist" if not parent.exists() else "is not a folder"
            raise InputError(
                f"cannot write: its folder {parent} {what}", source=str(path)
            ) from None
        return real
    except OSError as err:
        raise _cannot(err, path, "write") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError("is a folder, expected a file to write", source=str(path))
    if not stat.S_ISREG(st.st_mode):
        link = f" (a link to {real})" if real != Path(os.path.abspath(path)) else ""
        raise InputError(
            f"is a {file_kind(st.st_mode)}{link}; refusing to write over it", source=str(path)
        )
    return real


def write_atomic(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename.

    A reader sees the old file or the new one, never half of one. ``path`` must be a
    regular file or nothing (:func:`output_path`; a symbolic link's target is replaced, the
    link kept). A replaced file keeps its permission bits; a new one gets the usual mode
    (0666 less the umask). A failure leaves no temporary file behind and is an
    :class:`InputError` naming the path. Returns ``path``.
    """
    path = Path(path)
    real = output_path(path)
    tmp = real.parent / f".{real.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    try:
        with tmp.open("xb") as out:
            out.write(data)
            with contextlib.suppress(FileNotFoundError):
                os.fchmod(out.fileno(), stat.S_IMODE(os.stat(real).st_mode))
        os.replace(tmp, real)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise InputError(f"cannot write: {err.strerror or err}", source=str(path)) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def output_folder(path: Path) -> Path:
    """Create the folder ``path`` (and its parents) unless it exists; returns ``path``.

    Raises:
        InputError: one line when something that is not a folder is in the way (a file,
            a device, a dangling link) or the folder cannot be created.
    """
    path = Path(path)
    if "\0" in str(path):
        raise InputError("the path holds a NUL character", source=repr(str(path)))
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise InputError(
            "cannot create the folder: a file is in the way", source=str(path)
        ) from None
    except OSError as err:
        raise _cannot(err, path, "create the folder") from None
    if st is not None:
        if not stat.S_ISDIR(st.st_mode):
            raise InputError(
                f"is a {file_kind(st.st_mode)}, expected a folder to write into", source=str(path)
            )
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        if isinstance(err, FileExistsError) or err.errno == errno.ENOTDIR:
            raise InputError(
                "cannot create the folder: a file is in the way", source=str(path)
            ) from None
        raise _cannot(err, path, "create the folder") from None
    return path


class LineFile:
    """A text file written line by line that never ends in a partial line.

    Each :meth:`write` is one or more whole lines, written unbuffered; when a write fails
    (a full disk), the file is cut back to its last whole line, closed, and the error is
    raised as an :class:`InputError` naming the file. Opened by :func:`open_output`.
    """

    def __init__(self, fd: int, path: Path) -> None:
        self._fd: int | None = fd
        self.path = path
        self._end = os.lseek(fd, 0, os.SEEK_END)

    @property
    def closed(self) -> bool:
        return self._fd is None

    def write(self, text: str) -> int:
        """Write ``text`` (whole lines); returns the number of characters written."""
        if self._fd is None:
            raise InputError("the file is closed after an earlier failure", source=str(self.path))
        data = text.encode("utf-8")
        view = memoryview(data)
        try:
            while view:
                n = os.write(self._fd, view)
                view = view[n:]
        except OSError as err:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, self._end)  # no partial line is left behind
            self.close()
            raise InputError(
                f"cannot write: {err.strerror or err}", source=str(self.path)
            ) from None
        self._end += len(data)
        return len(text)

    def fileno(self) -> int:
        """The file descriptor (to hand the file to a child process as its output)."""
        if self._fd is None:
            raise ValueError("the file is closed")
        return self._fd

    def flush(self) -> None:
        """Nothing to do: every write goes straight to the file."""

    def close(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)

    def __enter__(self) -> LineFile:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def open_output(path: Path, *, append: bool = False) -> LineFile:
    """Open ``path`` to write lines to as they come (a trace, a recording of messages).

    Like :func:`write_atomic`, only a regular file or nothing is accepted (a symbolic
    link is followed); the file is truncated unless ``append``.
    """
    path = Path(path)
    real = output_path(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0)
    flags |= os.O_APPEND if append else os.O_TRUNC
    try:
        fd = os.open(real, flags | os.O_NONBLOCK, 0o666)
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # swapped for a device since the check
            os.close(fd)
            raise InputError(
                f"is a {file_kind(st.st_mode)}; refusing to write over it", source=str(path)
            )
        os.set_blocking(fd, True)
    except OSError as err:
        raise _cannot(err, path, "open for writing") from None
    return LineFile(fd, path)


def last_line(path: Path, tail: int = 4 * KiB) -> str:
    """The last non-empty line within the final ``tail`` bytes of a log ("" if none)."""
    try:
        with Path(path).open("rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                return ""
            f.seek(max(0, os.fstat(f.fileno()).st_size - tail))
            lines = f.read(tail).decode("utf-8", errors="replace").strip().splitlines()
    except OSError:
        return ""
    return lines[-1] if lines else ""
