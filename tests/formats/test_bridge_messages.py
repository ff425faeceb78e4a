"""Bridge messages: valid ones round-trip, every malformed payload is one InputError."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.arms import arm
from legws_daemon.errors import InputError
from legws_daemon.formats.bridge_messages import (
    BridgeCommand,
    BridgeState,
    bridge_contract,
    bridge_keys,
)
from legws_daemon.formats.messages import dump
from legws_daemon.robot.world import World
from legws_daemon.scene.scene import Scene

ARM_JOINTS = arm("sawyer").joint_names
MODEL_SPEED_LIMITS = arm("sawyer").speed_limits
SAWYER_BRIDGE = bridge_contract("sawyer")  # the Sawyer's side of the contract
parse_state, parse_command = SAWYER_BRIDGE.parse_state, SAWYER_BRIDGE.parse_command
JOINT_NAMES = SAWYER_BRIDGE.arm.hardware_joints
JOINT_SPEED_LIMITS = SAWYER_BRIDGE.arm.speed_limits
JOINT_LOWER, JOINT_UPPER = SAWYER_BRIDGE.arm.lower, SAWYER_BRIDGE.arm.upper

STATE = {
    "schema": 1,
    "seq": 3,
    "stamp": 1732612345.25,
    "q": [0.0, -1.2, 0.1, 1.7, 0.0, 1.1, -0.2],
    "dq": [0.0] * 7,
    "gripper": "open",
    "enabled": True,
    "estop": False,
}
COMMAND = {
    "schema": 1,
    "seq": 9,
    "stamp": 12.5,
    "mode": "joint_velocity",
    "dq": [0.1, -0.2, 0.0, 0.3, 0.0, 0.0, 0.5],
    "ttl": 0.1,
    "gripper": None,
}


def test_contract_constants_match_the_kinematic_model(desk: Scene) -> None:
    assert JOINT_NAMES == ARM_JOINTS
    np.testing.assert_array_equal(JOINT_SPEED_LIMITS, MODEL_SPEED_LIMITS)
    world = World(desk, visual=False)
    np.testing.assert_allclose(JOINT_LOWER, world.arm.lower)
    np.testing.assert_allclose(JOINT_UPPER, world.arm.upper)
    assert bridge_keys("sawyer") == {
        "state": "legws/sawyer/bridge/state",
        "command": "legws/sawyer/bridge/command",
        "resume": "legws/sawyer/bridge/resume",
        "stop": "legws/sawyer/stop/*",
    }


@pytest.mark.parametrize("name", ["sawyer", "panda", "ur5e", "kinova3"])
def test_each_arms_contract_has_its_joints_and_limits(name: str) -> None:
    """Joint vectors of the arm's DoF, each speed against that joint's limit, errors naming
    the arm's joints; one contract per arm, by name or description."""
    spec = arm(name)
    contract = bridge_contract(name)
    assert contract is bridge_contract(spec) and contract.arm is spec
    n = spec.dof
    state = contract.parse_state(json.dumps({**STATE, "q": [0.1] * n, "dq": [0.0] * n}), "s")
    assert len(state.q) == n and isinstance(state, BridgeState)
    for wrong in (n - 1, n + 1):
        with pytest.raises(InputError, match=rf"s: q: expected {n} joints \("):
            contract.parse_state(json.dumps({**STATE, "q": [0.1] * wrong, "dq": [0.0] * n}), "s")
    at = list(spec.speed_limits)
    assert contract.parse_command(json.dumps({**COMMAND, "dq": at}), "c").dq == tuple(at)
    over = [0.0] * n
    over[-1] = spec.speed_limits[-1] + 0.01
    with pytest.raises(InputError, match=rf"c: dq\[{n - 1}\]: {spec.hardware_joints[-1]} speed"):
        contract.parse_command(json.dumps({**COMMAND, "dq": over}), "c")


def test_a_message_without_an_arm_is_refused() -> None:
    """The base types are annotations: validated without an arm they refuse, so no message
    is ever believed with another arm's joint count or limits."""
    with pytest.raises(ValueError, match="validated for an arm"):
        BridgeState.model_validate(STATE)
    with pytest.raises(ValueError, match="validated for an arm"):
        BridgeCommand.model_validate(COMMAND)


