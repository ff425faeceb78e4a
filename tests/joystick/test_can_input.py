"""CAN joystick: frame decoding/encoding, the reader's freshness, and a virtual-bus run."""

from __future__ import annotations

import math
import struct
import threading
import time
import uuid
from collections.abc import Iterator

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons
from legws_daemon.formats.profile import CanSpec
from legws_daemon.joystick.can_input import (
    CanReader,
    decode_frame,
    encode_frame,
    frame_length,
    open_bus,
    run_can,
)
from legws_daemon.joystick.publisher import Publisher, clip_norm
from legws_daemon.transport.session import config_from_spec
from tests.joystick.helpers import KEY, daemon_side, dial_spec
from tests.net import free_port

SPEC = CanSpec()


@st.composite
def layouts(draw: st.DrawFn) -> CanSpec:
    """Random valid layouts: non-overlapping fields in a classic or an FD frame."""
    slots = draw(st.permutations(range(4)))  # four 2-byte slots, the button in one of them
    base = draw(st.integers(0, 8))
    axis_offsets = tuple(base + 2 * s for s in slots[:3])
    return CanSpec(
        arbitration_id=draw(st.integers(0, 0x1FFFFFFF)),
        axis_offsets=(axis_offsets[0], axis_offsets[1], axis_offsets[2]),
        button_offset=base + 2 * slots[3] + draw(st.integers(0, 1)),
        scale=draw(st.floats(100.0, 32767.0)),
        invert=draw(st.tuples(st.booleans(), st.booleans(), st.booleans())),
        enable_bit=draw(st.booleans()),
    )


unit = st.floats(-1.0, 1.0)
deflections = st.tuples(unit, unit, unit).map(clip_norm)
button_sets = st.builds(
    Buttons,
    cancel=st.booleans(),
    confirm=st.booleans(),
    enable=st.sampled_from([None, True, False]),
)


@given(layouts(), deflections, button_sets)
def test_decode_inverts_encode(
    spec: CanSpec, axes: tuple[float, float, float], buttons: Buttons
) -> None:
    data = encode_frame(spec, axes, buttons)
    assert len(data) == frame_length(spec)
    got, got_buttons = decode_frame(spec, spec.arbitration_id, data)
    # with an enable bit the frame says held or released; without one, nothing (None)
    enable = buttons.enabled if spec.enable_bit else None
    assert got_buttons == buttons.model_copy(update={"enable": enable})
    assert got == pytest.approx(axes, abs=2.0 / spec.scale)


@given(layouts(), st.data())
def test_any_frame_of_the_right_length_decodes_to_a_valid_deflection(
    spec: CanSpec, data: st.DataObject
) -> None:
    frame = data.draw(st.binary(min_size=frame_length(spec), max_size=64))
    axes, _ = decode_frame(spec, spec.arbitration_id, frame)
    assert math.sqrt(sum(a * a for a in axes)) <= 1.0 + 1e-9
    assert all(-1.0 <= a <= 1.0 for a in axes)


def test_decode_known_frame() -> None:
    frame = struct.pack("<hhhB", 16384, 0, -8192, 0b01) + b"\xff"
    axes, buttons = decode_frame(SPEC, 0x100, frame)
    assert axes == pytest.approx((16384 / 32767, 0.0, -8192 / 32767))
    assert buttons == Buttons(cancel=True, confirm=False)
    _, buttons = decode_frame(SPEC, 0x100, struct.pack("<hhhB", 0, 0, 0, 0b10))
    assert buttons == Buttons(cancel=False, confirm=True)


def test_the_enable_bit_is_a_hold_to_run_button_only_when_the_profile_says_so() -> None:
    with_enable = CanSpec(enable_bit=True)
    for bits, enabled in ((0b000, False), (0b100, True), (0b110, True), (0b010, False)):
        frame = struct.pack("<hhhB", 8000, 0, 0, bits)
        assert decode_frame(with_enable, 0x100, frame)[1].enable is enabled
        assert decode_frame(SPEC, 0x100, frame)[1].enable is None  # no enable button
    frame = encode_frame(with_enable, (0.5, 0, 0), Buttons(enable=False, confirm=True))
    assert frame[6] == 0b010
    assert encode_frame(SPEC, (0.5, 0, 0), Buttons(enable=True))[6] == 0


