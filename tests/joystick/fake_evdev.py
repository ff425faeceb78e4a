"""A fake of the one edge ``legws joystick evdev`` cannot have here: the kernel's input devices.

:class:`FakeNode` is a device (what sits behind ``/dev/input/eventN``): a name, ids,
capabilities, ranges, and its current state. :class:`FakeInputDevice` is one opened handle
with the part of ``evdev.InputDevice``'s API the reader uses, behaving as python-evdev's
does: ``fileno`` a real descriptor (a pipe, so ``select`` works), ``read()`` a generator
of ``evdev.InputEvent`` that raises ``BlockingIOError`` when nothing is queued and
``OSError(ENODEV)`` once the device is unplugged (the descriptor then polls readable, as
an evdev node does after its device is gone), ``read_one()`` ``None`` when nothing is
queued, ``capabilities(verbose=False, absinfo=True)``, ``absinfo(code)``,
``active_keys()``, ``close()``. Every event a node emits is queued on each of its open
handles, as the kernel does. :class:`FakeInputDir` holds the nodes by path, creates and
removes the ``eventN`` files a folder listing sees, and is the reader's opener.
"""

from __future__ import annotations

import errno
import os
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from evdev import AbsInfo, DeviceInfo, InputEvent, ecodes


def event(etype: int, code: int, value: int, at: float | None = None) -> InputEvent:
    """A real ``evdev.InputEvent`` stamped ``at`` (wall clock, default now)."""
    stamp = time.time() if at is None else at
    sec = int(stamp)
    return InputEvent(sec, int((stamp - sec) * 1e6), etype, code, value)


def syn(code: int = ecodes.SYN_REPORT) -> InputEvent:
    return event(ecodes.EV_SYN, code, 0)


class FakeNode:
    """A device: identity, capabilities, absinfo ranges, and the current state."""

    def __init__(
        self,
        name: str,
        vendor: int,
        product: int,
        *,
        keys: Iterable[int] = (),
        abs: dict[int, AbsInfo] | None = None,
        rel: Iterable[int] = (),
    ) -> None:
        self.name = name
        self.info = DeviceInfo(bustype=0x03, vendor=vendor, product=product, version=0x110)
        self.keys = sorted(keys)
        self.absinfo = dict(abs or {})
        self.rel = sorted(rel)
        self.down: set[int] = set()
        self.handles: list[FakeInputDevice] = []
        self.gone = False
        self._lock = threading.Lock()

    def capabilities(self, absinfo: bool = True) -> dict[int, list[Any]]:
        caps: dict[int, list[Any]] = {ecodes.EV_SYN: [ecodes.SYN_REPORT, ecodes.SYN_DROPPED]}
        if self.keys:
            caps[ecodes.EV_KEY] = list(self.keys)
        if self.rel:
            caps[ecodes.EV_REL] = list(self.rel)
        if self.absinfo:
            caps[ecodes.EV_ABS] = [
                (code, info) if absinfo else code for code, info in sorted(self.absinfo.items())
            ]
        return caps

    def emit(self, events: Iterable[InputEvent]) -> None:
        """Update the state and queue the events on every open handle."""
        batch = list(events)
        with self._lock:
            for e in batch:
                if e.type == ecodes.EV_KEY:
                    (self.down.add if e.value else self.down.discard)(e.code)
                elif e.type == ecodes.EV_ABS and e.code in self.absinfo:
                    self.absinfo[e.code] = self.absinfo[e.code]._replace(value=e.value)
            for handle in self.handles:
                handle.queue(batch)

    def frame(self, *changes: tuple[int, int, int]) -> None:
        """One frame: ``(type, code, value)`` events then ``SYN_REPORT``."""
        self.emit([*(event(t, c, v) for t, c, v in changes), syn()])

    def unplug(self) -> None:
        """Pull the cable: every open handle fails from now on."""
        with self._lock:
            self.gone = True
            for handle in self.handles:
                handle.kill()


