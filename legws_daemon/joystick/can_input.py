"""``legws joystick can``: a joystick on a CAN bus (python-can; socketcan, or virtual in tests).

The profile's ``[can]`` table gives the frame layout: one frame of ``arbitration_id`` with
three signed 16-bit little-endian axes at ``axis_offsets`` and a button byte at
``button_offset`` (bit 0 cancel, bit 1 confirm, bit 2 enable — the hold-to-run button — when
``enable_bit`` is set; else every frame counts as enabled; bit 3 the gripper button, bit 4 the
speed button: each press toggles the gripper asked for or steps the speed scale,
:mod:`legws_daemon.joystick.hand`), and with ``rotation_offsets`` three more for the rotation
axes. Counts are divided by ``scale``, negated
where ``invert`` says so, clipped to [-1, 1] and the deflection to norm 1
(:func:`decode_frame`; :func:`encode_frame` is its inverse).

:class:`CanReader` keeps the newest valid frame. Each tick the newest one is published; once
no valid frame has arrived for longer than the profile's deadman timeout, nothing is
published, so the daemon's own deadman stops the robot — stale input is never repeated.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Literal

import can

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons
from legws_daemon.formats.profile import CanSpec
from legws_daemon.joystick.hand import HandState
from legws_daemon.joystick.publisher import Publisher, Sample, clip_norm

Interface = Literal["socketcan", "virtual"]
INTERFACES: tuple[Interface, ...] = ("socketcan", "virtual")
CANCEL_BIT = 0x01
CONFIRM_BIT = 0x02
ENABLE_BIT = 0x04
GRIPPER_BIT = 0x08
SPEED_BIT = 0x10
_INT16 = struct.Struct("<h")


def frame_length(spec: CanSpec) -> int:
    """Bytes a frame needs for the layout; :class:`InputError` if the layout is impossible."""
    spans = [(off, off + 2, f"can.axis_offsets[{i}]") for i, off in enumerate(spec.axis_offsets)]
    for i, off in enumerate(spec.rotation_offsets or ()):
        spans.append((off, off + 2, f"can.rotation_offsets[{i}]"))
    spans.append((spec.button_offset, spec.button_offset + 1, "can.button_offset"))
    for i, (lo, hi, name) in enumerate(spans):
        if lo < 0 or hi > 64:
            raise InputError(f"offset {lo} does not fit a frame of at most 64 bytes", field=name)
        for lo2, hi2, name2 in spans[:i]:
            if lo < hi2 and lo2 < hi:
                raise InputError(f"overlaps {name2}", field=name)
    return max(hi for _, hi, _ in spans)


def _source(arbitration_id: int) -> str:
    return f"CAN frame 0x{arbitration_id:X}"


def decode_frame(spec: CanSpec, arbitration_id: int, data: bytes) -> Sample:
    """The deflection and buttons of one frame.

    Raises :class:`InputError` for a frame of another id or one too short for the layout.
    """
    if arbitration_id != spec.arbitration_id:
        raise InputError(
            f"expected id 0x{spec.arbitration_id:X}", source=_source(arbitration_id), field="id"
        )
    need = frame_length(spec)
    if len(data) < need:
        raise InputError(
            f"{len(data)} bytes, the layout needs {need}",
            source=_source(arbitration_id),
            field="data",
        )
    bits = data[spec.button_offset]
    buttons = Buttons(
        cancel=bool(bits & CANCEL_BIT),
        confirm=bool(bits & CONFIRM_BIT),
        enable=bool(bits & ENABLE_BIT) if spec.enable_bit else None,
    )
    axes = _values(spec, data, spec.axis_offsets, spec.invert)
    if spec.rotation_offsets is None:
        return axes, buttons
    return axes, buttons, _values(spec, data, spec.rotation_offsets, spec.rotation_invert)


def _values(
    spec: CanSpec, data: bytes, offsets: Sequence[int], invert: Sequence[bool]
) -> tuple[float, float, float]:
    raw = [
        _INT16.unpack_from(data, off)[0] / spec.scale * (-1.0 if inv else 1.0)
        for off, inv in zip(offsets, invert, strict=True)
    ]
    return clip_norm([min(1.0, max(-1.0, v)) for v in raw])


def hand_bits(spec: CanSpec, data: bytes) -> tuple[bool, bool]:
    """Whether the frame holds the gripper button and the speed button down."""
    bits = data[spec.button_offset]
    return bool(bits & GRIPPER_BIT), bool(bits & SPEED_BIT)


def encode_frame(
    spec: CanSpec,
    axes: Sequence[float],
    buttons: Buttons | None = None,
    rotation: Sequence[float] | None = None,
    *,
    gripper_down: bool = False,
    speed_down: bool = False,
) -> bytes:
    """The frame data :func:`decode_frame` reads back as ``axes`` (to 1/scale), ``buttons``
    and ``rotation`` (with ``rotation_offsets``), and :func:`hand_bits` as the gripper and
    speed buttons held.

    Counts are rounded and saturate at the 16-bit range; unused bytes are zero.
    """
    data = bytearray(frame_length(spec))
    groups = [(clip_norm(axes), spec.axis_offsets, spec.invert)]
    if spec.rotation_offsets is not None:
        turn = clip_norm(rotation if rotation is not None else (0.0, 0.0, 0.0))
        groups.append((turn, spec.rotation_offsets, spec.rotation_invert))
    for values, offsets, invert in groups:
        for value, off, inv in zip(values, offsets, invert, strict=True):
            count = round((-value if inv else value) * spec.scale)
            _INT16.pack_into(data, off, max(-32768, min(32767, count)))
    b = buttons if buttons is not None else Buttons()
    bits = (CANCEL_BIT if b.cancel else 0) | (CONFIRM_BIT if b.confirm else 0)
    bits |= (GRIPPER_BIT if gripper_down else 0) | (SPEED_BIT if speed_down else 0)
    data[spec.button_offset] = bits | (ENABLE_BIT if spec.enable_bit and b.enabled else 0)
    return bytes(data)


def open_bus(
    interface: Interface, channel: str, bitrate: int | None = None, spec: CanSpec | None = None
) -> can.BusABC:
    """Open a python-can bus; any failure is a one-line :class:`InputError`.

    With ``spec`` the bus filters on the joystick's arbitration id.
    """
    if interface not in INTERFACES:
        raise InputError(f"unknown interface {interface!r}; known: {', '.join(INTERFACES)}")
    kwargs: dict[str, Any] = {}
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    if spec is not None:
        kwargs["can_filters"] = [{"can_id": spec.arbitration_id, "can_mask": 0x1FFFFFFF}]
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except Exception as err:  # python-can raises CanError, OSError, ValueError, ImportError
        detail = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise InputError(
            f"cannot open {interface} channel {channel!r}: {detail}", field="CAN bus"
        ) from None


class CanReader:
    """The newest valid joystick frame on a bus, and whether it is fresh.

    Args:
        bus: an open python-can bus (the caller closes it).
        spec: the frame layout.
        timeout: a frame older than this, s, is no input (the profile's deadman timeout).
        clock: monotonic seconds (tests may pass their own).
        wall: wall-clock seconds, the clock of the bus's frame timestamps.
    """

    def __init__(
        self,
        bus: can.BusABC,
        spec: CanSpec,
        timeout: float,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        frame_length(spec)  # reject an impossible layout before any frame arrives
        if not timeout > 0:
            raise InputError(f"must be positive, got {timeout!r}", field="timeout")
        self.bus = bus
        self.spec = spec
        self.timeout = timeout
        self.clock = clock
        self.wall = wall
        self.frames = 0  # valid frames decoded
        self.rejected = 0  # frames of our id that did not decode
        self.last_error: str | None = None
        self._latest: Sample | None = None
        self._received = -float("inf")
        #: the gripper asked for and the speed scale (the presses of bits 3 and 4)
        self.hand = HandState()

    def poll(self) -> None:
        """Read every frame waiting on the bus (without blocking); keep the newest valid one.

        A frame's age is taken from its bus timestamp (wall clock: socketcan and the
        virtual bus stamp frames on arrival) when it has a plausible one, else it counts
        as received when polled.
        """
        while True:
            msg = self.bus.recv(timeout=0.0)
            if msg is None:
                return
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            if msg.arbitration_id != self.spec.arbitration_id:
                continue  # other devices share the bus
            try:
                data = bytes(msg.data)
                self._latest = decode_frame(self.spec, msg.arbitration_id, data)
                self.hand.update(*hand_bits(self.spec, data))
            except InputError as err:
                self.rejected += 1
                self.last_error = str(err)
                continue
            self.frames += 1
            age = self.wall() - msg.timestamp if msg.timestamp > 0 else 0.0
            self._received = self.clock() - (age if 0.0 <= age <= 60.0 else 0.0)

    def sample(self) -> Sample | None:
        """Poll, then the newest valid sample if it is fresh, else ``None`` (publish nothing):
        scaled by the speed scale, with the gripper asked for."""
        self.poll()
        if self._latest is None or self.clock() - self._received > self.timeout:
            return None
        turn = self._latest[2] if len(self._latest) == 3 else None
        return self.hand.sample(self._latest[0], self._latest[1], turn)


def run_can(
    publisher: Publisher,
    reader: CanReader,
    *,
    rate: float,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
) -> int:
    """Publish the newest fresh CAN sample at ``rate`` Hz until stopped; messages published."""
    return publisher.run(reader.sample, rate, duration, stop_event)
