"""A ``.rrd`` file as a file: its framing checked, its decoding tried apart from this
process, finished (rerun's footer added) only when every message of it is kept.

**Finishing.** The daemon writes ``save:`` recordings *without* a footer. Rerun's file
writer keeps the manifest of every chunk in memory until it writes the footer at the very
end, so over a long session the daemon grows by ~1.5 MiB a minute (the 10-minute soak:
+7.5 % after the first load, against a flat resident set without it). At close the file is
finished with ``rerun rrd optimize``, which writes a footer and compacts the chunks, into a
temporary file in the same folder that then replaces the original atomically: a reader sees
the raw stream or the finished file, never a half-written one. A raw file is still a valid
rerun stream (the viewer opens it); it only lacks the manifest, which ``rerun rrd verify``
requires and which speeds up random access. When finishing fails or takes too long the raw
file is kept, and the error says how to finish it by hand: ``legws recording finish FILE``.

**Whole or not at all.** A file is finished in place only when nothing of it would be lost:
its framing (:func:`scan`: a header, then messages of a known kind and a length, each
ending within the file, the last one at its end or at the footer) covers every byte, and
rerun decodes every message (``rerun rrd optimize`` without ``--continue-on-error``
succeeds). A file cut off in the middle of a message, or with a flipped bit in a length or
in a compressed payload, is left byte for byte as it is: the error says what is damaged and
what could be recovered (the chunks rerun still decodes before the first break of the
framing, and the latest ``time`` among them), and :func:`finish_recording` with ``out``
writes that part to another file, never over the input. A symbolic link is followed: its
target is finished in the target's folder and the link stays a link
(:mod:`legws_daemon.formats.files`).

**Decoding apart.** Rerun's decoder aborts the whole process on some damaged payloads (a
Rust panic in the Arrow reader: no Python exception, the interpreter is gone), so no
message of a file is decoded in this process before a ``rerun`` child process has decoded
all of them (:func:`check_readable`, once per version of a file): ``rerun rrd optimize``
for a raw file, ``rerun rrd verify`` (the data and the footer) for a finished one (without
a ``rerun`` executable, a broken installation, the file is read as it is). Rerun's
own log lines (a child's, and those the in-process reader writes on file descriptor 2:
:func:`quiet_stderr`) never reach the terminal; what matters of them ends up in legws's
one-line error.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import re
import secrets
import shutil
import stat
import struct
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from legws_daemon.errors import InputError
from legws_daemon.formats.files import MiB, output_path, regular_file
from legws_daemon.formats.printable import without_terminal_sequences

#: Seconds ``rerun rrd optimize`` may take at close. It reads the whole file: ~1.7 s for a
#: 48 MiB recording (6 minutes at 50 Hz) on the 2-core development machine.
FINISH_TIMEOUT = 60.0
#: The first bytes of an ``.rrd`` stream of this rerun's protocol.
RRD_MAGIC = b"RRF2"
#: The last bytes but four of a finished stream: its footer's trailer (the manifest's
#: place and length, a CRC, these bytes, a version).
FOOTER_MAGIC = b"RRF2FOOT"
_STREAM_HEADER = 12  # the magic, the writer's version (4 bytes), the encoding options (4)
_MESSAGE_HEADER = 16  # kind (u64), payload length (u64)
_FOOTER_TRAILER = 32
#: The message kinds of the protocol: end of stream (its payload: the footer), store info,
#: a chunk of data, a blueprint activation.
_KINDS = {0: "end of stream", 1: "store info", 2: "chunk", 3: "blueprint activation"}
_END, _CHUNK = 0, 2
#: Bytes per second ``rerun`` reads at least, for a file's own time limit (the development
#: machine decodes ~100 MiB/s; a limit never below :data:`FINISH_TIMEOUT`).
_SLOWEST_READ = 10 * MiB
#: Most runs of ``rerun rrd optimize`` spent on a damaged file that crashes rerun's reader,
#: bisecting for the longest prefix of its messages rerun decodes.
_MAX_ATTEMPTS = 24
#: What of a child's stderr is kept (its last bytes).
_STDERR_TAIL = 64 * 1024


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


def rerun_version() -> tuple[int, int, int]:
    """The version of the installed rerun-sdk (``0.41.0`` -> ``(0, 41, 0)``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        text = version("rerun-sdk")
    except PackageNotFoundError:
        return (0, 0, 0)
    found = re.match(r"(\d+)\.(\d+)\.(\d+)", text)
    return (int(found[1]), int(found[2]), int(found[3])) if found else (0, 0, 0)


def _version_text(v: Sequence[int]) -> str:
    return ".".join(str(n) for n in v)


def repair_hint(path: Path | str) -> str:
    """How to get what can be recovered of a damaged recording."""
    return (
        "write what can be recovered to another file with: "
        f"legws recording finish {path} --out OTHER.rrd"
    )


# --- the framing ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Scan:
    """The framing of a ``.rrd`` file, read from its message headers alone.

    Attributes:
        size: bytes in the file.
        version: the rerun version that wrote it (its first stream header).
        starts, ends: where each whole message (its header) starts and where it ends, in
            order, up to the first break.
        kinds: each one's kind (:data:`_KINDS`).
        footer: the file ends with rerun's footer (it is finished).
        intact: the bytes from the start that are framed (``size`` when nothing is broken).
        damage: where and how the framing breaks (``None``: every byte is framed).
    """

    size: int
    version: tuple[int, int, int]
    starts: tuple[int, ...]
    ends: tuple[int, ...]
    kinds: bytes
    footer: bool
    intact: int
    damage: str | None

    @property
    def chunks(self) -> int:
        """Whole chunk messages before the first break."""
        return self.kinds.count(_CHUNK)

    def chunks_in(self, messages: Sequence[int]) -> int:
        """Chunk messages among those of these indices."""
        return sum(1 for i in messages if self.kinds[i] == _CHUNK)


def _header_problem(head: bytes) -> str | None:
    """What is wrong with a stream header (``None``: it is one of this protocol)."""
    if head[:4] != RRD_MAGIC:
        return f"it does not start with {RRD_MAGIC!r}"
    compression, serializer, *reserved = head[8:12]
    if compression not in (0, 1) or serializer != 2 or any(reserved):
        return f"its header is damaged (unknown encoding options {head[8:12].hex()})"
    return None


def scan(
    path: Path, what: str = "not a rerun recording (.rrd)", *, name: str | None = None
) -> Scan:
    """The framing of the ``.rrd`` file ``path`` (reads the message headers only).

    Raises:
        InputError: the file is not a rerun recording of this protocol (another start, a
            header of unknown options: ``what``, then why; a version newer than the
            installed rerun), or it cannot be read; naming ``name`` (default: ``path``).
    """
    source = str(path) if name is None else name
    try:
        with path.open("rb") as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(_STREAM_HEADER)
            problem = (
                f"it does not start with {RRD_MAGIC!r}"
                if len(head) < _STREAM_HEADER
                else _header_problem(head)
            )
            if problem is not None:
                raise InputError(f"{what}: {problem}", source=source)
            version = (head[4], head[5], head[6])
            local = rerun_version()
            if version[:2] > local[:2]:
                raise InputError(
                    f"written by rerun {_version_text(version)}, newer than the rerun "
                    f"{_version_text(local)} legws reads with",
                    source=source,
                )
            return _frames(f, size, version)
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", source=source) from None


def _frames(f: Any, size: int, version: tuple[int, int, int]) -> Scan:
    starts: list[int] = []
    ends: list[int] = []
    kinds = bytearray()
    off = intact = _STREAM_HEADER
    footer = False
    damage = None
    while off < size:
        f.seek(off)
        head = f.read(_MESSAGE_HEADER)
        if head[:4] == RRD_MAGIC:  # another stream follows (files concatenated)
            problem = (
                "it ends in the middle of a stream header"
                if len(head) < _STREAM_HEADER
                else _header_problem(head[:_STREAM_HEADER])
            )
            if problem is not None:
                damage = f"at byte {off}: {problem}"
                break
            off = intact = off + _STREAM_HEADER
            footer = False
            continue
        if len(head) < _MESSAGE_HEADER:
            damage = f"it ends at byte {size}, in the middle of a message header"
            break
        kind, length = struct.unpack("<QQ", head)
        if kind not in _KINDS:
            damage = f"at byte {off}: not a message (kind {kind})"
            break
        end = off + _MESSAGE_HEADER + length
        if end > size:
            left = size - off - _MESSAGE_HEADER
            damage = (
                f"the message at byte {off} is {length} bytes long, the file ends {left} "
                "bytes after its header (cut off, or a damaged length)"
            )
            break
        starts.append(off)
        ends.append(end)
        kinds.append(kind)
        off = intact = end
        footer = False
        if kind == _END and size - off >= _FOOTER_TRAILER:
            f.seek(off)
            trailer = f.read(_FOOTER_TRAILER)
            if trailer[20:28] == FOOTER_MAGIC:
                start, span = struct.unpack_from("<QQ", trailer)
                if (start, span) != (end - length, length):
                    damage = f"at byte {off}: the footer does not match its manifest"
                    break
                off = intact = off + _FOOTER_TRAILER
                footer = True
    return Scan(size, version, tuple(starts), tuple(ends), bytes(kinds), footer, intact, damage)


# --- rerun's output ---------------------------------------------------------------------------

_LOG_LINE = re.compile(r"^(?:\S+\s+)?(TRACE|DEBUG|INFO|WARN|ERROR)\s+\S+?:\s+(.*)$")
_CHUNK_COUNT = re.compile(r"Chunk count (\d+) ->")


def rerun_reason(text: str) -> str | None:
    """The gist of rerun's log output (a child's stderr, or what the in-process reader
    wrote): a crash's message, else the first error, else the first warning, else the last
    ``Error:`` line; one line of at most 300 characters, or ``None`` when it says nothing."""
    lines = [without_terminal_sequences(line).strip() for line in text.splitlines()]
    lines = [line for line in lines if line]
    for i, line in enumerate(lines):
        if " panicked at " in line:  # 'message' on this line, or the message on the next
            after = line.split(" panicked at ", 1)[1]
            if after.startswith("'"):
                message = after.strip("'")
            else:
                message = lines[i + 1] if i + 1 < len(lines) else after
            return _clip(f"rerun's reader crashed: {message}")
    for level in ("ERROR", "WARN"):
        for line in lines:
            found = _LOG_LINE.match(line)
            if found and found[1] == level:
                return _clip(_message(found[2]))
    for line in lines:  # rrd verify: '"FILE": what is wrong'
        found = re.match(r'^"[^"]*": (.*)$', line)
        if found:
            return _clip(_message(found[1]))
    errors = [line for line in lines if line.startswith("Error:")]
    return _clip(errors[-1].removeprefix("Error:").strip()) if errors else None


def _message(text: str) -> str:
    """A rerun log message without its structured wrapping (``err="..."``)."""
    quoted = re.search(r'err="(.*)"', text)
    if quoted:
        text = quoted[1].replace('\\"', '"')
    text = re.sub(r'^couldn\'t decode message "[^"]*" -- skipping: ', "", text)
    parts = text.split(": ")  # rerun repeats its causes: keep each once
    kept: list[str] = []
    for part in parts:
        if not any(part in k for k in kept):
            kept.append(part)
    return ": ".join(kept)


def _clip(text: str, limit: int = 300) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


@dataclass
class Captured:
    """What was written on file descriptor 2 during :func:`quiet_stderr`."""

    text: str = ""

    @property
    def reason(self) -> str | None:
        return rerun_reason(self.text)


@contextlib.contextmanager
def quiet_stderr() -> Iterator[Captured]:
    """Run the block with file descriptor 2 (where rerun's Rust logger writes its coloured
    lines) sent to a temporary file; its last 64 KiB are then in the yielded object.

    Python warnings are silenced too (rerun's "no footer" on every raw file). Only for a
    command's own reading: another thread writing to stderr meanwhile is captured as well.
    """
    captured = Captured()
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield captured
        return
    try:
        with tempfile.TemporaryFile() as sink, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            os.dup2(sink.fileno(), 2)
            try:
                yield captured
            finally:
                with contextlib.suppress(OSError, ValueError):
                    sys.stderr.flush()
                os.dup2(saved, 2)
                captured.text = _tail(sink)
    finally:
        os.close(saved)


def _tail(f: Any) -> str:
    end = f.seek(0, os.SEEK_END)
    f.seek(max(0, end - _STDERR_TAIL))
    data: bytes = f.read()
    return data.decode("utf-8", errors="replace")


class _TimeoutError(Exception):
    """A ``rerun`` child ran over its time (and was killed)."""


def _rerun(
    args: list[str],
    timeout: float,
    *,
    feed: tuple[Path, Sequence[tuple[int, int]]] | None = None,
    own_session: bool = False,
) -> tuple[int, str]:
    """Run ``rerun ARGS`` (its stdin: the byte ranges ``feed[1]`` of the file ``feed[0]``,
    else nothing; its stdout discarded); its exit code and its stderr (the last 64 KiB).

    Raises:
        _TimeoutError: it ran over ``timeout`` seconds (and was killed).
        OSError: it could not be started.
    """
    env = {
        **os.environ,
        "RUST_LOG": "error,rerun::commands::rrd::merge_optimize=info",
        "RUST_BACKTRACE": "0",
    }
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(
            [rerun_cli(), *args],
            stdin=subprocess.PIPE if feed is not None else subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=err,
            env=env,
            start_new_session=own_session,  # finishing: a second Ctrl-C does not cut it short
        )
        feeder = None
        if feed is not None:
            feeder = threading.Thread(target=_feed, args=(proc, *feed), daemon=True)
            feeder.start()
        try:
            code = proc.wait(timeout=max(timeout, 0.01))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise _TimeoutError from None
        finally:
            if feeder is not None:
                feeder.join(timeout=5)
        return code, _tail(err)


def _feed(proc: subprocess.Popen[bytes], path: Path, ranges: Sequence[tuple[int, int]]) -> None:
    """Copy the byte ranges ``[start, end)`` of ``path`` to the child's stdin, then close it."""
    pipe = proc.stdin
    assert pipe is not None
    try:
        with path.open("rb") as f:
            for start, end in ranges:
                f.seek(start)
                left = end - start
                while left > 0:
                    data = f.read(min(left, MiB))
                    if not data:
                        break
                    pipe.write(data)
                    left -= len(data)
    except (OSError, ValueError):
        pass  # the child left early (it reports why itself)
    finally:
        with contextlib.suppress(OSError, ValueError):
            pipe.close()


def _time_limit(size: int) -> float:
    return max(FINISH_TIMEOUT, size / _SLOWEST_READ)


# --- reading ----------------------------------------------------------------------------------

#: ``(device, inode, size, mtime)`` of a file -> its problem (``None``: rerun decodes it all).
_CHECKED: dict[tuple[int, int, int, int], str | None] = {}


def check_readable(path: Path) -> Scan:
    """Make sure rerun decodes every message of ``path`` (a regular file) before this process
    decodes any: the framing is whole (:func:`scan`), then a ``rerun`` child process decodes
    the data (and the footer of a finished file). The result is kept per version of the
    file (its inode, size and modification time).

    Raises:
        InputError: one line naming the file: what is damaged, and how to recover the rest.
    """
    source = str(path)
    try:
        st = os.stat(path)
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", source=source) from None
    found = scan(path, "not a readable rerun recording (.rrd)")
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    if key in _CHECKED:
        problem = _CHECKED[key]
    else:
        try:
            problem = _CHECKED[key] = _decode_problem(path, found)
        except OSError:  # no rerun executable to decode it apart: read it as it is
            problem = None
    if problem is not None:
        raise InputError(
            f"not a readable rerun recording (.rrd): {problem}; {repair_hint(path)}",
            source=source,
        )
    return found


def _decode_problem(path: Path, found: Scan) -> str | None:
    if found.damage is not None:
        return found.damage
    args = ["rrd", "verify", str(path)] if found.footer else ["rrd", "optimize", str(path)]
    limit = _time_limit(found.size)
    try:
        code, err = _rerun(args, limit)
    except _TimeoutError:
        return f"rerun took over {limit:g} s to read it"
    if code == 0:
        return None
    return rerun_reason(err) or f"rerun cannot read it (exit {code})"


# --- finishing --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Finished:
    """What :func:`finish_recording` did.

    Attributes:
        source: the recording (its link's target when it is a link).
        written: the finished file (``source``, or ``out``); ``None`` when ``source`` was
            already finished and is left as it was.
        before: bytes of ``source``.
        after: bytes written.
        whole: every message of ``source`` is in what was written.
        damage: what is damaged in ``source`` (``None`` when whole).
        chunks: chunks kept; ``of``: whole chunks in ``source`` before any break.
        seconds: the latest ``time`` among what was kept (when not whole).
    """

    source: Path
    written: Path | None
    before: int
    after: int
    whole: bool
    damage: str | None = None
    chunks: int = 0
    of: int = 0
    seconds: float | None = None


def finish(path: Path | str, timeout: float = FINISH_TIMEOUT) -> str | None:
    """Add the footer to a ``.rrd`` written without one (compacting it on the way), in
    place, when every message of it is kept (:func:`finish_recording`).

    Returns:
        ``None`` when the file was finished, else the problem in one line (the file is kept
        unchanged).
    """
    try:
        finish_recording(Path(path), timeout)
    except InputError as err:
        return str(err)
    return None


def finish_recording(
    path: Path,
    timeout: float = FINISH_TIMEOUT,
    *,
    out: Path | None = None,
    needs: Sequence[str] = (),
) -> Finished:
    """Finish the recording ``path`` (a link: its target, in the target's folder).

    Args:
        path: the recording.
        timeout: seconds the whole of it may take.
        out: write the finished file there instead of over ``path`` (which is then never
            changed); for a damaged file, what can be recovered of it.
        needs: entity paths of which the finished file must hold at least one (``path`` is
            otherwise left as it is: not a recording of this kind).

    Raises:
        InputError: one line naming the file: not a recording, damaged (what could be
            recovered, and how), too slow, or what is in the way of writing.
    """
    deadline = time.monotonic() + timeout
    source = _source(path)
    try:
        st = regular_file(path, "recording")
    except InputError as err:
        raise InputError(f"{err}; expected a rerun recording (.rrd)") from None
    found = scan(source, name=str(path))
    target = None
    if out is not None:
        target = output_path(out)
        if Path(os.path.realpath(target)) == source:
            raise InputError(
                f"is {path} itself; --out must name another file", source=str(out), field="--out"
            )
    folder = (target or source).parent
    tmp = folder / f".{(target or source).name}.{os.getpid()}.{secrets.token_hex(4)}.finishing"
    try:
        return _finish(path, source, st, found, tmp, target, deadline, needs)
    except _TimeoutError:
        raise InputError(
            f"finishing took over {timeout:g} s; the raw file is kept", source=str(path)
        ) from None
    except OSError as err:
        raise InputError(
            f"finishing failed ({err.strerror or err}); the raw file is kept", source=str(path)
        ) from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _source(path: Path) -> Path:
    """The file a recording's path names: itself, or its link's target (which must exist)."""
    if "\0" in str(path):
        raise InputError("the path holds a NUL character", source=repr(str(path)))
    real = Path(os.path.realpath(path))
    if os.path.islink(path) and not real.exists():
        raise InputError(f"is a link to {real}, which does not exist", source=str(path))
    return real


def _left(deadline: float) -> float:
    left = deadline - time.monotonic()
    if left <= 0:
        raise _TimeoutError
    return left


def _finish(
    path: Path,
    source: Path,
    st: os.stat_result,
    found: Scan,
    tmp: Path,
    target: Path | None,
    deadline: float,
    needs: Sequence[str],
) -> Finished:
    tmp.open("xb").close()  # the folder takes a file (else: OSError, the file is kept)
    damage = found.damage
    if damage is None:
        code, err = _rerun(
            ["rrd", "optimize", "--output", str(tmp), str(source)],
            _left(deadline),
            own_session=True,
        )
        if code != 0 or not _nonempty(tmp):
            reason = rerun_reason(err) or f"exit {code}"
            reads, _ = _rerun(["rrd", "optimize", str(source)], _left(deadline))
            if reads == 0:  # rerun reads it all: writing the finished file failed
                raise InputError(f"finishing failed ({reason}); the raw file is kept",
                                 source=str(path))  # fmt: skip
            damage = reason
    whole = damage is None
    chunks = found.chunks
    if not whole:
        chunks = _salvage(source, found, tmp, deadline)
    if whole and needs and not (_entity_paths(tmp) & set(needs)):
        raise InputError(
            f"holds no legws telemetry ({', '.join(needs)}): not a daemon recording; it is "
            "left as it is (rerun rrd optimize finishes any recording)",
            source=str(path),
        )
    if whole:
        if target is None and found.footer and _verified(source, deadline):
            return Finished(source, None, st.st_size, st.st_size, True, of=found.chunks,
                            chunks=found.chunks)  # fmt: skip
        written = _install(tmp, target or source, st if target is None else None)
        return Finished(source, written, st.st_size, written.stat().st_size, True,
                        chunks=found.chunks, of=found.chunks)  # fmt: skip
    assert damage is not None
    seconds = _latest_time(tmp) if chunks else None
    kept = f"{chunks} of {found.chunks} chunks" + (
        "" if seconds is None else f", up to time {seconds:.2f} s"
    )
    if found.intact < found.size:
        kept += f" (the {found.size - found.intact} bytes from byte {found.intact} on are lost)"
    if target is not None and chunks:
        written = _install(tmp, target, None)
        return Finished(source, written, st.st_size, written.stat().st_size, False, damage,
                        chunks, found.chunks, seconds)  # fmt: skip
    if not chunks:
        raise InputError(
            f"cannot be finished: {damage}; nothing of it can be recovered; it is left as it is",
            source=str(path),
        )
    raise InputError(
        f"cannot be finished whole: {damage}; recoverable: {kept}; it is left as it is; "
        f"{repair_hint(path)}",
        source=str(path),
    )


def _nonempty(path: Path) -> bool:
    try:
        return path.stat().st_size > 0
    except OSError:
        return False


def _salvage(source: Path, found: Scan, tmp: Path, deadline: float) -> int:
    """Write to ``tmp`` what rerun decodes of ``source`` up to the first break of its framing
    (``--continue-on-error`` skips the messages it cannot decode). A message on which rerun's
    reader crashes is found by bisection (the shortest prefix that crashes ends with it) and
    left out; after :data:`_MAX_ATTEMPTS` runs, the longest prefix that decodes is kept.
    Returns the chunks kept (0: nothing)."""
    attempts = 0

    def attempt(messages: Sequence[int]) -> int | None:
        """Chunks written to ``tmp`` from these messages; ``None``: rerun's reader failed."""
        nonlocal attempts
        attempts += 1
        ranges = [(0, _STREAM_HEADER), *((found.starts[i], found.ends[i]) for i in messages)]
        code, err = _rerun(
            ["rrd", "optimize", "--continue-on-error", "--output", str(tmp)],
            _left(deadline),
            feed=(source, ranges),
            own_session=True,
        )
        if code != 0 or not _nonempty(tmp):
            return None
        counted = _CHUNK_COUNT.search(without_terminal_sequences(err))
        skipped = err.count("couldn't decode message")
        return int(counted[1]) if counted else max(found.chunks_in(messages) - skipped, 0)

    keep = list(range(len(found.ends)))
    longest = 0  # a prefix of ``keep`` that decodes
    while keep and attempts < _MAX_ATTEMPTS:
        kept = attempt(keep)
        if kept is not None:
            return kept
        lo, hi = longest, len(keep)  # keep[:lo] decodes, keep[:hi] crashes
        while hi - lo > 1 and attempts < _MAX_ATTEMPTS:
            mid = (lo + hi) // 2
            if attempt(keep[:mid]) is None:
                hi = mid
            else:
                lo = mid
        if hi - lo > 1:  # out of attempts
            longest = lo
            break
        del keep[hi - 1]  # the message it crashes on
        longest = lo
    result = attempt(keep[:longest]) if longest else None
    if result is None:
        with contextlib.suppress(OSError):
            tmp.unlink()
    return result or 0


def _verified(path: Path, deadline: float) -> bool:
    """``rerun rrd verify`` accepts ``path`` (its data and its footer)."""
    code, _ = _rerun(["rrd", "verify", str(path)], _left(deadline))
    return code == 0


def _install(tmp: Path, target: Path, keep: os.stat_result | None) -> Path:
    """Put the finished ``tmp`` at ``target`` atomically (keeping the permission bits of the
    file it replaces)."""
    try:
        mode = stat.S_IMODE(keep.st_mode if keep is not None else os.stat(target).st_mode)
    except FileNotFoundError:
        mode = None
    if mode is not None:
        os.chmod(tmp, mode)
    os.replace(tmp, target)
    return target


def _entity_paths(finished: Path) -> set[str]:
    """Entity paths of a finished file (from its manifest; rerun wrote it: safe to open)."""
    from rerun.chunk import RrdReader

    try:
        with quiet_stderr():
            paths = RrdReader(finished).store().schema().entity_paths()
    except Exception:  # a file rerun just wrote: nothing to say but that it has none
        return set()
    return {str(p).lstrip("/") for p in paths}


def _latest_time(finished: Path) -> float | None:
    """The latest value of the ``time`` timeline in a finished file, seconds."""
    import pyarrow.compute as pc  # type: ignore[import-untyped]
    from rerun.chunk import RrdReader

    latest: int | None = None
    try:
        with quiet_stderr():
            stream = RrdReader(finished).stream().filter(has_timeline="time", is_static=False)
            for chunk in stream:
                batch = chunk.to_record_batch()
                index = batch.schema.get_field_index("time")
                if index < 0:
                    continue
                value = pc.max(batch.column(index).cast("int64")).as_py()
                if isinstance(value, int):
                    latest = value if latest is None else max(latest, value)
    except Exception:
        return None
    return None if latest is None else latest / 1e9
