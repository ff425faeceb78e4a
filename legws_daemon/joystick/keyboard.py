"""``legws joystick keyboard``: steer from a terminal (no display needed).

Keys: ``w``/``s`` = +x/-x, ``a``/``d`` = +y/-y, ``r``/``f`` = +z/-z, space = zero,
``j``/``l`` turn about x, ``i``/``k`` about y, ``u``/``o`` about z (the rotation axes),
``g`` = the gripper (each press opens or closes it), ``v`` = the speed scale (1, 0.5, 0.25),
``c`` = cancel (in one message), ``q`` = quit. A terminal reports key presses but no key
releases, so a key sets the deflection on its axis and the deflection falls back to zero
unless the key comes again within the hold time (the terminal's key repeat keeps a held
key alive). That logic is the pure :class:`KeyboardState`; :class:`RawTerminal` puts the
terminal in cbreak mode (no echo, no line buffering, Ctrl-C still a signal) and always
restores it.
"""

from __future__ import annotations

import math
import os
import re
import select
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable
from types import TracebackType
from typing import TextIO

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons
from legws_daemon.joystick.daemon_status import fit
from legws_daemon.joystick.hand import HandState
from legws_daemon.joystick.publisher import Axes, Publisher, Sample, clip_norm

#: key -> (axis index, sign)
AXIS_KEYS: dict[str, tuple[int, float]] = {
    "w": (0, 1.0),
    "s": (0, -1.0),
    "a": (1, 1.0),
    "d": (1, -1.0),
    "r": (2, 1.0),
    "f": (2, -1.0),
}
#: key -> (rotation axis index, sign)
TURN_KEYS: dict[str, tuple[int, float]] = {
    "j": (0, 1.0),
    "l": (0, -1.0),
    "i": (1, 1.0),
    "k": (1, -1.0),
    "u": (2, 1.0),
    "o": (2, -1.0),
}
GRIPPER_KEY = "g"
SPEED_KEY = "v"
ZERO_KEY = " "
CANCEL_KEY = "c"
CONFIRM_KEYS = frozenset({"\r", "\n"})  # Enter
QUIT_KEYS = frozenset({"q", "\x03", "\x04"})  # q, and Ctrl-C / Ctrl-D should ISIG be off
HELP = (
    "keys: w/s +x/-x  a/d +y/-y  r/f +z/-z  j/l i/k u/o turn about x y z  g gripper  "
    "v speed  space zero (hold: let assistance run)  Enter confirm  c cancel  q quit"
)
#: Default hold time, s: a key's deflection lasts this long unless the key repeats.
HOLD = 0.3

# Escape sequences (arrow and function keys) must not be read as letters: "\x1b[A" has an "A".
_ESCAPES = re.compile(r"\x1b(\[[0-9;?]*[ -/]*[@-~]|O.|.)?", re.DOTALL)


class KeyboardState:
    """Deflection from key presses, with hold-time decay; pure (the caller passes the time).

    Args:
        step: the deflection one key sets on its axis, in (0, 1].
        hold: how long, s, a key's deflection (and the enable) lasts without a repeat,
            in (0, 10].
        hold_to_run: enable only while a steering key or space is held (see the module
            docstring); ``False``: every message enabled.
    """

    def __init__(self, step: float = 1.0, hold: float = HOLD, hold_to_run: bool = True) -> None:
        if not (math.isfinite(step) and 0.0 < step <= 1.0):
            raise InputError(f"must be in (0, 1], got {step!r}", field="step")
        if not (math.isfinite(hold) and 0.0 < hold <= 10.0):
            raise InputError(f"must be in (0, 10] s, got {hold!r}", field="hold")
        self.step = step
        self.hold = hold
        self.hold_to_run = hold_to_run
        self._value = [0.0, 0.0, 0.0]
        self._since = [-math.inf, -math.inf, -math.inf]
        self._turn = [0.0, 0.0, 0.0]
        self._turn_since = [-math.inf, -math.inf, -math.inf]
        #: the gripper asked for and the speed scale (``g`` and ``v``)
        self.hand = HandState()
        self._held = -math.inf  # the last steering key or space
        self._cancel = False
        self._confirm = False
        self.quit = False

    def press(self, key: str, now: float) -> bool:
        """Handle one key pressed at ``now`` (s); whether the key means anything.

        Letters are case-insensitive (caps lock). Quit keys set :attr:`quit`.
        """
        key = key.lower() if len(key) == 1 else key
        if key in AXIS_KEYS:
            axis, sign = AXIS_KEYS[key]
            self._value[axis] = sign * self.step
            self._since[axis] = now
            self._held = now
        elif key in TURN_KEYS:
            axis, sign = TURN_KEYS[key]
            self._turn[axis] = sign * self.step
            self._turn_since[axis] = now
            self._held = now
        elif key == ZERO_KEY:
            self._value = [0.0, 0.0, 0.0]
            self._since = [-math.inf, -math.inf, -math.inf]
            self._turn = [0.0, 0.0, 0.0]
            self._turn_since = [-math.inf, -math.inf, -math.inf]
            self._held = now
        elif key == GRIPPER_KEY:
            self.hand.toggle_gripper()
        elif key == SPEED_KEY:
            self.hand.step_speed()
        elif key == CANCEL_KEY:
            self._cancel = True
        elif key in CONFIRM_KEYS:
            self._confirm = True
        elif key in QUIT_KEYS:
            self.quit = True
        else:
            return False
        return True

    def axes(self, now: float) -> Axes:
        """The deflection at ``now``: held axes keep their value, the others are zero.

        A deflection on several axes is scaled down to norm 1.
        """
        return self._held_axes(self._value, self._since, now)

    def rotation(self, now: float) -> Axes:
        """The rotation axes at ``now``, as :meth:`axes`."""
        return self._held_axes(self._turn, self._turn_since, now)

    def _held_axes(self, values: list[float], since: list[float], now: float) -> Axes:
        held = [
            v if 0.0 <= now - t <= self.hold else 0.0 for v, t in zip(values, since, strict=True)
        ]
        return clip_norm(held)

    def enabled(self, now: float) -> bool:
        """Whether the enable button counts as held at ``now`` (always without hold-to-run)."""
        return not self.hold_to_run or 0.0 <= now - self._held <= self.hold

    def sample(self, now: float) -> Sample:
        """The deflection and buttons to publish at ``now``; a pending confirm or cancel is
        used up (and sent enabled: pressing it is the operator's act)."""
        pressed = self._cancel or self._confirm
        enable = (pressed or self.enabled(now)) if self.hold_to_run else None
        buttons = Buttons(cancel=self._cancel, confirm=self._confirm, enable=enable)
        self._cancel = self._confirm = False
        return self.hand.sample(self.axes(now), buttons, self.rotation(now))