class FakeInputDevice:
    """One open handle on a :class:`FakeNode` (the API of ``evdev.InputDevice``)."""

    def __init__(self, node: FakeNode, path: str) -> None:
        self.node = node
        self.path = path
        self.name = node.name
        self.info = node.info
        self._read_fd, self._write_fd = os.pipe()
        os.set_blocking(self._read_fd, False)
        self.fd = self._read_fd
        self._queue: list[InputEvent] = []
        self._dead = False
        self._lock = threading.Lock()

    # -- driven by the node --
    def queue(self, events: list[InputEvent]) -> None:
        with self._lock:
            self._queue.extend(events)
            if self._write_fd >= 0:
                os.write(self._write_fd, b"e")

    def kill(self) -> None:
        with self._lock:
            self._dead = True
            if self._write_fd >= 0:
                os.write(self._write_fd, b"x")  # readable, as a node whose device left

    # -- evdev.InputDevice API --
    def fileno(self) -> int:
        return self.fd

    def _check(self) -> None:
        if self.fd < 0:
            raise OSError(errno.EBADF, "Bad file descriptor")
        if self._dead:
            raise OSError(errno.ENODEV, "No such device")

    def read(self) -> Iterator[InputEvent]:
        with self._lock:
            self._check()
            if not self._queue:
                raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")
            batch, self._queue = self._queue, []
            try:
                while os.read(self._read_fd, 4096):
                    pass
            except BlockingIOError:
                pass
        yield from batch

    def read_one(self) -> InputEvent | None:
        with self._lock:
            self._check()
            return self._queue.pop(0) if self._queue else None

    def capabilities(self, verbose: bool = False, absinfo: bool = True) -> dict[int, list[Any]]:
        assert not verbose, "the reader asks for codes, not names"
        self._check()
        return self.node.capabilities(absinfo)

    def absinfo(self, axis_num: int) -> AbsInfo:
        self._check()
        return self.node.absinfo[axis_num]

    def active_keys(self, verbose: bool = False) -> list[int]:
        self._check()
        return sorted(self.node.down)

    def close(self) -> None:
        with self._lock:
            for fd in (self._read_fd, self._write_fd):
                if fd >= 0:
                    os.close(fd)
            self._read_fd = self._write_fd = self.fd = -1
        with self.node._lock:
            if self in self.node.handles:
                self.node.handles.remove(self)


