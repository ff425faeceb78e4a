"""Rerun's web viewer on this machine: ``--rerun web[:[HOST:]PORT]`` and ``legws view --web``.

:class:`WebViewer` runs the ``rerun`` CLI as a child process::

    rerun --serve-web --bind HOST --port PORT+1 --web-viewer-port PORT \\
          --server-memory-limit 1GiB [FILE.rrd]

which serves the web viewer's page over HTTP on ``PORT`` (default 9090) and a gRPC proxy on
``PORT+1``: SDKs log into it (:attr:`WebTarget.grpc_url`), and it keeps up to the memory
limit of what they logged for browsers that open the page later. With a file it serves the
file instead. The page is :attr:`WebTarget.page_url`. Both listen on ``HOST`` only,
127.0.0.1 unless told otherwise (the SDK's own ``serve_grpc``/``serve_web_viewer`` bind
every interface, so they are not used).

The child is tied to this process: it gets SIGTERM when the thread that started it ends
(Linux ``PR_SET_PDEATHSIG``), and it runs in a session of its own, so :func:`stop_process`
ends it and anything it started. Its output goes to a log file in a temporary folder; the
last error line of that log is what a failure reports.

The helpers (:func:`viewer_binary`, :func:`spawn`, :func:`stop_process`, :func:`port_free`,
:func:`accepting`) are shared with :mod:`.screenshot`.
"""

from __future__ import annotations

import ctypes
import ipaddress
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from urllib.parse import quote

from legws_daemon.errors import InputError
from legws_daemon.formats.printable import without_terminal_sequences
from legws_daemon.telemetry.rerun_log import viewer_executable
from legws_daemon.telemetry.rrd_file import rerun_cli

DEFAULT_HOST = "127.0.0.1"
#: Port of the web page; the gRPC proxy listens on the next one.
DEFAULT_WEB_PORT = 9090
WEB_FORMS = "web, web:PORT or web:HOST:PORT"
#: Seconds a child gets to exit after SIGTERM before it is killed.
STOP_GRACE = 3.0
_PR_SET_PDEATHSIG = 1
_LOG_TAIL = 64 * 1024


@dataclass(frozen=True)
class WebTarget:
    """Where the web viewer listens: the page on ``web_port``, gRPC on ``grpc_port``."""

    host: str = DEFAULT_HOST
    web_port: int = DEFAULT_WEB_PORT
    grpc_port: int = DEFAULT_WEB_PORT + 1

    @property
    def url_host(self) -> str:
        """The host to put in URLs: 127.0.0.1 for the unspecified address 0.0.0.0."""
        return "127.0.0.1" if self.host == "0.0.0.0" else self.host

    @property
    def grpc_url(self) -> str:
        """What SDKs log into: ``rerun+http://HOST:GRPC/proxy``."""
        return f"rerun+http://{self.url_host}:{self.grpc_port}/proxy"

    @property
    def page_url(self) -> str:
        """The page to open in a browser; it connects to :attr:`grpc_url`."""
        return f"http://{self.url_host}:{self.web_port}/?url={quote(self.grpc_url, safe='')}"


def parse_web_target(arg: str | None, *, field: str = "--rerun") -> WebTarget:
    """Parse what follows ``web:`` in ``--rerun web[:[HOST:]PORT]`` (``None`` for ``web``).

    ``HOST`` is an IPv4 address or ``localhost`` (read as 127.0.0.1), 127.0.0.1 by default;
    ``PORT`` is the web page's port, 9090 by default, and the gRPC stream is on ``PORT+1``.

    Raises:
        InputError: one line naming ``field`` when the host or the port is not valid.
    """
    if arg is None:
        return WebTarget()
    host_text, sep, port_text = arg.rpartition(":")
    host = DEFAULT_HOST
    if sep:
        if host_text == "localhost":
            host = "127.0.0.1"
        else:
            try:
                host = str(ipaddress.IPv4Address(host_text))
            except ValueError:
                raise InputError(
                    f"expected an IPv4 address or localhost as the host, got {host_text!r} "
                    f"(forms: {WEB_FORMS})",
                    field=field,
                ) from None
    text = port_text.strip()
    if not (text.isascii() and text.isdigit()) or not 1 <= int(text) <= 65534:
        raise InputError(
            f"expected a port 1-65534 (the web page; gRPC uses the next one), got "
            f"{port_text!r} (forms: {WEB_FORMS})",
            field=field,
        )
    port = int(text)
    return WebTarget(host, port, port + 1)