def test_full_deflection_on_two_axes_is_clipped_to_norm_one_and_inverted() -> None:
    spec = CanSpec(invert=(False, True, False))
    axes, _ = decode_frame(spec, 0x100, struct.pack("<hhhB", 32767, 32767, -32768, 0))
    assert math.sqrt(sum(a * a for a in axes)) == pytest.approx(1.0)
    assert axes[0] > 0 > axes[1]
    assert axes[0] == pytest.approx(-axes[1]) == pytest.approx(-axes[2])


def test_short_frame_and_wrong_id_are_refused() -> None:
    with pytest.raises(InputError, match=r"CAN frame 0x100: data: 6 bytes, the layout needs 7"):
        decode_frame(SPEC, 0x100, bytes(6))
    with pytest.raises(InputError, match=r"CAN frame 0x101: id: expected id 0x100"):
        decode_frame(SPEC, 0x101, bytes(8))


def test_impossible_layouts_are_refused() -> None:
    with pytest.raises(InputError, match=r"can.axis_offsets\[1\].*overlaps can.axis_offsets\[0\]"):
        frame_length(CanSpec(axis_offsets=(0, 1, 4)))
    with pytest.raises(InputError, match=r"can.button_offset.*overlaps"):
        frame_length(CanSpec(button_offset=5))
    with pytest.raises(InputError, match=r"can.axis_offsets\[0\]"):
        frame_length(CanSpec(axis_offsets=(-2, 2, 4)))
    with pytest.raises(InputError, match=r"can.axis_offsets\[2\]"):
        frame_length(CanSpec(axis_offsets=(0, 2, 63)))


@pytest.fixture
def channel() -> str:
    return f"legws-test-{uuid.uuid4().hex}"


@pytest.fixture
def buses(channel: str) -> Iterator[tuple[can.BusABC, can.BusABC]]:
    """(device side, joystick reader side) on one virtual channel; both shut down after.

    The device side keeps the timestamps of the frames it sends (a FakeClock's wall time).
    """
    device = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    reader = open_bus("virtual", channel, spec=SPEC)
    try:
        yield device, reader
    finally:
        reader.shutdown()
        device.shutdown()


def send(
    bus: can.BusABC,
    axes: tuple[float, float, float],
    buttons: Buttons | None = None,
    stamp: float | None = None,
) -> None:
    """One joystick frame; ``stamp`` (wall clock) defaults to now."""
    data = encode_frame(SPEC, axes, buttons)
    msg = can.Message(
        arbitration_id=SPEC.arbitration_id,
        data=data,
        is_extended_id=False,
        timestamp=time.time() if stamp is None else stamp,
    )
    bus.send(msg)


class FakeClock:
    """Monotonic and wall clocks the test moves by hand (virtual frames carry wall stamps)."""

    def __init__(self) -> None:
        self.mono = 100.0
        self.offset = time.time() - self.mono

    def monotonic(self) -> float:
        return self.mono

    def wall(self) -> float:
        return self.mono + self.offset


def test_reader_keeps_the_newest_valid_frame_and_goes_stale(
    buses: tuple[can.BusABC, can.BusABC],
) -> None:
    device, bus = buses
    clock = FakeClock()
    reader = CanReader(bus, SPEC, timeout=0.25, clock=clock.monotonic, wall=clock.wall)
    assert reader.sample() is None  # nothing yet
    send(device, (0.1, 0.0, 0.0), stamp=clock.wall())
    send(device, (0.0, 0.4, 0.0), Buttons(cancel=True), stamp=clock.wall())
    sample = reader.sample()
    assert sample is not None
    assert sample[0] == pytest.approx((0.0, 0.4, 0.0), abs=1e-4)
    assert sample[1] == Buttons(cancel=True)
    assert reader.frames == 2
    clock.mono += 0.2
    assert reader.sample() is not None
    clock.mono += 0.1  # 0.3 s after the last frame: no input
    assert reader.sample() is None
    send(device, (0.0, 0.0, -0.5), stamp=clock.wall())
    clock.mono += 0.01
    sample = reader.sample()
    assert sample is not None
    assert sample[0] == pytest.approx((0.0, 0.0, -0.5), abs=1e-4)


