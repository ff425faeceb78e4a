"""Child processes of the end-to-end bridge tests (a robot, a bridge, a daemon, ...).

Each runs in a session of its own (its own process group), its output collected line by
line by a thread; :meth:`Process.stop` always ends it (SIGTERM, then SIGKILL to the group).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
import time
from collections.abc import Mapping
from typing import IO

#: Time a process has to end on SIGTERM before its group is killed, s.
STOP_TIMEOUT = 10.0


class Process:
    """A child process and its output (stdout and stderr together).

    Args:
        name: what the test calls it (in failure messages).
        argv: the command.
        env: its environment (default: this process's), with ``PYTHONUNBUFFERED=1``.
    """

    def __init__(self, name: str, argv: list[str], env: Mapping[str, str] | None = None) -> None:
        self.name = name
        self.lines: list[str] = []
        self._seen = threading.Condition()
        self.proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
            env={**(os.environ if env is None else env), "PYTHONUNBUFFERED": "1"},
            start_new_session=True,
        )
        assert self.proc.stdout is not None
        self._reader = threading.Thread(target=self._read, args=(self.proc.stdout,), daemon=True)
        self._reader.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            with self._seen:
                self.lines.append(line.rstrip("\n"))
                self._seen.notify_all()

    def wait_for_line(self, text: str, timeout: float) -> str:
        """The first line holding ``text``, waiting up to ``timeout`` s for it; raises
        (with the output) when it does not come or the process ends first."""
        deadline = time.monotonic() + timeout
        with self._seen:
            while True:
                found = next((line for line in self.lines if text in line), None)
                if found is not None:
                    return found
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    raise AssertionError(f"{self.name}: no {text!r}; output:\n{self.log()}")
                self._seen.wait(min(left, 0.2))

    def wait(self, timeout: float) -> int:
        """The exit code, waiting up to ``timeout`` s; raises (with the output) when the
        process is still running then."""
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(
                f"{self.name}: still running after {timeout:g} s; output:\n{self.log()}"
            ) from None
        self._reader.join(2.0)
        return code

    def text(self) -> str:
        """Everything it wrote so far."""
        with self._seen:
            return "\n".join(self.lines)

    def log(self, last: int = 60) -> str:
        """Its last ``last`` lines (for failure messages)."""
        with self._seen:
            return "\n".join(self.lines[-last:])

    def stop(self) -> int | None:
        """SIGTERM, then SIGKILL to its group after :data:`STOP_TIMEOUT`; the exit code
        (``None``: killed)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(STOP_TIMEOUT)
                self._reader.join(2.0)
                return None
        self._reader.join(2.0)
        return self.proc.returncode