def test_round_trips() -> None:
    state = parse_state(json.dumps(STATE), "state")
    assert state.q[1] == -1.2
    assert state.gripper == "open"
    assert parse_state(dump(state), "state") == state
    command = parse_command(json.dumps(COMMAND), "command")
    assert command.dq[6] == 0.5
    assert command.gripper is None
    assert parse_command(dump(command), "command") == command
    assert json.loads(dump(command))["schema"] == 1


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"q": [0.0] * 6}, "q"),
        ({"q": [0.0] * 6 + ["1"]}, "q[6]"),
        ({"q": [0.0] * 6 + [7.0]}, "q[6]"),
        ({"dq": [0.0, 11.0, 0, 0, 0, 0, 0]}, "dq[1]"),
        ({"gripper": "half"}, "gripper"),
        ({"enabled": 1}, "enabled"),
        ({"estop": None}, "estop"),
        ({"seq": -1}, "seq"),
        ({"stamp": "now"}, "stamp"),
        ({"schema": 2}, "schema"),
        ({"torque": [0.0] * 7}, "torque"),
    ],
)
def test_bad_states_name_the_field(change: dict[str, object], field: str) -> None:
    with pytest.raises(InputError) as info:
        parse_state(json.dumps({**STATE, **change}), "legws/r/bridge/state")
    assert f"legws/r/bridge/state: {field}" in str(info.value)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"mode": "ee_velocity"}, "mode"),
        ({"dq": [0.0] * 8}, "dq"),
        ({"dq": [1.75, 0, 0, 0, 0, 0, 0]}, "dq[0]"),  # over right_j0's 1.74 rad/s
        ({"dq": [0, 0, 0, 0, 0, 0, -4.6]}, "dq[6]"),
        ({"ttl": 0.0}, "ttl"),
        ({"ttl": 1.5}, "ttl"),
        ({"gripper": "moving"}, "gripper"),
        ({"seq": 1.5}, "seq"),
        ({"speed": 1}, "speed"),
    ],
)
def test_bad_commands_name_the_field(change: dict[str, object], field: str) -> None:
    with pytest.raises(InputError) as info:
        parse_command(json.dumps({**COMMAND, **change}), "legws/r/bridge/command")
    assert f"legws/r/bridge/command: {field}" in str(info.value)


def test_non_finite_values_are_rejected() -> None:
    for key, bad in (("q", "q[2]"), ("dq", "dq[2]")):
        doc = {**STATE, key: [0.0, 0.0, math.nan, 0.0, 0.0, 0.0, 0.0]}
        with pytest.raises(InputError, match=re.escape(bad)):
            parse_state(json.dumps(doc), "state")  # a NaN literal
    doc = {**COMMAND, "dq": [0.0, 0.0, math.inf, 0.0, 0.0, 0.0, 0.0]}
    with pytest.raises(InputError, match=re.escape("dq[2]")):
        parse_command(json.dumps(doc), "command")


def test_speed_limits_are_exact_up_to_floating_point_slack() -> None:
    at_limit = {**COMMAND, "dq": list(JOINT_SPEED_LIMITS)}
    assert parse_command(json.dumps(at_limit), "command").dq == tuple(JOINT_SPEED_LIMITS)
    reverse = {**COMMAND, "dq": [-v for v in JOINT_SPEED_LIMITS]}
    assert parse_command(json.dumps(reverse), "command").dq[0] == -1.74


_JSON_SCALARS = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6)


@settings(max_examples=2000, deadline=None)
@given(st.binary(max_size=300) | st.text(max_size=300))
def test_arbitrary_payloads_are_input_errors(payload: bytes | str) -> None:
    for parser in (parse_state, parse_command):
        message = ""
        try:
            parser(payload, "fuzz")
        except InputError as err:  # the only error a payload may cause
            message = str(err)
        assert "\n" not in message


@settings(max_examples=1500, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from([*STATE, *COMMAND, "x"]),
        _JSON_SCALARS | st.lists(_JSON_SCALARS, max_size=8),
    ),
    st.booleans(),
)
def test_arbitrary_json_objects_are_input_errors(doc: dict[str, object], based: bool) -> None:
    for base, parser in ((STATE, parse_state), (COMMAND, parse_command)):
        text = json.dumps({**base, **doc} if based else doc)
        message = ""
        msg: BridgeState | BridgeCommand | None = None
        try:
            msg = parser(text, "fuzz")
        except InputError as err:  # the only error a document may cause
            message = str(err)
        assert "\n" not in message
        if msg is not None:  # anything accepted is within the contract
            assert all(math.isfinite(v) for v in msg.dq)
        if isinstance(msg, BridgeCommand):
            limits = JOINT_SPEED_LIMITS
            assert all(abs(v) <= lim + 1e-6 for v, lim in zip(msg.dq, limits, strict=True))
