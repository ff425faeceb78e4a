"""evdev input devices: events -> samples, discovery, unplug and reconnect, a zenoh run.

Events are real ``evdev.InputEvent`` objects; the shipped mappings are the ones under test.
The only fake is the kernel's device (tests/joystick/fake_evdev.py), and a test through a
real uinput virtual device runs where ``/dev/uinput`` is writable.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import evdev
import pytest
from evdev import AbsInfo, InputEvent, ecodes
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.formats.input_mapping import InputMapping, load_mapping_named
from legws_daemon.formats.messages import Buttons, JoystickMessage
from legws_daemon.formats.validation import validate
from legws_daemon.joystick.evdev_input import (
    EvdevReader,
    choose_mapping,
    event_paths,
    list_devices,
    none_found_reason,
    run_evdev,
)
from legws_daemon.joystick.evdev_state import (
    NO_INPUT,
    DeviceIdentity,
    DeviceState,
    missing_capabilities,
    recognises,
    shape,
)
from legws_daemon.joystick.publisher import ZERO, Publisher, Sample
from legws_daemon.transport.session import config_from_spec
from tests.joystick.fake_evdev import (
    STICK,
    FakeInputDir,
    FakeNode,
    dualsense,
    dualsense_motion,
    event,
    keyboard,
    spacemouse_abs,
    spacemouse_rel,
    syn,
    xbox_pad,
)
from tests.joystick.helpers import KEY, daemon_side, dial_spec
from tests.net import free_port

_, XBOX = load_mapping_named("xbox")
_, SPACEMOUSE = load_mapping_named("spacemouse")
_, HID = load_mapping_named("hid_joystick")
_, PLAYSTATION = load_mapping_named("playstation")
PAD_RANGES = {c: (i.min, i.max) for c, i in xbox_pad().absinfo.items()}
PUCK_RANGES = {c: (i.min, i.max) for c, i in spacemouse_abs().absinfo.items()}

EV_KEY, EV_ABS, EV_REL = ecodes.EV_KEY, ecodes.EV_ABS, ecodes.EV_REL
LB, A, B = ecodes.BTN_TL, ecodes.BTN_SOUTH, ecodes.BTN_EAST


def frame(state: DeviceState, now: float, *changes: tuple[int, int, int]) -> None:
    """One frame of real events, then SYN_REPORT, read at ``now``."""
    state.feed_all([*(event(t, c, v) for t, c, v in changes), syn()], now)


def pad() -> DeviceState:
    return DeviceState(XBOX, PAD_RANGES)


def norm(axes: tuple[float, float, float]) -> float:
    return math.sqrt(sum(a * a for a in axes))


# --- the Xbox pad ---------------------------------------------------------------------------


def test_stick_forward_is_plus_x_only_while_enable_is_held() -> None:
    state = pad()
    frame(state, 0.0, (EV_ABS, ecodes.ABS_Y, -32768))  # stick fully up, LB not held
    assert state.sample(0.0) == NO_INPUT == (ZERO, Buttons(enable=False))
    frame(state, 0.1, (EV_KEY, LB, 1))
    axes, buttons = state.sample(0.1)[:2]
    assert axes == pytest.approx((1.0, 0.0, 0.0), abs=1e-4)
    assert buttons == Buttons(enable=True, confirm=False, cancel=False)
    frame(state, 0.2, (EV_ABS, ecodes.ABS_Y, 32767))  # stick down: -x
    assert state.sample(0.2)[0] == pytest.approx((-1.0, 0.0, 0.0), abs=1e-4)
    frame(state, 0.3, (EV_KEY, LB, 0))  # let go of LB, stick still down
    assert state.sample(0.3) == NO_INPUT


def test_stick_left_is_plus_y_and_right_stick_or_dpad_up_is_plus_z() -> None:
    state = pad()
    frame(state, 0.0, (EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_X, -32768))
    assert state.sample(0.0)[0] == pytest.approx((0.0, 1.0, 0.0), abs=1e-4)
    frame(state, 0.1, (EV_ABS, ecodes.ABS_X, 0), (EV_ABS, ecodes.ABS_RY, -32768))
    assert state.sample(0.1)[0] == pytest.approx((0.0, 0.0, 1.0), abs=1e-4)
    frame(state, 0.2, (EV_ABS, ecodes.ABS_RY, 0), (EV_ABS, ecodes.ABS_HAT0Y, -1))
    assert state.sample(0.2)[0] == pytest.approx((0.0, 0.0, 0.5))  # the d-pad at half speed
    frame(state, 0.3, (EV_ABS, ecodes.ABS_HAT0Y, 1))
    assert state.sample(0.3)[0] == pytest.approx((0.0, 0.0, -0.5))
    # d-pad and right stick both up: summed, then clipped to 1
    frame(state, 0.4, (EV_ABS, ecodes.ABS_HAT0Y, -1), (EV_ABS, ecodes.ABS_RY, -32768))
    assert state.sample(0.4)[0] == pytest.approx((0.0, 0.0, 1.0), abs=1e-4)


def test_deadzone_gives_exactly_zero_and_the_curve_is_quadratic_beyond_it() -> None:
    state = pad()
    edge = int(0.149 * 32767)  # just inside 15 %
    frame(state, 0.0, (EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -edge), (EV_ABS, ecodes.ABS_X, edge))
    axes, buttons = state.sample(0.0)[:2]
    assert axes == (0.0, 0.0, 0.0)  # exactly, not approximately
    assert buttons.enable
    frame(state, 0.1, (EV_ABS, ecodes.ABS_Y, -16384))  # half up
    half = (16384 - 0.5) / 32767.5  # the centre of -32768..32767 is -0.5
    assert state.sample(0.1)[0][0] == pytest.approx(((half - 0.15) / 0.85) ** 2)


def test_two_stick_axes_at_full_deflection_are_clipped_to_norm_one() -> None:
    state = pad()
    frame(
        state, 0.0, (EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -32768), (EV_ABS, ecodes.ABS_X, -32768)
    )
    axes, _ = state.sample(0.0)
    assert norm(axes) == pytest.approx(1.0)
    assert axes[0] == pytest.approx(axes[1]) == pytest.approx(math.sqrt(0.5), abs=1e-4)


def test_confirm_and_cancel_are_sent_only_with_enable_held() -> None:
    state = pad()
    frame(state, 0.0, (EV_KEY, A, 1))  # confirm without enable: nothing
    assert state.sample(0.0) == NO_INPUT
    frame(state, 0.1, (EV_KEY, LB, 1))
    assert state.sample(0.1) == (ZERO, Buttons(enable=True, confirm=True, cancel=False))
    frame(state, 0.2, (EV_KEY, A, 0), (EV_KEY, B, 1))
    assert state.sample(0.2) == (ZERO, Buttons(enable=True, confirm=False, cancel=True))
    frame(state, 0.3, (EV_KEY, B, 2))  # auto-repeat: still held
    assert state.sample(0.3)[1].cancel
    frame(state, 0.4, (EV_KEY, LB, 0))
    assert state.sample(0.4) == NO_INPUT


def test_a_frame_takes_effect_at_its_syn_report() -> None:
    state = pad()
    state.feed(event(EV_KEY, LB, 1), 0.0)
    state.feed(event(EV_ABS, ecodes.ABS_Y, -32768), 0.0)
    assert state.sample(0.0) == NO_INPUT  # half a frame: nothing yet
    state.feed(syn(), 0.0)
    assert state.sample(0.0)[0][0] == pytest.approx(1.0, abs=1e-4)
    assert (state.events, state.frames) == (3, 1)


def test_a_button_held_when_the_device_opens_counts_after_a_release() -> None:
    state = pad()
    state.sync({ecodes.ABS_Y: -32768}, [LB, A], fresh=True)  # LB stuck down at start
    assert state.sample(0.0) == NO_INPUT
    frame(state, 0.1, (EV_KEY, LB, 2))  # a repeat does not arm it
    assert state.sample(0.1) == NO_INPUT
    frame(state, 0.2, (EV_KEY, LB, 0))
    frame(state, 0.3, (EV_KEY, LB, 1))
    axes, buttons = state.sample(0.3)[:2]
    assert axes[0] == pytest.approx(1.0, abs=1e-4)  # the synced stick position counts
    assert buttons == Buttons(enable=True)  # A was held at open too: not yet a confirm


def test_syn_dropped_discards_to_the_next_report_and_waits_for_a_resync() -> None:
    state = pad()
    frame(state, 0.0, (EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -32768))
    assert state.sample(0.0)[1].enable
    state.feed_all(
        [
            event(EV_ABS, ecodes.ABS_X, -32768),  # the frame the overflow cut
            syn(ecodes.SYN_DROPPED),
            event(EV_ABS, ecodes.ABS_X, -32768),  # up to the next SYN_REPORT: discarded
            syn(),
        ],
        0.1,
    )
    assert state.dropped == 1
    assert state.needs_sync
    assert state.sample(0.1) == NO_INPUT  # unknown: at rest, buttons up
    # what the reader does at once: the device's current state; LB still held counts
    state.sync({ecodes.ABS_Y: -32768, ecodes.ABS_X: 0}, [LB])
    assert not state.needs_sync
    assert state.sample(0.1)[0] == pytest.approx((1.0, 0.0, 0.0), abs=1e-4)
    frame(state, 0.2, (EV_ABS, ecodes.ABS_X, -32768))  # later frames apply again
    assert state.sample(0.2)[0][1] > 0.7


def test_a_trigger_as_button_and_as_a_one_sided_axis() -> None:
    data: dict[str, Any] = {
        "schema_version": 1,
        "device": {"name": "pad with triggers", "match": ["x-box"]},
        "axis": [
            {"code": "ABS_Y", "drives": "x", "invert": True},
            {"code": "ABS_Z", "drives": "z", "rest": "min", "invert": True},  # LT: down
        ],
        "buttons": {"enable": {"code": "ABS_RZ", "threshold": 0.5}, "confirm": "BTN_SOUTH"},
    }
    mapping = validate(InputMapping, data, "test")
    state = DeviceState(mapping, PAD_RANGES)
    frame(state, 0.0, (EV_ABS, ecodes.ABS_RZ, 400), (EV_ABS, ecodes.ABS_Z, 1023))
    assert state.sample(0.0) == NO_INPUT  # RT below half way
    frame(state, 0.1, (EV_ABS, ecodes.ABS_RZ, 600))
    assert state.sample(0.1) == ((0.0, 0.0, -1.0), Buttons(enable=True))
    frame(state, 0.2, (EV_ABS, ecodes.ABS_Z, 0))  # LT released: trigger rest is its min
    assert state.sample(0.2)[0] == (0.0, 0.0, 0.0)


def test_an_absolute_axis_without_a_range_is_inactive() -> None:
    state = DeviceState(XBOX)  # no device ranges: the pad's sticks have no range in the file
    frame(state, 0.0, (EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -32768))
    assert state.sample(0.0) == (ZERO, Buttons(enable=True))


# --- the SpaceMouse ------------------------------------------------------------------------


def test_a_playstation_pad_with_its_0_to_255_sticks() -> None:
    ranges = {c: (i.min, i.max) for c, i in dualsense().absinfo.items()}
    state = DeviceState(PLAYSTATION, ranges)
    frame(state, 0.0, (EV_ABS, ecodes.ABS_Y, 0), (EV_ABS, ecodes.ABS_X, 128))  # stick up
    assert state.sample(0.0) == (ZERO, Buttons(enable=False))  # L1 not held
    frame(state, 0.1, (EV_KEY, ecodes.BTN_TL, 1), (EV_KEY, ecodes.BTN_SOUTH, 1))
    axes, buttons = state.sample(0.1)[:2]
    assert axes == pytest.approx((1.0, 0.0, 0.0), abs=1e-3)
    assert buttons == Buttons(enable=True, confirm=True)
    frame(state, 0.2, (EV_ABS, ecodes.ABS_Y, 130), (EV_ABS, ecodes.ABS_X, 125))  # drift
    assert state.sample(0.2)[0] == ZERO  # inside the deadzone


def test_spacemouse_on_ev_rel_pushes_and_decays_after_the_hold_time() -> None:
    state = DeviceState(SPACEMOUSE)
    frame(state, 9.9, (EV_KEY, ecodes.BTN_0, 1))  # the left button held: hold-to-run
    frame(state, 10.0, (EV_REL, ecodes.REL_Y, -350))  # cap pushed away from the user
    axes, buttons = state.sample(10.0)[:2]
    assert axes == pytest.approx((1.0, 0.0, 0.0))
    assert buttons == Buttons(enable=True)
    assert state.sample(10.09)[0] == pytest.approx((1.0, 0.0, 0.0))  # within 0.1 s
    assert state.sample(10.11) == (ZERO, Buttons(enable=True))  # no event: back at rest
    # pushed right (+X raw) = -y; pressed down (+Z raw) = -z; lifted (-Z raw) = +z
    frame(state, 11.0, (EV_REL, ecodes.REL_X, 175), (EV_REL, ecodes.REL_Z, -175))
    half = ((0.5 - 0.08) / 0.92) ** 2  # half deflection through deadzone and quadratic
    assert state.sample(11.0)[0] == pytest.approx((0.0, -half, half))
    # the axes decay one by one: Z keeps reporting, X fell silent
    frame(state, 11.08, (EV_REL, ecodes.REL_Z, -175))
    axes, _ = state.sample(11.15)
    assert axes[1] == 0.0
    assert axes[2] > 0.0


def test_spacemouse_on_ev_abs_keeps_its_last_value() -> None:
    state = DeviceState(SPACEMOUSE, PUCK_RANGES)
    frame(state, 0.0, (EV_ABS, ecodes.ABS_Y, -350), (EV_ABS, ecodes.ABS_Z, 350))
    assert state.sample(0.0) == (ZERO, Buttons(enable=False))  # the left button not held
    frame(state, 0.0, (EV_KEY, ecodes.BTN_0, 1))
    axes, _ = state.sample(0.0)
    assert axes == pytest.approx((math.sqrt(0.5), 0.0, -math.sqrt(0.5)))
    assert state.sample(5.0)[0] == axes  # absolute: no decay
    frame(state, 5.1, (EV_ABS, ecodes.ABS_Y, 0), (EV_ABS, ecodes.ABS_Z, 20))  # noise at rest
    assert state.sample(5.1)[0] == (0.0, 0.0, 0.0)


def test_spacemouse_left_button_is_hold_to_run_and_right_confirms() -> None:
    state = DeviceState(SPACEMOUSE)
    frame(state, 0.0, (EV_KEY, ecodes.BTN_1, 1))
    assert state.sample(0.0) == (ZERO, Buttons(enable=False))  # a confirm without enable
    frame(state, 0.1, (EV_KEY, ecodes.BTN_0, 1))
    assert state.sample(0.1) == (ZERO, Buttons(enable=True, confirm=True))
    frame(state, 0.2, (EV_KEY, ecodes.BTN_1, 0), (EV_KEY, ecodes.BTN_0, 0))
    assert state.sample(0.2) == (ZERO, Buttons(enable=False))


# --- properties ------------------------------------------------------------------------------

values = st.floats(-1.5, 1.5, allow_nan=False)
deadzones = st.floats(0.0, 0.9)
exponents = st.floats(0.25, 5.0)


@given(values, values, deadzones, exponents)
def test_the_curve_is_monotone_and_continuous(
    a: float, b: float, deadzone: float, exponent: float
) -> None:
    lo, hi = sorted((a, b))
    f_lo, f_hi = shape(lo, deadzone, exponent), shape(hi, deadzone, exponent)
    assert f_lo <= f_hi  # monotone
    # continuous: a Hölder bound (Lipschitz for exponents >= 1), no jump at the deadzone
    step = (hi - lo) / (1.0 - deadzone)
    assert f_hi - f_lo <= 2.0 * max(exponent, 1.0) * step ** min(exponent, 1.0) + 1e-12
    assert -1.0 <= f_lo <= f_hi <= 1.0


@given(deadzones, exponents, st.floats(0.0, 1.0))
def test_the_curve_is_zero_in_the_deadzone_and_one_at_full_deflection(
    deadzone: float, exponent: float, fraction: float
) -> None:
    inside = fraction * deadzone
    assert shape(inside, deadzone, exponent) == 0.0
    assert shape(-inside, deadzone, exponent) == 0.0
    assert shape(1.0, deadzone, exponent) == 1.0
    assert shape(-1.0, deadzone, exponent) == -1.0


def _event_strategy(codes: list[tuple[int, int, int, int]]) -> st.SearchStrategy[InputEvent]:
    """Events of the given (type, code, lo, hi) kinds, SYN_REPORT and SYN_DROPPED among them."""
    kinds = [st.tuples(st.just(t), st.just(c), st.integers(lo, hi)) for t, c, lo, hi in codes]
    kinds.append(st.tuples(st.just(0), st.sampled_from([0, 0, 0, 3]), st.just(0)))
    return st.one_of(kinds).map(lambda tcv: event(*tcv))


PAD_EVENTS = _event_strategy(
    [(EV_ABS, c, -40000, 40000) for c in (ecodes.ABS_X, ecodes.ABS_Y, ecodes.ABS_RY)]
    + [(EV_ABS, ecodes.ABS_HAT0Y, -1, 1)]
    + [(EV_KEY, c, 0, 2) for c in (LB, A, B)]
)
PUCK_EVENTS = _event_strategy(
    [(EV_REL, c, -600, 600) for c in (ecodes.REL_X, ecodes.REL_Y, ecodes.REL_Z)]
    + [(EV_ABS, c, -600, 600) for c in (ecodes.ABS_X, ecodes.ABS_Y, ecodes.ABS_Z)]
    + [(EV_KEY, c, 0, 1) for c in (ecodes.BTN_0, ecodes.BTN_1)]
)


def _check(sample: Sample) -> None:
    axes, buttons = sample[:2]
    assert norm(axes) <= 1.0 + 1e-9
    assert all(-1.0 <= a <= 1.0 for a in axes)
    if not buttons.enable:
        assert sample == NO_INPUT
    JoystickMessage.model_validate(
        {"schema": 1, "seq": 0, "stamp": 0.0, "axes": list(axes), "buttons": buttons}
    )


@settings(max_examples=200)
@given(st.lists(PAD_EVENTS, max_size=60), st.lists(st.floats(0.0, 0.05), max_size=60))
def test_any_pad_event_sequence_gives_valid_samples(
    events: list[InputEvent], gaps: list[float]
) -> None:
    state = pad()
    now = 0.0
    for e, gap in zip(events, gaps + [0.0] * len(events), strict=False):
        now += gap
        state.feed(e, now)
        _check(state.sample(now))


@settings(max_examples=200)
@given(st.lists(PUCK_EVENTS, max_size=60), st.lists(st.floats(0.0, 0.2), max_size=60))
def test_any_spacemouse_event_sequence_gives_valid_samples(
    events: list[InputEvent], gaps: list[float]
) -> None:
    state = DeviceState(SPACEMOUSE, PUCK_RANGES)
    now = 0.0
    for e, gap in zip(events, gaps + [0.0] * len(events), strict=False):
        now += gap
        state.feed(e, now)
        sample = state.sample(now)
        _check(sample)
        assert sample[1].enable == state.enabled()
    assert state.deflection(now + 0.2) == state.deflection(now + 1.0)  # REL decayed either way


# --- matching ---------------------------------------------------------------------------------


def identity(node: FakeNode) -> DeviceIdentity:
    caps = node.capabilities(absinfo=False)
    return DeviceIdentity(
        node.name,
        node.info.vendor,
        node.info.product,
        frozenset(caps.get(EV_KEY, ())),
        frozenset(caps.get(EV_ABS, ())),
        frozenset(caps.get(EV_REL, ())),
    )


@pytest.mark.parametrize(
    ("node", "expected"),
    [
        (xbox_pad(), ["xbox"]),
        (xbox_pad("Generic X-Box pad"), ["xbox"]),
        (xbox_pad("Xbox Wireless Controller"), ["xbox"]),
        (dualsense(), ["playstation"]),
        (dualsense("Sony Interactive Entertainment Wireless Controller"), ["playstation"]),
        (dualsense_motion(), []),  # the pad's sensor node: no L1
        (spacemouse_rel(), ["spacemouse"]),
        (spacemouse_abs(), ["spacemouse"]),
        (keyboard(), []),
        # the consumer-control node beside a pad: the name matches, no LB and no sticks
        (FakeNode("Xbox Wireless Controller Consumer Control", 0x045E, 0x0B13, keys=[163]), []),
        (
            FakeNode(
                "Thrustmaster USB Joystick",
                0x044F,
                0xB108,
                keys=[ecodes.BTN_TRIGGER, ecodes.BTN_THUMB, ecodes.BTN_THUMB2],
                abs={ecodes.ABS_X: STICK, ecodes.ABS_Y: STICK},
            ),
            ["hid_joystick"],
        ),
    ],
)
def test_which_mapping_recognises_which_device(node: FakeNode, expected: list[str]) -> None:
    mappings = {"xbox": XBOX, "spacemouse": SPACEMOUSE, "hid_joystick": HID}
    mappings["playstation"] = PLAYSTATION
    got = [name for name, m in mappings.items() if recognises(m, identity(node))]
    assert got == expected


def test_missing_capabilities_name_the_codes() -> None:
    assert missing_capabilities(XBOX, identity(keyboard())) == [
        "BTN_TL",
        "any of ABS_Y, ABS_X, ABS_RY, ABS_HAT0Y, ABS_RX, ABS_HAT0X",
    ]
    assert missing_capabilities(SPACEMOUSE, identity(spacemouse_rel())) == []


# --- discovery ----------------------------------------------------------------------------------


def test_list_devices_in_number_order_with_mappings_and_reasons(devices: FakeInputDir) -> None:
    devices.plug(10, spacemouse_rel())
    devices.plug(3, xbox_pad())
    devices.plug(2, keyboard())
    devices.forbid(4)
    (devices.folder / "js0").touch()  # not an event node
    found = list_devices(devices.folder, devices.open)
    assert [Path(f.path).name for f in found] == ["event2", "event3", "event4", "event10"]
    assert [f.mappings for f in found] == [(), ("xbox",), (), ("spacemouse",)]
    lines = [f.describe() for f in found]
    assert lines[1] == (
        f'{devices.path(3)}: "Microsoft X-Box 360 pad" 045e:028e, 8 absolute axes, '
        "0 relative axes, 11 buttons/keys; mapping: xbox"
    )
    assert lines[0].endswith("mapping: none")
    assert lines[2].startswith(f"{devices.path(4)}: cannot open: permission denied: join the")
    assert "udev rule" in lines[2]
    assert all(h.fd == -1 for h in devices.opened)  # every node listed was closed again


def test_no_devices_and_no_folder(tmp_path: Path) -> None:
    assert event_paths(tmp_path / "nope") == []
    assert list_devices(tmp_path / "nope") == []
    assert "does not exist" in none_found_reason(tmp_path / "nope")
    reason = none_found_reason(tmp_path)
    assert reason.startswith(f"no input devices found in {tmp_path}")
    assert "'input' group" in reason


def test_choose_mapping(devices: FakeInputDir) -> None:
    with pytest.raises(InputError, match="no input devices found in") as info:
        choose_mapping(None, None, devices.folder, devices.open)
    assert "\n" not in str(info.value)
    devices.plug(1, keyboard())
    devices.plug(2, spacemouse_abs())
    assert choose_mapping(None, None, devices.folder, devices.open)[0] == "spacemouse"
    devices.plug(3, xbox_pad())
    # shipped mappings are tried in name order: spacemouse before xbox
    assert choose_mapping(None, None, devices.folder, devices.open)[0] == "spacemouse"
    assert choose_mapping(None, devices.path(3), devices.folder, devices.open)[0] == "xbox"
    assert choose_mapping("xbox", None, devices.folder, devices.open)[1] == XBOX
    with pytest.raises(InputError, match=r'no shipped mapping .* recognises "AT Translated'):
        choose_mapping(None, devices.path(1), devices.folder, devices.open)
    with pytest.raises(InputError, match=r"event9: cannot open: no such device"):
        choose_mapping(None, devices.path(9), devices.folder, devices.open)
    devices.forbid(4)
    devices.unplug(devices.path(2))
    devices.unplug(devices.path(3))
    with pytest.raises(InputError, match=r"2 event devices, 1 readable, none recognised.*group"):
        choose_mapping(None, None, devices.folder, devices.open)


# --- the reader: open, unplug, reconnect -------------------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def reader_for(
    devices: FakeInputDir, mapping: InputMapping = XBOX, device: str | None = None
) -> tuple[EvdevReader, Clock, list[str]]:
    clock = Clock()
    log: list[str] = []
    reader = EvdevReader(
        mapping,
        device=device,
        folder=devices.folder,
        opener=devices.open,
        clock=clock,
        retry=0.5,
        log=log.append,
    )
    return reader, clock, log


def test_opening_errors_are_one_line(devices: FakeInputDir) -> None:
    reader, _, _ = reader_for(devices)
    with pytest.raises(InputError, match=r"device: no input device matches mapping 'Xbox"):
        reader.open()
    path = devices.plug(1, keyboard())
    reader, _, _ = reader_for(devices, device=path)
    with pytest.raises(InputError, match=r'event1: "AT Translated Set 2 keyboard" lacks BTN_TL'):
        reader.open()
    forbidden = devices.forbid(2)
    reader, _, _ = reader_for(devices, device=forbidden)
    with pytest.raises(InputError, match=r"event2: cannot open: permission denied"):
        reader.open()
    assert all(h.fd == -1 for h in devices.opened)


def test_unplug_sends_no_input_at_once_and_a_replug_is_picked_up(devices: FakeInputDir) -> None:
    devices.plug(2, keyboard())
    node = xbox_pad()
    path = devices.plug(5, node)
    reader, clock, log = reader_for(devices)
    reader.open()
    assert (reader.path, reader.name) == (path, "Microsoft X-Box 360 pad")
    node.frame((EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -32768))
    reader.pump()
    assert reader.sample()[0] == pytest.approx((1.0, 0.0, 0.0), abs=1e-4)

    devices.unplug(path)
    reader.pump()  # the read fails with ENODEV
    assert not reader.connected
    assert reader.sample() == NO_INPUT
    assert reader.unplugged == 1
    assert len(log) == 1
    assert log[0].startswith("legws: input device lost (no such device): Microsoft X-Box")
    opened = len(devices.opened)
    clock.now += 0.4
    reader.pump()  # before the retry time: no look
    assert len(devices.opened) == opened
    clock.now += 0.2
    reader.pump()  # looks, finds nothing (the keyboard is no pad)
    assert not reader.connected
    assert reader.sample() == NO_INPUT

    # it comes back on another node, LB held while plugging in: not armed yet
    back = xbox_pad()
    back.down.add(LB)
    back.absinfo[ecodes.ABS_Y] = STICK._replace(value=-32768)
    new_path = devices.plug(7, back)
    clock.now += 0.6
    reader.pump()
    assert reader.connected
    assert reader.path == new_path
    assert (reader.unplugged, reader.reconnected) == (1, 1)
    assert log[1] == f"legws: input device back: Microsoft X-Box 360 pad at {new_path}"
    assert reader.sample() == NO_INPUT
    back.frame((EV_KEY, LB, 0))
    back.frame((EV_KEY, LB, 1))
    reader.pump()
    assert reader.sample()[0] == pytest.approx((1.0, 0.0, 0.0), abs=1e-4)  # the stick as it is
    reader.close()
    assert not reader.connected


def test_an_explicit_device_is_waited_for_on_its_own_path(devices: FakeInputDir) -> None:
    node = xbox_pad()
    path = devices.plug(3, node)
    reader, clock, log = reader_for(devices, device=path)
    reader.open()
    devices.unplug(path)
    reader.pump()
    assert not reader.connected
    devices.plug(4, xbox_pad())  # another pad elsewhere: not taken
    clock.now += 1.0
    reader.pump()
    assert not reader.connected
    devices.plug(3, keyboard())  # the path is back, but as a keyboard: not taken
    clock.now += 1.0
    reader.pump()
    assert not reader.connected
    devices.unplug(path)
    again = xbox_pad()
    devices.plug(3, again)
    clock.now += 1.0
    reader.pump()
    assert reader.connected
    assert reader.path == path
    again.frame((EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_X, -32768))
    reader.pump()
    assert reader.sample()[0] == pytest.approx((0.0, 1.0, 0.0), abs=1e-4)
    assert (reader.unplugged, reader.reconnected, len(log)) == (1, 1, 2)
    reader.close()


def test_syn_dropped_resynchronises_from_the_device(devices: FakeInputDir) -> None:
    node = xbox_pad()
    devices.plug(0, node)
    reader, _, _ = reader_for(devices)
    reader.open()
    node.frame((EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -32768))
    reader.pump()
    # the kernel's buffer overflowed: the stick went from up to left, the events were lost
    # (the device's state knows)
    node.absinfo[ecodes.ABS_X] = STICK._replace(value=-32768)
    node.absinfo[ecodes.ABS_Y] = STICK._replace(value=0)
    node.emit([event(EV_ABS, ecodes.ABS_Y, -100), syn(ecodes.SYN_DROPPED), syn()])
    reader.pump()
    assert reader.state.dropped == 1
    assert not reader.state.needs_sync
    axes, buttons = reader.sample()[:2]
    assert buttons.enable  # LB held throughout: still counts after the resync
    assert axes == pytest.approx((0.0, 1.0, 0.0), abs=1e-4)
    reader.close()


def test_the_thread_reads_without_blocking_the_sample(devices: FakeInputDir) -> None:
    node = spacemouse_rel()
    devices.plug(0, node)
    reader = EvdevReader(SPACEMOUSE, folder=devices.folder, opener=devices.open, log=lambda _: None)
    with reader:
        start = time.monotonic()
        for _ in range(20):
            reader.sample()
        assert time.monotonic() - start < 2.0  # no sample waits for the silent device
        node.frame((EV_KEY, ecodes.BTN_0, 1), (EV_REL, ecodes.REL_Z, -350))
        deadline = time.monotonic() + 5.0
        while reader.sample()[0][2] < 0.99:
            assert time.monotonic() < deadline, "the thread did not read the event"
            time.sleep(0.005)
        time.sleep(0.15)
        assert reader.sample()[0] == ZERO  # no more events: decayed
    assert not reader.connected


def wait_for(done: Callable[[], bool], what: str, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not done():
        assert time.monotonic() < deadline, what
        time.sleep(0.005)


def test_an_unexpected_reader_error_is_no_input_not_a_frozen_stick(devices: FakeInputDir) -> None:
    node = xbox_pad()
    devices.plug(0, node)
    log: list[str] = []
    reader = EvdevReader(
        XBOX, folder=devices.folder, opener=devices.open, retry=0.05, log=log.append
    )
    with reader:
        node.frame((EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -32768))
        wait_for(lambda: reader.sample()[1].enable, "the press was not read")

        def broken() -> Iterator[InputEvent]:
            raise RuntimeError("boom")
            yield  # a generator, as evdev's read is

        devices.opened[-1].read = broken  # type: ignore[method-assign]
        node.frame((EV_ABS, ecodes.ABS_X, -32768))
        wait_for(lambda: reader.sample() == NO_INPUT, "the failed reader still steers")
        wait_for(lambda: bool(log), "the loss was not logged")  # (logged after the stop)
        assert log[0].startswith("legws: input device lost (reader error: RuntimeError: boom)")
        wait_for(lambda: reader.connected, "the device was not opened again")
        assert reader.sample() == NO_INPUT  # LB still held from before: press it again
        node.frame((EV_KEY, LB, 0))
        node.frame((EV_KEY, LB, 1))
        wait_for(lambda: reader.sample()[1].enable, "the fresh press was not read")
        assert norm(reader.sample()[0]) == pytest.approx(1.0)


# --- a real publisher over zenoh loopback ----------------------------------------------------


def test_publisher_over_zenoh_through_unplug_and_reconnect(devices: FakeInputDir) -> None:
    node = xbox_pad()
    path = devices.plug(3, node)
    log: list[str] = []
    reader = EvdevReader(
        XBOX, folder=devices.folder, opener=devices.open, retry=0.05, log=log.append
    )
    stop = threading.Event()
    results: list[int] = []
    port = free_port()
    pub = Publisher(config_from_spec(dial_spec(port)), KEY, source="evdev-test")
    with daemon_side(port) as inbox, pub, reader:
        assert pub.wait_matched(10.0)
        loop = threading.Thread(
            target=lambda: results.append(
                run_evdev(pub, reader, rate=50.0, duration=30.0, stop_event=stop)
            )
        )
        loop.start()
        try:
            inbox.wait_for(3)
            assert all(m.buttons == Buttons(enable=False) for m in inbox.snapshot())
            node.frame((EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_Y, -32768), (EV_KEY, A, 1))
            inbox.wait_until(lambda ms: any(m.axes[0] > 0.99 for m in ms))
            mark = len(inbox.snapshot())
            devices.unplug(path)
            inbox.wait_until(lambda ms: any(not m.buttons.enable for m in ms[mark:]))
            time.sleep(0.3)  # unplugged for a while
            back = xbox_pad()
            devices.plug(3, back)
            deadline = time.monotonic() + 10.0
            while not reader.connected:
                assert time.monotonic() < deadline, "the pad was not picked up again"
                time.sleep(0.01)
            back.frame((EV_KEY, LB, 1), (EV_ABS, ecodes.ABS_X, -32768))
            inbox.wait_until(lambda ms: any(m.axes[1] > 0.99 for m in ms[mark:]))
        finally:
            stop.set()
            loop.join(10.0)
        assert not loop.is_alive()
        final = inbox.wait_for(results[0] + 1)
    assert [m.seq for m in final] == list(range(results[0] + 1))
    assert len({m.session for m in final}) == 1
    steering = next(m for m in final if m.axes[0] > 0.99)
    assert steering.buttons == Buttons(enable=True, confirm=True, cancel=False)
    lost = next(i for i in range(mark, len(final)) if not final[i].buttons.enable)
    back_at = next(i for i in range(lost, len(final)) if final[i].buttons.enable)
    gap = final[lost:back_at]
    assert len(gap) >= 10  # 0.3 s at 50 Hz, at least
    assert all(m.axes == (0.0, 0.0, 0.0) and m.buttons == Buttons(enable=False) for m in gap)
    assert final[-1].bye
    assert final[-1].axes == (0.0, 0.0, 0.0)
    assert not final[-1].buttons.enable
    assert [line.split(":")[1].strip() for line in log] == [
        "input device lost (no such device)",
        "input device back",
    ]


# --- a real virtual device through the kernel ----------------------------------------------------


def pump_until(reader: EvdevReader, done: Callable[[], bool], what: str) -> None:
    """Let the reader read (on this thread) until ``done()``, at most 5 s."""
    deadline = time.monotonic() + 5.0
    while not done():
        assert time.monotonic() < deadline, what
        reader.pump(0.05)


@pytest.mark.skipif(
    not os.access("/dev/uinput", os.W_OK),
    reason="needs a writable /dev/uinput (the uinput module loaded; root or a udev rule)",
)
def test_a_uinput_virtual_pad_through_the_kernel() -> None:
    stick = AbsInfo(value=0, min=-32768, max=32767, fuzz=16, flat=128, resolution=0)
    caps: dict[int, Sequence[Any]] = {
        EV_KEY: [A, B, LB, ecodes.BTN_TR],
        EV_ABS: [
            (ecodes.ABS_X, stick),
            (ecodes.ABS_Y, stick),
            (ecodes.ABS_RY, stick),
            (ecodes.ABS_HAT0Y, AbsInfo(value=0, min=-1, max=1, fuzz=0, flat=0, resolution=0)),
        ],
    }
    log: list[str] = []
    ui = evdev.UInput(caps, name="legws test X-Box pad", vendor=0x045E, product=0x028E)
    try:
        path = str(ui.device.path)
        reader = EvdevReader(XBOX, device=path, log=log.append)
        reader.open()  # the real evdev.InputDevice on the node the kernel made
        assert reader.name == "legws test X-Box pad"
        assert reader.sample() == NO_INPUT
        ui.write(EV_KEY, LB, 1)
        ui.write(EV_ABS, ecodes.ABS_Y, -32768)
        ui.syn()
        pump_until(reader, lambda: reader.sample()[0][0] > 0.99, "stick up was not read")
        assert reader.sample()[1] == Buttons(enable=True)
        ui.write(EV_ABS, ecodes.ABS_X, -32768)
        ui.write(EV_KEY, A, 1)
        ui.syn()
        pump_until(reader, lambda: reader.sample()[1].confirm, "A was not read")
        assert norm(reader.sample()[0]) == pytest.approx(1.0)
        ui.write(EV_KEY, LB, 0)
        ui.syn()
        pump_until(reader, lambda: reader.sample() == NO_INPUT, "LB release was not read")
    finally:
        ui.close()  # the virtual device goes away: an unplug
    pump_until(reader, lambda: not reader.connected, "the removal was not noticed")
    assert reader.sample() == NO_INPUT
    assert "input device lost" in log[0]
    reader.close()
