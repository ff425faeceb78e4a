"""The operator's full hand on every publisher: rotation axes, the gripper button and the
speed scale (the press logic, the keyboard, CAN frames, evdev events), and the wire form
that keeps schema-1 senders' bytes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from evdev import ecodes

from legws_daemon.errors import InputError
from legws_daemon.formats.input_mapping import load_mapping_named
from legws_daemon.formats.messages import (
    Buttons,
    JoystickMessage,
    canonical_bytes,
    dump,
    parse,
)
from legws_daemon.formats.profile import CanSpec
from legws_daemon.joystick.can_input import decode_frame, encode_frame, hand_bits
from legws_daemon.joystick.evdev_state import DeviceState
from legws_daemon.joystick.hand import SPEED_LEVELS, HandState
from legws_daemon.joystick.keyboard import KeyboardState
from tests.joystick.fake_evdev import event, syn, xbox_pad

_, XBOX = load_mapping_named("xbox")
PAD_RANGES = {c: (i.min, i.max) for c, i in xbox_pad().absinfo.items()}
EV_KEY, EV_ABS = ecodes.EV_KEY, ecodes.EV_ABS


def test_presses_toggle_the_gripper_and_step_the_speed() -> None:
    hand = HandState()
    assert (hand.gripper, hand.scale) == (None, 1.0)  # no request before the first press
    hand.update(gripper_down=True)
    hand.update(gripper_down=True)  # still held: one press
    assert hand.gripper is True
    hand.update()
    hand.update(gripper_down=True)
    assert hand.gripper is False
    scales = []
    for _ in range(4):
        hand.update(speed_down=True)
        hand.update()
        scales.append(hand.scale)
    assert scales == [*SPEED_LEVELS[1:], SPEED_LEVELS[0], SPEED_LEVELS[1]]


def test_a_schema_1_message_keeps_its_canonical_bytes_and_wire_form() -> None:
    old = {"schema": 1, "seq": 42, "stamp": 1732612345.25, "axes": [0.6, 0.0, -0.8],
           "buttons": {"cancel": False, "confirm": False, "enable": True},
           "source": "gamepad:4242", "session": "9f2c61d07ab34e15", "bye": False}  # fmt: skip
    m = parse(JoystickMessage, json.dumps(old).encode(), "joystick")
    # the bytes docs/messages.md prints for this message, before rotation and gripper
    assert canonical_bytes(m) == (
        b'{"axes":[0.6,0.0,-0.8],"buttons":{"cancel":false,"confirm":false,"enable":true},'
        b'"bye":false,"schema":1,"seq":42,"session":"9f2c61d07ab34e15",'
        b'"source":"gamepad:4242","stamp":1732612345.25}'
    )
    wire = json.loads(dump(m))
    assert "rotation" not in wire and "gripper" not in wire["buttons"]
    new = parse(
        JoystickMessage,
        json.dumps(
            {**old, "rotation": [0.0, 0.0, 0.5], "buttons": {**old["buttons"], "gripper": True}}
        ).encode(),
        "joystick",
    )
    assert b'"rotation":[0.0,0.0,0.5]' in canonical_bytes(new)
    assert b'"gripper":true' in canonical_bytes(new)
    assert parse(JoystickMessage, dump(new), "joystick") == new


def test_a_rotation_beyond_norm_one_is_refused_naming_the_field() -> None:
    bad = {"schema": 1, "seq": 1, "stamp": 0.0, "axes": [0, 0, 0], "rotation": [0.9, 0.9, 0]}
    with pytest.raises(InputError, match=r"rotation: rotation must have norm <= 1"):
        parse(JoystickMessage, json.dumps(bad).encode(), "joystick")


def test_the_keyboard_turns_grips_and_scales() -> None:
    k = KeyboardState(hold=0.3)
    k.press("u", 0.0)  # +z turn
    k.press("w", 0.0)
    axes, buttons, turn = k.sample(0.1)  # type: ignore[misc]
    assert axes == (1.0, 0.0, 0.0) and turn == (0.0, 0.0, 1.0)
    assert buttons.gripper is None
    k.press("g", 0.2)
    k.press("v", 0.2)  # half speed
    k.press("w", 0.2)
    axes, buttons = k.sample(0.25)[:2]
    assert buttons.gripper is True and axes == (0.5, 0.0, 0.0)
    assert len(k.sample(1.0)) == 2  # the turn key let go: no rotation in the message


def test_a_can_frame_carries_rotation_and_the_hand_buttons() -> None:
    spec = CanSpec(rotation_offsets=(8, 10, 12), rotation_invert=(False, False, True))
    data = encode_frame(spec, (0.5, 0.0, 0.0), Buttons(confirm=True), (0.0, 0.25, 0.5),
                        gripper_down=True)  # fmt: skip
    axes, buttons, turn = decode_frame(spec, spec.arbitration_id, data)  # type: ignore[misc]
    assert axes == pytest.approx((0.5, 0.0, 0.0), abs=1e-4)
    assert turn == pytest.approx((0.0, 0.25, 0.5), abs=1e-4)
    assert buttons.confirm and hand_bits(spec, data) == (True, False)
    with pytest.raises(InputError, match="overlaps"):
        decode_frame(CanSpec(rotation_offsets=(0, 10, 12)), 0x100, data)


def test_an_xbox_pad_turns_with_its_right_stick_and_grips_with_y() -> None:
    state = DeviceState(XBOX, PAD_RANGES)

    def frame(now: float, *changes: tuple[int, int, int]) -> None:
        state.feed_all([*(event(t, c, v) for t, c, v in changes), syn()], now)

    frame(0.0, (EV_KEY, ecodes.BTN_TL, 1), (EV_ABS, ecodes.ABS_RX, -32768))  # right stick left
    axes, buttons, turn = state.sample(0.0)  # type: ignore[misc]
    assert turn == pytest.approx((0.0, 0.0, 1.0), abs=1e-4) and buttons.gripper is None
    frame(0.1, (EV_KEY, ecodes.BTN_NORTH, 1))
    assert state.sample(0.1)[1].gripper is True
    frame(0.2, (EV_KEY, ecodes.BTN_NORTH, 0), (EV_KEY, ecodes.BTN_WEST, 1))
    frame(0.2, (EV_ABS, ecodes.ABS_Y, -32768))  # stick fully up, at half speed
    axes, buttons, turn = state.sample(0.2)  # type: ignore[misc]
    assert buttons.gripper is True  # the toggle holds
    assert np.allclose(axes, (0.5, 0.0, 0.0), atol=1e-4)
    assert np.allclose(turn, (0.0, 0.0, 0.5), atol=1e-4)
    frame(0.3, (EV_KEY, ecodes.BTN_TL, 0))  # enable released: no input, nothing toggles
    frame(0.3, (EV_KEY, ecodes.BTN_WEST, 0), (EV_KEY, ecodes.BTN_NORTH, 1))
    assert state.sample(0.3)[1].enable is False