class FakeInputDir:
    """A folder of fake event nodes: ``plug``/``unplug`` create and remove ``eventN``
    files (what a listing sees), and :meth:`open` is the reader's opener."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.nodes: dict[str, FakeNode] = {}
        self.forbidden: set[str] = set()
        self.opened: list[FakeInputDevice] = []

    def path(self, number: int) -> str:
        return str(self.folder / f"event{number}")

    def plug(self, number: int, node: FakeNode) -> str:
        path = self.path(number)
        Path(path).touch()
        self.nodes[path] = node
        return path

    def unplug(self, path: str) -> FakeNode:
        node = self.nodes.pop(path)
        Path(path).unlink()
        node.unplug()
        return node

    def forbid(self, number: int) -> str:
        """A node this user may not open (no 'input' group)."""
        path = self.path(number)
        Path(path).touch()
        self.forbidden.add(path)
        return path

    def open(self, path: str) -> FakeInputDevice:
        if path in self.forbidden:
            raise PermissionError(errno.EACCES, "Permission denied", path)
        node = self.nodes.get(path)
        if node is None or node.gone:
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", path)
        handle = FakeInputDevice(node, path)
        node.handles.append(handle)
        self.opened.append(handle)
        return handle

    def close_all(self) -> None:
        for handle in self.opened:
            handle.close()


# --- the devices of the tests ----------------------------------------------------------------

STICK = AbsInfo(value=0, min=-32768, max=32767, fuzz=16, flat=128, resolution=0)
TRIGGER = AbsInfo(value=0, min=0, max=1023, fuzz=0, flat=0, resolution=0)
HAT = AbsInfo(value=0, min=-1, max=1, fuzz=0, flat=0, resolution=0)
PUCK = AbsInfo(value=0, min=-350, max=350, fuzz=0, flat=0, resolution=0)
PAD_KEYS = (
    ecodes.BTN_SOUTH,
    ecodes.BTN_EAST,
    ecodes.BTN_NORTH,
    ecodes.BTN_WEST,
    ecodes.BTN_TL,
    ecodes.BTN_TR,
    ecodes.BTN_SELECT,
    ecodes.BTN_START,
    ecodes.BTN_MODE,
    ecodes.BTN_THUMBL,
    ecodes.BTN_THUMBR,
)


def xbox_pad(name: str = "Microsoft X-Box 360 pad") -> FakeNode:
    """An Xbox 360 pad as the xpad driver presents it."""
    axes = {ecodes.ABS_X: STICK, ecodes.ABS_Y: STICK, ecodes.ABS_RX: STICK, ecodes.ABS_RY: STICK}
    axes |= {ecodes.ABS_Z: TRIGGER, ecodes.ABS_RZ: TRIGGER}
    axes |= {ecodes.ABS_HAT0X: HAT, ecodes.ABS_HAT0Y: HAT}
    return FakeNode(name, 0x045E, 0x028E, keys=PAD_KEYS, abs=axes)


PS_STICK = AbsInfo(value=128, min=0, max=255, fuzz=0, flat=0, resolution=0)


def dualsense(
    name: str = "Sony Interactive Entertainment DualSense Wireless Controller",
) -> FakeNode:
    """A DualSense as hid-playstation presents its gamepad node (sticks 0..255)."""
    axes = {c: PS_STICK for c in (ecodes.ABS_X, ecodes.ABS_Y, ecodes.ABS_RX, ecodes.ABS_RY)}
    axes |= {ecodes.ABS_Z: PS_STICK, ecodes.ABS_RZ: PS_STICK}  # L2, R2
    axes |= {ecodes.ABS_HAT0X: HAT, ecodes.ABS_HAT0Y: HAT}
    keys = (*PAD_KEYS, ecodes.BTN_TL2, ecodes.BTN_TR2)
    return FakeNode(name, 0x054C, 0x0CE6, keys=keys, abs=axes)


def dualsense_motion() -> FakeNode:
    """The motion-sensor node the same pad creates: accelerometer and gyro, no buttons."""
    codes = (ecodes.ABS_X, ecodes.ABS_Y, ecodes.ABS_Z, ecodes.ABS_RX, ecodes.ABS_RY, ecodes.ABS_RZ)
    sensor = AbsInfo(value=0, min=-32768, max=32767, fuzz=0, flat=0, resolution=8192)
    name = "Sony Interactive Entertainment DualSense Wireless Controller Motion Sensors"
    return FakeNode(name, 0x054C, 0x0CE6, abs=dict.fromkeys(codes, sensor))


def spacemouse_rel() -> FakeNode:
    """A SpaceNavigator on a kernel that reports EV_REL."""
    rel = (ecodes.REL_X, ecodes.REL_Y, ecodes.REL_Z, ecodes.REL_RX, ecodes.REL_RY, ecodes.REL_RZ)
    keys = (ecodes.BTN_0, ecodes.BTN_1)
    return FakeNode("3Dconnexion SpaceNavigator", 0x046D, 0xC626, keys=keys, rel=rel)


def spacemouse_abs() -> FakeNode:
    """A SpaceMouse Compact on a kernel that reports EV_ABS."""
    codes = (ecodes.ABS_X, ecodes.ABS_Y, ecodes.ABS_Z, ecodes.ABS_RX, ecodes.ABS_RY, ecodes.ABS_RZ)
    keys = (ecodes.BTN_0, ecodes.BTN_1)
    return FakeNode(
        "3Dconnexion SpaceMouse Compact", 0x256F, 0xC635, keys=keys, abs=dict.fromkeys(codes, PUCK)
    )


def keyboard() -> FakeNode:
    keys = range(ecodes.KEY_ESC, ecodes.KEY_KPDOT + 1)
    return FakeNode("AT Translated Set 2 keyboard", 0x0001, 0x0001, keys=keys)
