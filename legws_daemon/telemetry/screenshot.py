"""A picture of a recording as the Rerun viewer shows it, without a display.

:func:`screenshot_recording` starts the native viewer headless on a free loopback port::

    rerun --headless --renderer vulkan --bind 127.0.0.1 --port P --window-size WxH

(Vulkan, in software with Mesa's lavapipe when there is no GPU: Debian package
mesa-vulkan-drivers), drives it with :class:`rerun.experimental.ViewerClient`: opens the
file, polls :meth:`~rerun.experimental.ViewerClient.get_state` until nothing is loading
and the recording has its timelines, puts the time cursor on the ``time`` timeline
(paused), and takes a screenshot of the whole viewer (views, time panel and all).

Without a time the cursor goes to the recording's last posterior value
(:func:`last_posterior_time`: the end of its last inference), where the posterior plot,
which shows the time before the cursor, has its curves; a session that went on idle after
its last decision would show an empty plot at its end. A recording without a posterior
(not the daemon's) is shown at its end.

The viewer shows its log messages as notification toasts over the views for a few
seconds. Its log level is set to ``error`` (``RUST_LOG``), which leaves only the toast of
its gRPC address, shown at start-up. The headless viewer's clock is the frames it draws
(it draws when asked for a picture), not the wall clock: after 6 s idle the toast was still
there, and on a busy machine after 4 s of pictures every quarter second too. So
:data:`TOAST_PICTURES` small pictures are asked for first (the toast was gone after 4-6,
at any pace), then the screenshot.
"""

from __future__ import annotations

import contextlib
import math
import socket
import subprocess
import tempfile
import time as clock
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path, regular_file, write_atomic
from legws_daemon.telemetry.rerun_log import POSTERIOR_PREFIX
from legws_daemon.telemetry.rrd_file import RRD_MAGIC
from legws_daemon.telemetry.web_viewer import (
    accepting,
    child_error,
    spawn,
    stop_process,
    viewer_binary,
)

#: The timeline ``--time`` is on (a duration in seconds), as :mod:`.rerun_log` writes it.
TIME_TIMELINE = "time"
#: Small pictures taken before the screenshot, so the start-up toast is gone: it was gone
#: after 4-6 (at any pace: 0.8 s without pause, 4.7 s with 1 s between them).
TOAST_PICTURES = 12
_THUMBNAIL = 64
#: Picture size limits, in pixels per side.
MIN_SIDE, MAX_SIDE = 64, 8192
_VULKAN_HINT = (
    "the headless viewer renders with Vulkan; without a GPU install Mesa's software "
    "Vulkan (Debian package mesa-vulkan-drivers)"
)
_PORT_ATTEMPTS = 3
#: Nanoseconds of rounding allowed at the ends of the recording's time range.
_SLACK_NS = 1000


def screenshot_recording(
    rrd: Path,
    out: Path,
    *,
    time: float | None = None,
    size: tuple[int, int] = (1600, 1000),
    timeout: float = 60.0,
) -> Path:
    """Write a PNG of the recording ``rrd`` as the viewer shows it at ``time``.

    Args:
        rrd: a Rerun recording (``.rrd``).
        out: the PNG to write (atomically; a regular file or nothing).
        time: seconds on the ``time`` timeline; when ``None``, the recording's last
            posterior value (:func:`last_posterior_time`), else its end.
        size: the viewer's window, width and height in pixels.
        timeout: seconds the whole run may take.

    Returns:
        ``out``.

    Raises:
        InputError: one line: a missing or foreign file, a time outside the recording,
            an output that cannot be written, no Vulkan, or the viewer failing.
    """
    rrd, out = Path(rrd), Path(out)
    if time is not None and not math.isfinite(time):
        raise InputError(f"expected a finite number of seconds, got {time!r}", field="--time")
    width, height = size
    if not all(isinstance(n, int) and MIN_SIDE <= n <= MAX_SIDE for n in size):
        raise InputError(
            f"expected a width and height of {MIN_SIDE}-{MAX_SIDE} pixels, got {width}x{height}",
            field="--size",
        )
    if not (math.isfinite(timeout) and timeout > 0):
        raise InputError(f"expected a positive number of seconds, got {timeout!r}", field="timeout")
    check_recording(rrd)
    output_path(out)
    deadline = clock.monotonic() + timeout
    if time is None:
        time = last_posterior_time(rrd)
    with tempfile.TemporaryDirectory(prefix="legws-screenshot-") as tmp:
        png = _capture(rrd.resolve(), time, size, Path(tmp), deadline)
    return write_atomic(out, png)


