"""Wire messages: valid ones round-trip, every malformed payload is one InputError."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import (
    CommandRequest,
    EventMessage,
    JoystickMessage,
    StatusMessage,
    dump,
    parse,
)

GOOD = {"schema": 1, "seq": 7, "stamp": 12.5, "axes": [0.6, 0.0, -0.8], "source": "sim-user"}


def test_joystick_round_trip() -> None:
    msg = parse(JoystickMessage, json.dumps(GOOD), "joystick")
    assert msg.axes == (0.6, 0.0, -0.8)
    assert msg.buttons.cancel is False
    assert parse(JoystickMessage, dump(msg), "joystick") == msg


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"axes": [0.9, 0.9, 0.0]}, "axes"),  # norm > 1
        ({"axes": [1.5, 0.0, 0.0]}, "axes[0]"),
        ({"axes": ["0.1", 0.0, 0.0]}, "axes[0]"),
        ({"axes": [0.1, 0.0]}, "axes"),
        ({"seq": -1}, "seq"),
        ({"seq": 1.5}, "seq"),
        ({"stamp": None}, "stamp"),
        ({"schema": 2}, "schema"),
        ({"buttons": {"cancel": "yes"}}, "buttons.cancel"),
        ({"speed": 3}, "speed"),
    ],
)
def test_bad_joystick_messages_name_the_field(change: dict[str, object], field: str) -> None:
    with pytest.raises(InputError) as info:
        parse(JoystickMessage, json.dumps({**GOOD, **change}), "legws/r/joystick")
    assert f"legws/r/joystick: {field}" in str(info.value)


def test_nan_axes_are_rejected() -> None:
    text = json.dumps({**GOOD, "axes": [math.nan, 0.0, 0.0]})  # NaN literal
    with pytest.raises(InputError, match="axes"):
        parse(JoystickMessage, text, "joystick")


@settings(max_examples=3000, deadline=None)
@given(st.binary(max_size=300) | st.text(max_size=300))
def test_arbitrary_payloads_never_crash(payload: bytes | str) -> None:
    message = ""
    try:
        parse(JoystickMessage, payload, "fuzz")
    except InputError as err:  # the only error a payload may cause
        message = str(err)
    assert "\n" not in message


@settings(max_examples=1000, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["schema", "seq", "stamp", "axes", "buttons", "source", "x"]),
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5)
        | st.lists(st.floats(), max_size=4),
    )
)  # fmt: skip
def test_arbitrary_json_objects_never_crash(doc: dict[str, object]) -> None:
    try:
        msg = parse(JoystickMessage, json.dumps(doc), "fuzz")
    except InputError:
        return
    assert math.sqrt(sum(a * a for a in msg.axes)) <= 1.0 + 1e-6


def test_status_event_and_command() -> None:
    status = StatusMessage.model_validate({
        "schema": 1, "robot": "sawyer_sim", "seq": 1, "stamp": 0.0, "mode": "teleop",
        "posterior": {"mug": 0.7, "stapler": 0.3}, "adapter": "sim",
    })  # fmt: skip
    assert parse(StatusMessage, dump(status), "status") == status
    event = EventMessage.model_validate(
        {
            "schema": 1,
            "robot": "r",
            "seq": 2,
            "stamp": 1.0,
            "kind": "commit",
            "detail": {"goal": "mug"},
        }
    )
    assert parse(EventMessage, dump(event), "events") == event
    assert parse(CommandRequest, b'{"schema": 1, "command": "reset"}', "cmd").command == "reset"
    with pytest.raises(InputError, match="argument"):
        parse(CommandRequest, b'{"schema": 1, "command": "load_scene"}', "cmd")
    with pytest.raises(InputError, match="command"):
        parse(CommandRequest, b'{"schema": 1, "command": "explode"}', "cmd")