def keys_of(text: str) -> list[str]:
    """The key presses in a chunk read from the terminal, escape sequences dropped."""
    return list(_ESCAPES.sub("", text))


def stdin_terminal_fd() -> int:
    """The file descriptor of standard input if it is a terminal; else :class:`InputError`."""
    try:
        fd = sys.stdin.fileno()
    except (AttributeError, OSError, ValueError):
        fd = -1
    if fd < 0 or not os.isatty(fd):
        raise InputError(
            "standard input is not a terminal; run it in a terminal, "
            "or use 'legws joystick replay' or 'legws joystick can'",
            field="stdin",
        )
    return fd


class RawTerminal:
    """A terminal in cbreak mode for the duration of a ``with`` block; restored on exit.

    Args:
        fd: the terminal's file descriptor (see :func:`stdin_terminal_fd`).
    """

    def __init__(self, fd: int) -> None:
        if not os.isatty(fd):
            raise InputError(f"file descriptor {fd} is not a terminal", field="stdin")
        self.fd = fd
        self._saved: list[int | list[bytes | int]] | None = None
        self.closed = False  # end of input seen

    def __enter__(self) -> RawTerminal:
        self._saved = termios.tcgetattr(self.fd)
        tty.setcbreak(self.fd, termios.TCSANOW)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._saved is not None:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None

    def read(self) -> str:
        """Everything typed since the last call, without blocking ("" if nothing)."""
        chunks: list[bytes] = []
        while not self.closed and select.select([self.fd], [], [], 0.0)[0]:
            try:
                data = os.read(self.fd, 1024)
            except OSError:  # the terminal went away (hang-up)
                data = b""
            if not data:
                self.closed = True
            chunks.append(data)
        return b"".join(chunks).decode("utf-8", errors="ignore")


def status_line(axes: Axes, buttons: Buttons) -> str:
    """The one-line deflection display (without the carriage return)."""
    x, y, z = axes
    line = f"x {x:+.2f}  y {y:+.2f}  z {z:+.2f}  " + ("run " if buttons.enabled else "hold")
    return line + ("  confirm" if buttons.confirm else "") + ("  cancel" if buttons.cancel else "")


def run_keyboard(
    publisher: Publisher,
    terminal: RawTerminal,
    state: KeyboardState,
    *,
    rate: float,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
    out: TextIO | None = None,
    daemon: Callable[[], str | None] | None = None,
) -> int:
    """Publish the keyboard's deflection at ``rate`` Hz until ``q``, a signal or ``duration``.

    Prints :data:`HELP` and then the current deflection on one overwritten line to ``out``
    (default standard error), followed by ``daemon()``: what the daemon does (its status
    line, :func:`~legws_daemon.joystick.daemon_status.status_text`; ``None``: nothing yet).
    Returns the number of messages published (without the final zero message
    :meth:`Publisher.run` adds).
    """
    stream = out if out is not None else sys.stderr
    stop = stop_event if stop_event is not None else threading.Event()
    shown = ""
    stream.write(HELP + "\n")
    stream.flush()

    def sample() -> Sample | None:
        nonlocal shown
        now = time.monotonic()
        for key in keys_of(terminal.read()):
            state.press(key, now)
        if state.quit or terminal.closed:
            stop.set()
            return None
        taken = state.sample(now)
        axes, buttons = taken[0], taken[1]
        line = status_line(axes, buttons)
        said = daemon() if daemon is not None else None
        if said is not None:
            line += " | " + said
        if line != shown:
            stream.write("\r" + fit(line, stream) + "\x1b[K")
            stream.flush()
            shown = line
        return taken

    try:
        return publisher.run(sample, rate, duration, stop)
    finally:
        stream.write("\n")
        stream.flush()
