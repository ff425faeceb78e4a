"""``legws joystick evdev``: gamepads, SpaceMice and HID joysticks through python-evdev.

The device side of :mod:`legws_daemon.joystick.evdev_state`: finding devices under
``/dev/input`` (or ``$LEGWS_INPUT_DIR``), matching them to a mapping
(:mod:`legws_daemon.formats.input_mapping`), and :class:`EvdevReader`, which reads one device
on a background thread and answers the publisher's ticks from the state without ever
waiting for the device.

Unplugging: a read that fails (``ENODEV`` when the device is pulled out, or any other
``OSError``) closes the device and from then on every sample is zero with ``enable``
released, so the daemon stops the robot at once. The reader then looks for the device every
``retry`` seconds: the same path when ``--device`` named one, else any device the mapping
recognises (the previous path first), and carries on with it without a restart. Both
events are logged on standard error. An unexpected error on the reader thread is handled
the same way (no input, then a fresh open): a stick never freezes at its last deflection.

After the device is opened (at start or on reconnecting), a button that is already held
counts only once it has been released and pressed again: an enable button stuck down, or
held while the cable is plugged back in, does not start a motion.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import select
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Literal, Protocol

import evdev
from evdev import InputEvent

from legws_daemon.errors import InputError
from legws_daemon.formats.input_mapping import (
    EV_ABS,
    EV_KEY,
    EV_REL,
    InputMapping,
    load_mapping_named,
    mapping_names,
    shipped_mappings,
)
from legws_daemon.formats.printable import safe_text
from legws_daemon.joystick.evdev_state import (
    NO_INPUT,
    AbsRange,
    DeviceIdentity,
    DeviceState,
    missing_capabilities,
    recognises,
)
from legws_daemon.joystick.publisher import Publisher, Sample

#: Where input devices are looked for unless ``$LEGWS_INPUT_DIR`` says otherwise.
INPUT_DIR = Path("/dev/input")
INPUT_DIR_ENV = "LEGWS_INPUT_DIR"
#: Seconds between two looks for a lost device.
RETRY = 0.5
#: Longest wait of the reader thread for events before it checks whether it should stop, s.
POLL = 0.05
PERMISSION_HINT = (
    "join the 'input' group (sudo usermod -aG input $USER, then log in again) "
    "or add a udev rule for the device (docs/daemon.md)"
)


class InputDeviceLike(Protocol):
    """The part of ``evdev.InputDevice`` the reader uses (tests fake exactly this)."""

    name: str
    info: evdev.DeviceInfo

    def fileno(self) -> int: ...

    def read(self) -> Iterator[InputEvent]: ...

    def capabilities(
        self, verbose: Literal[False] = ..., absinfo: bool = ...
    ) -> dict[int, list[int]]: ...

    def absinfo(self, axis_num: int) -> evdev.AbsInfo: ...

    def active_keys(self, verbose: bool = ...) -> list[int]: ...

    def close(self) -> None: ...


#: Opens a device node (raises ``OSError`` when it cannot).
Opener = Callable[[str], InputDeviceLike]


def open_device(path: str) -> InputDeviceLike:
    """``evdev.InputDevice(path)``: non-blocking, read-write if allowed, else read-only
    (reading is all the reader does)."""
    return evdev.InputDevice(path)


def input_dir() -> Path:
    """``$LEGWS_INPUT_DIR`` or ``/dev/input``."""
    env = os.environ.get(INPUT_DIR_ENV)
    return Path(env) if env else INPUT_DIR


def event_paths(folder: Path | None = None) -> list[str]:
    """The ``event*`` nodes of the folder, in number order (``event2`` before ``event10``)."""
    where = folder if folder is not None else input_dir()
    try:
        names = [n for n in os.listdir(where) if re.fullmatch(r"event\d+", n)]
    except OSError:
        return []
    return [str(where / n) for n in sorted(names, key=lambda n: int(n[5:]))]


def identify(device: InputDeviceLike) -> DeviceIdentity:
    """The name, ids and capabilities of an open device."""
    caps = device.capabilities(verbose=False, absinfo=False)
    return DeviceIdentity(
        name=device.name,
        vendor=device.info.vendor,
        product=device.info.product,
        keys=frozenset(caps.get(EV_KEY, ())),
        abs=frozenset(caps.get(EV_ABS, ())),
        rel=frozenset(caps.get(EV_REL, ())),
    )


def _why(err: OSError) -> str:
    if isinstance(err, PermissionError):
        return f"permission denied: {PERMISSION_HINT}"
    if err.errno in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
        return "no such device"
    return err.strerror or str(err) or type(err).__name__


@dataclass(frozen=True)
class FoundDevice:
    """One ``/dev/input/event*`` node: what it is and which shipped mappings recognise it,
    or why it could not be opened."""

    path: str
    identity: DeviceIdentity | None = None
    mappings: tuple[str, ...] = ()
    error: str | None = None

    def describe(self) -> str:
        """One line for ``--list``."""
        if self.identity is None:
            return f"{self.path}: cannot open: {self.error}"
        d = self.identity
        mapping = ", ".join(self.mappings) if self.mappings else "none"
        return (
            f'{self.path}: "{d.name}" {d.vendor:04x}:{d.product:04x}, {len(d.abs)} absolute '
            f"axes, {len(d.rel)} relative axes, {len(d.keys)} buttons/keys; mapping: {mapping}"
        )


def list_devices(
    folder: Path | None = None,
    opener: Opener | None = None,
    mappings: list[tuple[str, InputMapping]] | None = None,
) -> list[FoundDevice]:
    """Every event node with its identity and matching mappings (default: the shipped
    ones); a node that cannot be opened is listed with the reason. ``opener`` defaults to
    :func:`open_device`."""
    known = shipped_mappings() if mappings is None else mappings
    open_node = opener or open_device
    found = []
    for path in event_paths(folder):
        try:
            device = open_node(path)
        except OSError as err:
            found.append(FoundDevice(path, error=_why(err)))
            continue
        try:
            ident = identify(device)
        except OSError as err:
            found.append(FoundDevice(path, error=_why(err)))
            continue
        finally:
            with contextlib.suppress(OSError):
                device.close()
        names = tuple(name for name, m in known if recognises(m, ident))
        found.append(FoundDevice(path, ident, names))
    return found


def none_found_reason(folder: Path | None = None) -> str:
    """The line ``--list`` prints when it finds nothing, saying why there may be nothing."""
    where = folder if folder is not None else input_dir()
    if not where.is_dir():
        return (
            f"no input devices: {where} does not exist (no input subsystem here, e.g. a "
            "container without /dev/input mounted)"
        )
    return (
        f"no input devices found in {where}: none plugged in, or this user may not read "
        f"them ({PERMISSION_HINT})"
    )


def choose_mapping(
    mapping: str | None,
    device: str | None,
    folder: Path | None = None,
    opener: Opener | None = None,
) -> tuple[str, InputMapping]:
    """The mapping to run and its name: ``mapping`` (a name or a path) if given; else the
    first shipped mapping (in name order) that recognises ``device``, or, without a device,
    some device present. Raises a one-line :class:`InputError` when there is none."""
    if mapping is not None:
        return load_mapping_named(mapping)
    known = shipped_mappings()
    names = ", ".join(mapping_names()) or "(none)"
    if device is not None:
        try:
            opened = (opener or open_device)(device)
        except OSError as err:
            raise InputError(f"cannot open: {_why(err)}", source=device) from None
        try:
            ident = identify(opened)
        except OSError as err:
            raise InputError(f"cannot read the device: {_why(err)}", source=device) from None
        finally:
            with contextlib.suppress(OSError):
                opened.close()
        for name, candidate in known:
            if recognises(candidate, ident):
                return name, candidate
        raise InputError(
            f'no shipped mapping ({names}) recognises "{ident.name}" '
            f"{ident.vendor:04x}:{ident.product:04x}; pass --mapping NAME|FILE",
            source=device,
        )
    found = list_devices(folder, opener, known)
    for name, candidate in known:
        if any(name in f.mappings for f in found):
            return name, candidate
    readable = [f for f in found if f.identity is not None]
    if not found:
        why = none_found_reason(folder)
    else:
        why = (
            f"{len(found)} event devices, {len(readable)} readable, none recognised "
            f"by a shipped mapping ({names}); see legws joystick evdev --list"
        )
        if len(readable) < len(found):
            why += f"; some cannot be opened: {PERMISSION_HINT}"
    raise InputError(why, field="device")


def _log_stderr(message: str) -> None:
    # a device's name is the device's to choose: made terminal-safe
    print(safe_text(message), file=sys.stderr, flush=True)


class EvdevReader:
    """One input device read on a background thread; the newest state, sampled per tick.

    Args:
        mapping: the validated mapping.
        device: the event node to read (``--device``); ``None``: the first device the
            mapping recognises. When it is lost, the same path is waited for (a
            ``/dev/input/by-id/`` path survives replugging).
        folder: where to look for devices (default :func:`input_dir`).
        opener: opens a node (default :func:`open_device`; tests pass a fake).
        clock: monotonic seconds: event times and the retry schedule.
        retry: seconds between looks for a lost device.
        log: where unplug and reconnect lines go (standard error).
        label: the mapping's name in messages (default: the name in its ``[device]``).

    Use it as a context manager (opens the device, starts the thread; closes both), or
    :meth:`open` and :meth:`pump` by hand (tests).
    """

    def __init__(
        self,
        mapping: InputMapping,
        *,
        device: str | None = None,
        folder: Path | None = None,
        opener: Opener | None = None,
        clock: Callable[[], float] = time.monotonic,
        retry: float = RETRY,
        log: Callable[[str], None] = _log_stderr,
        label: str | None = None,
    ) -> None:
        if not retry > 0:
            raise InputError(f"must be positive, got {retry!r}", field="retry")
        self.mapping = mapping
        self.explicit = device
        self.folder = folder
        self.opener: Opener = opener or open_device
        self.clock = clock
        self.retry = retry
        self.log = log
        self.label = label if label is not None else mapping.device.name
        self.state = DeviceState(mapping)
        self.path: str | None = None
        self.identity: DeviceIdentity | None = None
        self.unplugged = 0  # devices lost
        self.reconnected = 0  # devices found again
        self._device: InputDeviceLike | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._next_try = 0.0

    # -- lifetime ------------------------------------------------------------------------

    def __enter__(self) -> EvdevReader:
        if self._device is None:
            self.open()
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def open(self) -> None:
        """Open the device (``--device``, or the first one the mapping recognises).

        Raises a one-line :class:`InputError` if there is none or it cannot be opened.
        """
        if self.explicit is not None:
            try:
                device = self.opener(self.explicit)
            except OSError as err:
                raise InputError(f"cannot open: {_why(err)}", source=self.explicit) from None
            ident = self._identify_or_close(device, self.explicit)
            missing = missing_capabilities(self.mapping, ident)
            if missing:
                with contextlib.suppress(OSError):
                    device.close()
                raise InputError(
                    f'"{ident.name}" lacks {", ".join(missing)} of mapping '
                    f"{self.label!r}; see legws joystick evdev --list",
                    source=self.explicit,
                )
            self._attach(self.explicit, device, ident)
            return
        got = self._find(prefer=None)
        if got is None:
            raise InputError(
                f"no input device matches mapping {self.label!r} in "
                f"{self.folder or input_dir()}; see legws joystick evdev --list",
                field="device",
            )
        self._attach(*got)

    def start(self) -> None:
        """Read the device on a background thread until :meth:`close`."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="legws-evdev", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread and close the device (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        with self._lock:
            device, self._device = self._device, None
        if device is not None:
            with contextlib.suppress(OSError):
                device.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.pump(POLL)
            except Exception as err:  # never leave a frozen state behind: no input instead
                if self._device is not None:
                    self._lose(f"reader error: {type(err).__name__}: {err}")
                else:
                    self._stop.wait(self.retry)

    # -- the device ----------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._device is not None

    @property
    def name(self) -> str:
        return self.identity.name if self.identity is not None else "?"

    def _identify_or_close(self, device: InputDeviceLike, path: str) -> DeviceIdentity:
        try:
            return identify(device)
        except OSError as err:
            with contextlib.suppress(OSError):
                device.close()
            raise InputError(f"cannot read the device: {_why(err)}", source=path) from None

    def _find(self, prefer: str | None) -> tuple[str, InputDeviceLike, DeviceIdentity] | None:
        """The first node the mapping recognises (``prefer`` tried first), opened."""
        paths = event_paths(self.folder)
        if prefer in paths:
            paths.remove(prefer)
            paths.insert(0, prefer)
        for path in paths:
            try:
                device = self.opener(path)
            except OSError:
                continue
            try:
                ident = identify(device)
            except OSError:
                ident = None
            if ident is not None and recognises(self.mapping, ident):
                return path, device, ident
            with contextlib.suppress(OSError):
                device.close()
        return None

    def _reopen(self) -> tuple[str, InputDeviceLike, DeviceIdentity] | None:
        if self.explicit is None:
            return self._find(prefer=self.path)
        try:
            device = self.opener(self.explicit)
        except OSError:
            return None
        try:
            ident = identify(device)
        except OSError:
            ident = None
        if ident is None or missing_capabilities(self.mapping, ident):
            with contextlib.suppress(OSError):
                device.close()
            return None
        return self.explicit, device, ident

    def _attach(self, path: str, device: InputDeviceLike, ident: DeviceIdentity) -> None:
        """Take an open device: its ranges and current state (held buttons not armed)."""
        try:
            codes = self.state.abs_codes & ident.abs
            infos = {code: device.absinfo(code) for code in codes}
            keys = list(device.active_keys())
        except OSError as err:
            with contextlib.suppress(OSError):
                device.close()
            raise InputError(f"cannot read the device: {_why(err)}", source=path) from None
        ranges: dict[int, AbsRange] = {c: (i.min, i.max) for c, i in infos.items()}
        with self._lock:
            self.state.set_ranges(ranges)
            self.state.sync({c: i.value for c, i in infos.items()}, keys, fresh=True)
            self._device = device
            self.path = path
            self.identity = ident

    def _sync(self, device: InputDeviceLike) -> None:
        """After SYN_DROPPED: the device's current state (enable buttons included)."""
        codes = self.state.abs_codes & (self.identity.abs if self.identity else frozenset())
        values = {code: device.absinfo(code).value for code in codes}
        self.state.sync(values, device.active_keys())

    def _lose(self, why: str) -> None:
        with self._lock:
            device, self._device = self._device, None
            self.state.reset()
            self.unplugged += 1
        if device is not None:
            with contextlib.suppress(OSError):
                device.close()
        self._next_try = self.clock() + self.retry
        self.log(
            f"legws: input device lost ({why}): {self.name} at {self.path}; sending "
            "zero with enable released until it is back"
        )

    def pump(self, timeout: float = 0.0) -> None:
        """Wait up to ``timeout`` s for events and apply them; when the device is lost,
        look for it again if the retry time has come (else wait the ``timeout``)."""
        device = self._device
        if device is None:
            now = self.clock()
            if now < self._next_try:
                self._stop.wait(min(timeout, self._next_try - now))
                return
            self._next_try = now + self.retry
            got = self._reopen()
            if got is None:
                return
            try:
                self._attach(*got)
            except InputError:
                return
            self.reconnected += 1
            self.log(f"legws: input device back: {self.name} at {self.path}")
            return
        try:
            ready, _, _ = select.select([device], [], [], timeout)
            if not ready:
                return
            events = list(device.read())
        except BlockingIOError:
            return
        except OSError as err:
            self._lose(_why(err))
            return
        except ValueError as err:  # select on a closed descriptor
            self._lose(str(err))
            return
        try:
            with self._lock:
                now = self.clock()
                for event in events:
                    self.state.feed(event, now)
                    if self.state.needs_sync:
                        self._sync(device)
        except OSError as err:
            self._lose(_why(err))

    # -- the publisher's side ------------------------------------------------------------

    def sample(self) -> Sample:
        """What to publish now: the device's sample, or zero with enable released while
        there is no device. Never waits for the device."""
        with self._lock:
            if self._device is None:
                return NO_INPUT
            return self.state.sample(self.clock())


def run_evdev(
    publisher: Publisher,
    reader: EvdevReader,
    *,
    rate: float,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
) -> int:
    """Publish the reader's sample at ``rate`` Hz until stopped; messages published."""
    return publisher.run(reader.sample, rate, duration, stop_event)