def check_recording(rrd: Path) -> None:
    """Refuse in one line what is not a regular file starting like a Rerun recording."""
    try:
        regular_file(rrd, "recording")
        with rrd.open("rb") as f:
            magic = f.read(len(RRD_MAGIC))
    except InputError as err:
        raise InputError(f"{err}; expected a rerun recording (.rrd)") from None
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror or err}", source=str(rrd)) from None
    if magic != RRD_MAGIC:
        raise InputError(
            f"is not a rerun recording (it does not start with {RRD_MAGIC!r})", source=str(rrd)
        )


def last_posterior_time(rrd: Path) -> float | None:
    """Seconds on the ``time`` timeline of the recording's last posterior value (a finite
    one: a NaN ends a curve), or ``None`` when it has none or cannot be read here (the
    viewer then says why)."""
    from rerun.chunk import RrdReader

    latest: int | None = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer": a recording that was cut short
            stream = RrdReader(rrd).stream().filter(content=[f"/{POSTERIOR_PREFIX}**"])
            chunks = stream.to_chunks()
    except (RuntimeError, ValueError, OSError):
        return None
    for chunk in chunks:
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if TIME_TIMELINE not in names or "Scalars:scalars" not in names:
            continue
        nanos = batch.column(TIME_TIMELINE).cast("int64").to_pylist()
        for ns, value in zip(nanos, batch.column("Scalars:scalars").to_pylist(), strict=True):
            if ns is not None and value and value[0] is not None and math.isfinite(value[0]):
                latest = ns if latest is None else max(latest, ns)
    return None if latest is None else latest / 1e9


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
    return port


def _capture(
    rrd: Path, time: float | None, size: tuple[int, int], tmp: Path, deadline: float
) -> bytes:
    """Start the headless viewer, take the picture, stop the viewer (also on errors)."""
    runtime = tmp / "runtime"
    runtime.mkdir(mode=0o700)
    log = tmp / "rerun.log"
    env = {"RUST_LOG": "error", "XDG_RUNTIME_DIR": str(runtime)}
    for attempt in range(_PORT_ATTEMPTS):
        port = _free_port()
        args = [str(viewer_binary()), "--headless", "--renderer", "vulkan"]
        args += ["--bind", "127.0.0.1", "--port", str(port)]
        args += ["--window-size", f"{size[0]}x{size[1]}", "--hide-welcome-screen"]
        proc = spawn(args, log, env)
        try:
            if not _wait_listening(proc, port, log, deadline, last=attempt + 1 == _PORT_ATTEMPTS):
                continue  # another process took the port in between: try another
            return _drive(proc, port, rrd, time, log, deadline)
        finally:
            stop_process(proc)
    raise AssertionError("unreachable")  # pragma: no cover


def _viewer_failed(proc: Any, log: Path) -> InputError:
    code = proc.poll()
    note = child_error(log) or "no output"
    exited = f"exited (code {code})" if code is not None else "failed"
    return InputError(f"the headless Rerun viewer {exited}: {note}; {_VULKAN_HINT}")


def _wait_listening(proc: Any, port: int, log: Path, deadline: float, *, last: bool) -> bool:
    """True once the viewer listens; False when its port was taken (unless ``last``)."""
    while not accepting("127.0.0.1", port):
        if proc.poll() is not None:
            if not last and "in use" in child_error(log).lower():
                return False
            raise _viewer_failed(proc, log)
        if clock.monotonic() > deadline:
            raise InputError("the headless Rerun viewer did not start in time")
        clock.sleep(0.05)
    return True