def test_bad_and_foreign_frames_do_not_refresh_the_input(
    buses: tuple[can.BusABC, can.BusABC], channel: str
) -> None:
    device, bus = buses
    clock = FakeClock()
    reader = CanReader(bus, SPEC, timeout=0.25, clock=clock.monotonic, wall=clock.wall)
    send(device, (0.3, 0.0, 0.0), stamp=clock.wall())
    assert reader.sample() is not None
    clock.mono += 0.3
    now = clock.wall()
    for msg in (
        can.Message(arbitration_id=0x100, data=bytes(3), is_extended_id=False, timestamp=now),
        can.Message(arbitration_id=0x200, data=bytes(8), is_extended_id=False, timestamp=now),
        can.Message(
            arbitration_id=0x100, is_remote_frame=True, is_extended_id=False, timestamp=now
        ),
    ):
        device.send(msg)
    assert reader.sample() is None
    assert reader.rejected == 1
    assert reader.last_error is not None
    assert "needs 7" in reader.last_error
    # without the bus filter, foreign ids reach the reader and are skipped there
    unfiltered = can.Bus(interface="virtual", channel=channel)
    try:
        other = CanReader(unfiltered, SPEC, timeout=0.25, clock=clock.monotonic, wall=clock.wall)
        device.send(
            can.Message(arbitration_id=0x200, data=bytes(8), is_extended_id=False, timestamp=now)
        )
        assert other.sample() is None
        assert other.frames == 0
        assert other.rejected == 0
    finally:
        unfiltered.shutdown()


def test_frame_age_comes_from_the_bus_timestamp(buses: tuple[can.BusABC, can.BusABC]) -> None:
    device, bus = buses
    clock = FakeClock()
    reader = CanReader(bus, SPEC, timeout=0.25, clock=clock.monotonic, wall=clock.wall)
    send(device, (0.2, 0.0, 0.0), stamp=clock.wall())
    clock.mono += 0.3  # the frame waited in the queue longer than the timeout
    assert reader.sample() is None


def test_unknown_interface_and_missing_device_are_one_line_errors() -> None:
    with pytest.raises(InputError, match="unknown interface 'pcan'"):
        open_bus("pcan", "x")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="cannot open socketcan channel 'legwsnope0'") as info:
        open_bus("socketcan", "legwsnope0")
    assert "\n" not in str(info.value)


def test_virtual_bus_end_to_end_over_zenoh(channel: str) -> None:
    """Frames on a virtual bus -> the reader loop in a thread -> zenoh -> a subscriber."""
    device = can.Bus(interface="virtual", channel=channel)
    bus = open_bus("virtual", channel, spec=SPEC)
    stop = threading.Event()
    results: list[int] = []
    port = free_port()
    pub = Publisher(config_from_spec(dial_spec(port)), KEY, source="can-test")
    try:
        with daemon_side(port) as inbox, pub:
            assert pub.wait_matched(10.0)
            reader = CanReader(bus, SPEC, timeout=0.25)
            loop = threading.Thread(
                target=lambda: results.append(
                    run_can(pub, reader, rate=50.0, duration=20.0, stop_event=stop)
                )
            )
            loop.start()
            try:
                assert inbox.snapshot() == []  # no frame yet: nothing published
                time.sleep(0.2)
                assert inbox.snapshot() == []
                for _ in range(15):  # a device sending at 50 Hz for 0.3 s
                    send(device, (0.6, 0.0, -0.8), Buttons(confirm=True))
                    time.sleep(0.02)
                got = inbox.wait_for(5)
                time.sleep(0.25 + 0.1)  # the deadman timeout and then some: stale
                stale = len(inbox.snapshot())
                time.sleep(0.4)
                assert len(inbox.snapshot()) == stale  # stale input is not repeated
            finally:
                stop.set()
                loop.join(10.0)
            assert not loop.is_alive()
            final = inbox.wait_for(stale + 1)
    finally:
        bus.shutdown()
        device.shutdown()
    assert results == [stale]
    live = final[:stale]
    assert all(m.axes == pytest.approx((0.6, 0.0, -0.8), abs=1e-4) for m in live)
    assert all(m.buttons == Buttons(confirm=True) for m in live)
    assert [m.seq for m in final] == list(range(stale + 1))
    assert 5 <= stale <= 40  # ~0.3 s of frames + 0.25 s deadman at 50 Hz
    assert final[-1].axes == (0.0, 0.0, 0.0)
    assert got[0].source == "can-test"