# --- child processes -------------------------------------------------------------------


def viewer_binary() -> Path:
    """The ``rerun`` binary itself: the one bundled with rerun-sdk, else
    :func:`~legws_daemon.telemetry.rerun_log.viewer_executable` (whose venv script is a
    Python shim around the binary, so a death signal would reach only the shim).

    Raises:
        InputError: when there is no Rerun viewer (one line: what to install).
    """
    bundled = Path(rerun_cli())
    if bundled.is_absolute() and bundled.is_file() and os.access(bundled, os.X_OK):
        return bundled
    return viewer_executable()


def die_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` that asks Linux to SIGTERM the child when this thread ends."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None
    prctl = libc.prctl
    parent = os.getpid()

    def set_death_signal() -> None:
        prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent:  # the parent died before the call
            os._exit(1)

    return set_death_signal


def spawn(
    args: list[str], log: Path, env: Mapping[str, str] | None = None
) -> subprocess.Popen[bytes]:
    """Start ``args`` in a session of its own, tied to this thread, output to ``log``.

    The environment is this process's plus ``env``, with Rerun's analytics off and plain
    (uncoloured) log lines.
    """
    full = {
        **os.environ,
        "RERUN_TELEMETRY_ENABLED": "false",
        "NO_COLOR": "1",
        "RUST_BACKTRACE": "0",
        **(env or {}),
    }
    with log.open("wb") as out:
        try:
            return subprocess.Popen(
                args,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=full,
                start_new_session=True,
                preexec_fn=die_with_parent(),  # only prctl: safe after fork
            )
        except OSError as err:
            raise InputError(f"cannot start {args[0]}: {err.strerror or err}") from None


def _signal_group(proc: subprocess.Popen[bytes], sig: signal.Signals) -> None:
    try:
        os.killpg(proc.pid, sig)  # the child leads its own session and process group
    except (ProcessLookupError, PermissionError):
        if proc.poll() is None:
            proc.send_signal(sig)


def stop_process(proc: subprocess.Popen[bytes], grace: float = STOP_GRACE) -> None:
    """End a child of :func:`spawn` and its process group: SIGTERM, SIGKILL after ``grace``."""
    if proc.poll() is not None:
        return
    _signal_group(proc, signal.SIGTERM)
    try:
        proc.wait(grace)
    except subprocess.TimeoutExpired:
        _signal_group(proc, signal.SIGKILL)
        proc.wait(grace)


def child_error(log: Path) -> str:
    """The line of a child's log that says what went wrong ("" if the log is empty).

    A Rust panic's message, else the last ``ERROR`` line, else the last line.
    """
    try:
        with log.open("rb") as f:
            f.seek(max(0, log.stat().st_size - _LOG_TAIL))
            text = f.read(_LOG_TAIL).decode("utf-8", errors="replace")
    except OSError:
        return ""
    lines = [" ".join(without_terminal_sequences(line).split()) for line in text.splitlines()]
    lines = [line for line in lines if line]
    for needle in ("panicked at", " ERROR ", "error:", "Error:"):
        found = [line for line in lines if needle in line]
        if found:
            return found[-1][:400]
    return lines[-1][:400] if lines else ""


def port_free(host: str, port: int) -> bool:
    """Whether nothing listens on TCP ``host:port`` (a bind to it succeeds)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def accepting(host: str, port: int, timeout: float = 0.2) -> bool:
    """Whether a TCP connection to ``host:port`` succeeds."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


# --- the web viewer --------------------------------------------------------------------


class WebViewer:
    """A running ``rerun --serve-web`` child; a context manager that stops it."""

    def __init__(
        self, target: WebTarget, proc: subprocess.Popen[bytes], workdir: Path, field: str
    ) -> None:
        self.target = target
        self._proc = proc
        self._workdir = workdir
        self._field = field
        self._closed = False

    @classmethod
    def start(
        cls,
        target: WebTarget,
        *,
        recording: Path | None = None,
        memory_limit: str = "1GiB",
        timeout: float = 20.0,
        field: str = "--rerun",
    ) -> WebViewer:
        """Start the web viewer and return once both its ports accept connections.

        Args:
            target: where to listen (:func:`parse_web_target`).
            recording: a ``.rrd`` to serve instead of a live gRPC proxy.
            memory_limit: ``--server-memory-limit``: how much the proxy keeps for late
                viewers (``1GiB``, ``25%``...).
            timeout: seconds to wait for the ports.
            field: the option an error names.

        Raises:
            InputError: one line when a port is taken, the child exits early or the
                timeout passes; the child is stopped.
        """
        for port, what in ((target.web_port, "web page"), (target.grpc_port, "gRPC stream")):
            if not port_free(target.host, port):
                raise InputError(
                    f"port {port} on {target.host} (the {what}) is already in use; "
                    f"choose another with web:PORT (the web page's port; gRPC uses PORT+1)",
                    field=field,
                )
        exe = viewer_binary()
        workdir = Path(tempfile.mkdtemp(prefix="legws-web-viewer-"))
        args = [str(exe), "--serve-web", "--bind", target.host, "--port", str(target.grpc_port)]
        args += ["--web-viewer-port", str(target.web_port)]
        args += ["--server-memory-limit", memory_limit]
        if recording is not None:
            args.append(str(recording))
        env = {"RUST_LOG": os.environ.get("RUST_LOG", "warn")}
        try:
            proc = spawn(args, workdir / "rerun.log", env)
        except BaseException:
            shutil.rmtree(workdir, ignore_errors=True)
            raise
        viewer = cls(target, proc, workdir, field)
        try:
            viewer._wait_ready(timeout)
        except BaseException:
            viewer.close()
            raise
        return viewer

    @property
    def log(self) -> Path:
        """The child's output (stdout and stderr); removed by :meth:`close`."""
        return self._workdir / "rerun.log"

    @property
    def pid(self) -> int:
        return self._proc.pid

    @property
    def running(self) -> bool:
        return self._proc.poll() is None

    def _wait_ready(self, timeout: float) -> None:
        host = self.target.url_host
        deadline = time.monotonic() + timeout
        waiting = [self.target.web_port, self.target.grpc_port]
        while waiting:
            code = self._proc.poll()
            if code is not None:
                raise InputError(
                    f"the Rerun web viewer exited (code {code}): "
                    f"{child_error(self.log) or 'no output'}",
                    field=self._field,
                )
            waiting = [port for port in waiting if not accepting(host, port)]
            if not waiting:
                return
            if time.monotonic() > deadline:
                note = child_error(self.log)
                raise InputError(
                    f"the Rerun web viewer did not listen on {host}:{waiting[0]} within "
                    f"{timeout:g} s" + (f": {note}" if note else ""),
                    field=self._field,
                )
            time.sleep(0.05)

    def wait(self) -> int:
        """Block until the child exits (Ctrl-C raises KeyboardInterrupt); its exit code."""
        return self._proc.wait()

    def close(self) -> None:
        """Stop the child (SIGTERM, SIGKILL after a few seconds) and remove its log; idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            stop_process(self._proc)
        finally:
            shutil.rmtree(self._workdir, ignore_errors=True)

    def __enter__(self) -> WebViewer:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