def _drive(
    proc: Any, port: int, rrd: Path, time: float | None, log: Path, deadline: float
) -> bytes:
    from rerun.experimental import ViewerClient

    def call(what: str, fn: Any, *args: Any, **kwargs: Any) -> Any:
        if clock.monotonic() > deadline:
            raise InputError(f"the viewer took too long ({what})", source=str(rrd))
        try:
            return fn(*args, **kwargs)
        except Exception as err:  # the bindings raise RuntimeError, ValueError...
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(2.0)  # a viewer that is dying (a panic) answers "transport error"
            if proc.poll() is not None:
                raise _viewer_failed(proc, log) from None
            text = " ".join(str(err).split())[:300]
            raise InputError(f"the viewer failed to {what}: {text}", source=str(rrd)) from None

    # a viewer without Vulkan can die between listening and the connection: that, too, is
    # its exit and the hint, not the bindings' "transport error"
    client = call("connect", ViewerClient.connect, f"rerun+http://127.0.0.1:{port}/proxy")
    call("start", client.get_state)  # the renderer is up (no Vulkan: the child panics)
    opened = call("open the file", client.open, str(rrd))
    store_id, timelines = _wait_loaded(call, client, opened.store_ids, rrd, deadline)
    _seek(call, client, store_id, timelines, time, rrd)
    for _ in range(TOAST_PICTURES):  # the toast's clock runs by frames drawn, not by seconds
        call("draw", client.take_screenshot, max_size=_THUMBNAIL)
    png: bytes = call("take the screenshot", client.take_screenshot)
    if not png.startswith(b"\x89PNG"):
        raise InputError("the viewer returned no picture", source=str(rrd))
    return png


def _wait_loaded(
    call: Any, client: Any, store_ids: list[str], rrd: Path, deadline: float
) -> tuple[str, dict[str, Any]]:
    """The recording's store id and its timelines by name, once loaded."""
    settled: float | None = None
    while True:
        state = call("load the file", client.get_state)
        wanted = [r for r in state.recordings if r.store_id in store_ids] or [
            r for r in state.recordings if r.store_id == state.active_recording
        ]
        if not state.loading and wanted:
            recording = wanted[0]
            if recording.timelines:
                return recording.store_id, {t.name: t for t in recording.timelines}
            # static data only, or still arriving: give it a moment
            settled = settled or clock.monotonic()
            if clock.monotonic() - settled > 2.0:
                return recording.store_id, {}
        elif not state.loading and not wanted and settled is None:
            settled = clock.monotonic()
        elif not state.loading and settled is not None and clock.monotonic() - settled > 2.0:
            raise InputError(
                f"the viewer found no recording in it: {_last_error(call, client)} (a file "
                "cut off by a crash is repaired by `legws recording finish FILE`)",
                source=str(rrd),
            )
        if clock.monotonic() > deadline:
            raise InputError("the viewer did not finish loading it in time", source=str(rrd))
        clock.sleep(0.1)


def _last_error(call: Any, client: Any) -> str:
    """The viewer's last logged error, on one line (it says why a file did not load)."""
    entries = call("read its log", client.get_logs)
    errors = [e.message for e in entries if e.level == "ERROR"]
    if not errors:
        return "no error logged"
    text = " ".join(errors[-1].split())
    return text if len(text) <= 300 else text[:297] + "..."


def _seek(
    call: Any,
    client: Any,
    store_id: str,
    timelines: dict[str, Any],
    time: float | None,
    rrd: Path,
) -> None:
    """Put the cursor at ``time`` s on the ``time`` timeline, or at the recording's end."""
    line = timelines.get(TIME_TIMELINE)
    if time is not None:
        if line is None or line.start is None or line.end is None:
            raise InputError(
                f"the recording has no {TIME_TIMELINE!r} timeline to seek on", field="--time"
            )
        ns = round(time * 1e9)
        if not line.start - _SLACK_NS <= ns <= line.end + _SLACK_NS:
            raise InputError(
                f"{time:g} s is outside the recording, which spans "
                f"{line.start / 1e9:g}-{line.end / 1e9:g} s",
                field="--time",
            )
        ns = min(max(ns, line.start), line.end)
    else:
        if line is None:  # no `time`: the end of whichever timeline is not the wall clock
            line = next((t for t in timelines.values() if t.name != "log_time"), None)
        if line is None or line.end is None:
            return
        ns = line.end
    kind = line.time_type
    if kind == "sequence":
        when: dict[str, Any] = {"sequence": int(ns)}
    elif kind == "timestamp":
        when = {"timestamp": np.datetime64(int(ns), "ns")}
    else:
        when = {"duration": np.timedelta64(int(ns), "ns")}
    call(
        "set the time",
        client.set_time,
        line.name,
        play_state="paused",
        recording=store_id,
        **when,
    )
