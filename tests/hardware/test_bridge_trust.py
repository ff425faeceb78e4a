"""What the sawyer adapter believes of the bridge: plausible joint states only.

On a transport without authentication any peer can publish on the bridge's state key.
Authentication (``legws secure init``) keeps such peers out; the adapter also checks what
it receives: a joint faster than its specification between two states, an angle outside
the joint's range, or an EE outside the workspace box (grown by
:data:`~legws_daemon.hardware.bridge.PLAUSIBLE_MARGIN`; the bridge keeps it inside) is a
hardware fault, held until a reset (:meth:`BridgeAdapter.resume`). Real zenoh peers on
loopback, the fake bridge; the intruder is a third session.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.arms import arm
from legws_daemon.errors import HardwareError
from legws_daemon.formats.bridge_messages import bridge_keys, stop_key
from legws_daemon.formats.profile import load_profile
from legws_daemon.hardware.bridge import (
    JUMP_JITTER,
    BridgeAdapter,
    implausible_angles,
    implausible_jump,
)
from legws_daemon.hardware.fake_bridge import FakeBridge
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from tests.hardware.helpers import peers, wait_for

PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sawyer.toml"
KEYS = bridge_keys("sawyer")
SAWYER = arm("sawyer")
HOME_Q = [-0.16, -1.30, -0.19, 1.73, 0.06, 1.14, -0.19]


@pytest.fixture(scope="module")
def desk() -> Scene:
    return load_scene("desk")


@given(
    st.lists(st.floats(-1.0, 1.0), min_size=7, max_size=7),
    st.floats(0.0, 0.5),
    st.integers(0, 6),
)
def test_a_jump_is_implausible_exactly_beyond_the_speed_limit(
    direction: list[float], elapsed: float, joint: int
) -> None:
    q0 = np.array(HOME_Q)
    limit = arm("sawyer").speed_limits[joint] * (elapsed + JUMP_JITTER)
    step = np.zeros(7)
    step[joint] = 0.999 * limit * (1 if direction[joint] >= 0 else -1)
    assert implausible_jump(SAWYER, q0, q0 + step, elapsed) is None
    step[joint] *= 1.002 / 0.999
    problem = implausible_jump(SAWYER, q0, q0 + step, elapsed)
    assert problem is not None and f"right_j{joint}" in problem


def test_angles_outside_the_joint_range_are_implausible() -> None:
    assert implausible_angles(SAWYER, HOME_Q) is None
    q = list(HOME_Q)
    q[3] = 3.2  # right_j3's range ends at 3.0439
    assert "right_j3" in (implausible_angles(SAWYER, q) or "")


def _state(seq: int, q: list[float], **extra: object) -> bytes:
    msg = {"schema": 1, "seq": seq, "stamp": time.time(), "q": q, "dq": [0.0] * 7,
           "gripper": "open", "enabled": True, "estop": False, **extra}  # fmt: skip
    return json.dumps(msg).encode()


def test_an_intruders_joint_states_fault_the_adapter_until_a_reset(desk: Scene) -> None:
    """The red-team case: a foreign peer publishes other joint angles next to the bridge's
    stream. The first one makes the state implausible (a jump), the adapter refuses to use
    it — no EE from it is ever reported — and stays faulted until resume()."""
    profile = load_profile(PROFILE)
    with (
        peers() as (daemon, robot),
        FakeBridge(robot, "sawyer", desk) as fake,
        BridgeAdapter(profile, desk, daemon) as adapter,
    ):
        before = adapter.read_state()
        np.testing.assert_allclose(before.q, fake.q, atol=1e-9)
        shifted = np.array(fake.q)
        shifted[6] += 0.6
        robot.put(KEYS["state"], _state(10**6, shifted.tolist()))
        assert wait_for(lambda: adapter.implausible is not None, 2.0)
        with pytest.raises(HardwareError, match=r"implausible joint state.*right_j6 moved"):
            adapter.read_state()
        time.sleep(0.1)  # the bridge's own states go on: still not believed
        with pytest.raises(HardwareError, match="implausible"):
            adapter.read_state()
        adapter.resume()  # the operator's reset believes the bridge again
        np.testing.assert_allclose(adapter.read_state().q, fake.q, atol=1e-3)


def test_an_ee_outside_the_workspace_is_implausible(desk: Scene) -> None:
    """Angles that move smoothly (no jump) to an EE far outside the box: the bridge keeps
    the arm inside, so this is not the arm. The intruder replaces the bridge here."""
    profile = load_profile(PROFILE)
    box_y = profile.workspace.y[1]
    with peers() as (daemon, robot):
        stop = threading.Event()
        q = np.array(HOME_Q)

        def stream() -> None:
            seq = 0
            while not stop.wait(0.005):
                robot.put(KEYS["state"], _state(seq, q.tolist()))
                seq += 1

        thread = threading.Thread(target=stream)
        thread.start()
        try:
            with BridgeAdapter(profile, desk, daemon) as adapter:
                assert adapter.read_state().ee_position[1] < box_y
                problem = None
                for _ in range(400):  # the base joint turns slowly: +y, out of the box
                    q[0] += 0.004
                    time.sleep(0.005)
                    try:
                        state = adapter.read_state()
                    except HardwareError as err:
                        problem = str(err)
                        break
                    assert state.ee_position[1] <= box_y + 0.05 + 1e-9
                assert problem is not None, "the EE left the box and was still believed"
                assert "outside the workspace box" in problem
        finally:
            stop.set()
            thread.join(timeout=5.0)


def test_a_stop_is_held_by_the_bridge_until_resume(desk: Scene) -> None:
    """Any peer's stop on its stop key: the bridge holds it (its state names the role),
    the adapter reports it in the state, and resume() clears it."""
    profile = load_profile(PROFILE)
    with (
        peers() as (daemon, robot),
        FakeBridge(robot, "sawyer", desk),
        BridgeAdapter(profile, desk, daemon) as adapter,
    ):
        assert adapter.read_state().stopped_by is None
        robot.put(stop_key("sawyer", "safety"), b"")
        assert wait_for(lambda: adapter.read_state().stopped_by == "safety", 2.0)
        adapter.resume()
        assert adapter.read_state().stopped_by is None
        adapter.stop_by("operator")  # the daemon's own stop goes out on its key
        assert wait_for(lambda: adapter.read_state().stopped_by == "daemon", 2.0)
        adapter.resume()
        assert adapter.read_state().stopped_by is None
