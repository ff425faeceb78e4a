"""The sawyer adapter against the fake bridge, over two zenoh peers on loopback.

Sessions: explicit loopback endpoints, multicast scouting off, always closed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import zenoh

from legws_daemon.errors import BridgeTimeoutError, HardwareError, InputError, LegwsError
from legws_daemon.formats.bridge_messages import BridgeCommand, bridge_contract, bridge_keys
from legws_daemon.formats.profile import ProfileSpec, load_profile
from legws_daemon.hardware.base import Adapter, adapter_class
from legws_daemon.hardware.bridge import STOP_REPEATS, BridgeAdapter
from legws_daemon.hardware.fake_bridge import FakeBridge
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from tests.hardware.helpers import Held, peers, ticking, wait_for

PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sawyer.toml"
KEYS = bridge_keys("sawyer")


@pytest.fixture(scope="module")
def desk() -> Scene:
    return load_scene("desk")


def sawyer_profile(**sawyer: object) -> ProfileSpec:
    """The shipped profile with some ``[sawyer]`` settings changed."""
    profile = load_profile(PROFILE)
    return profile.model_copy(update={"link": profile.link.model_copy(update=sawyer)})


class CommandLog:
    """Every command the robot side receives, validated."""

    def __init__(self, session: zenoh.Session) -> None:
        self.commands: list[BridgeCommand] = []
        self._lock = threading.Lock()
        self.subscriber = session.declare_subscriber(KEYS["command"], self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        command = bridge_contract("sawyer").parse_command(
            sample.payload.to_bytes(), KEYS["command"]
        )
        with self._lock:
            self.commands.append(command)

    def snapshot(self) -> list[BridgeCommand]:
        with self._lock:
            return list(self.commands)


def test_registered_and_needs_a_session(desk: Scene) -> None:
    assert adapter_class("sawyer") is adapter_class("bridge") is BridgeAdapter
    profile = sawyer_profile()
    with pytest.raises(LegwsError, match="zenoh session"):
        BridgeAdapter(profile, desk, None)
    with peers() as (daemon, _):
        with pytest.raises(InputError, match=r"link\.command"):
            BridgeAdapter(sawyer_profile(command="ee_velocity"), desk, daemon)
        adapter = BridgeAdapter(profile, desk, daemon)
        with pytest.raises(LegwsError, match="not connected"):
            adapter.read_state()


def test_round_trip_with_the_fake_bridge(desk: Scene) -> None:
    """The adapter through the fake bridge, whose motion runs on a held clock (its state
    keeps coming in real time): the measured state is the fake's, zero commands are exact
    zeros, and 20 ticks of +x move the EE by the commanded speed times the clock's 20 ticks."""
    profile = sawyer_profile()
    clock = Held()
    with (
        peers() as (daemon, robot),
        FakeBridge(robot, "sawyer", desk, clock=clock) as fake,
        ticking(fake),
    ):
        log = CommandLog(robot)
        adapter = BridgeAdapter(profile, desk, daemon)
        adapter.connect()
        # the state is the fake's q, and the EE pose its forward kinematics
        s0 = adapter.read_state()
        np.testing.assert_allclose(s0.q, fake.q, atol=1e-12)  # nothing moves yet
        world = World(desk, visual=False)
        world.set_q(s0.q)
        np.testing.assert_allclose(s0.ee_position, world.ee_position(), atol=1e-12)
        np.testing.assert_allclose(s0.ee_position, desk.home.position, atol=1e-3)
        assert abs(time.monotonic() - s0.stamp) < profile.link.heartbeat_timeout
        assert not s0.gripper_closed

        # a zero command sends dq = 0 exactly and leaves q unchanged
        for _ in range(5):
            np.testing.assert_array_equal(adapter.stop(), 0.0)
            clock.now += adapter.dt
        assert wait_for(lambda: len(log.snapshot()) >= 5 and fake.received >= 5)
        np.testing.assert_array_equal(fake.q, s0.q)
        # (they may all have arrived at one instant of the clock: the rate's burst is spent
        # until it moves on)
        clock.now += 0.2
        assert all(c.dq == (0.0,) * 7 for c in log.snapshot())
        assert log.snapshot()[0].ttl == pytest.approx(2 * adapter.dt)

        # 20 ticks of +x, each received by the bridge before its period passes on the
        # clock: the EE moves 0.03 m/s times 20 periods
        for k in range(20):
            received = fake.received
            sent = adapter.send_velocity(adapter.read_state(), [0.03, 0.0, 0.0])
            np.testing.assert_allclose(sent, [0.03, 0.0, 0.0])
            assert wait_for(lambda n=received: fake.received > n)
            before = fake.q
            clock.now += adapter.dt
            # the period integrated by the bridge, then its new state heard by the adapter
            assert wait_for(lambda q=before: not np.array_equal(fake.q, q)), (k, fake.limited)
            moved = fake.q
            assert wait_for(lambda q=moved: np.array_equal(adapter.read_state().q, q))
        received = fake.received
        adapter.stop()
        assert wait_for(lambda: fake.received > received)
        clock.now += adapter.dt
        assert wait_for(lambda: np.array_equal(adapter.read_state().q, fake.q))
        s1 = adapter.read_state()
        shift = s1.ee_position - s0.ee_position
        assert shift[0] == pytest.approx(0.03 * 20 * adapter.dt, abs=1e-3)
        np.testing.assert_allclose(shift[1:], 0.0, atol=1e-3)
        assert fake.rejected == 0

        # the gripper: the request reaches the bridge, its state comes back
        adapter.grip(True)
        assert wait_for(lambda: fake.gripper == "moving")
        clock.now += 0.25  # the fake hand's 0.2 s
        assert wait_for(lambda: adapter.read_state().gripper_closed)
        assert fake.gripper == "closed"
        n = len(log.snapshot())
        adapter.stop()  # every later command carries the request
        assert wait_for(lambda: len(log.snapshot()) > n)
        assert log.snapshot()[n].gripper == "closed"
        adapter.grip(False)
        assert wait_for(lambda: fake.gripper == "moving")
        clock.now += 0.25
        assert wait_for(lambda: fake.gripper == "open")
        # (the fake's next state message brings it: not the instant the fake opened)
        assert wait_for(lambda: not adapter.read_state().gripper_closed)

        # disconnect: a few zero commands, then silence; the daemon's session stays open
        sent_before = len(log.snapshot())
        adapter.disconnect()
        assert wait_for(lambda: len(log.snapshot()) >= sent_before + STOP_REPEATS)
        assert all(c.dq == (0.0,) * 7 for c in log.snapshot()[sent_before:])
        adapter.disconnect()  # idempotent: nothing more is sent
        time.sleep(0.1)
        assert len(log.snapshot()) == sent_before + STOP_REPEATS
        assert not daemon.is_closed()
        seqs = [c.seq for c in log.snapshot()]
        assert seqs == sorted(seqs)
        assert adapter.rejected == 0


def test_no_bridge_times_out(desk: Scene) -> None:
    profile = sawyer_profile(bridge_timeout=0.4)
    with peers() as (daemon, _):
        adapter = BridgeAdapter(profile, desk, daemon)
        start = time.monotonic()
        with pytest.raises(BridgeTimeoutError) as info:
            adapter.connect()
        waited = time.monotonic() - start
    # it waited the timeout out (the arm's model is built first, ~0.6 s on a quiet machine:
    # the upper bound only says it did not hang)
    assert 0.4 <= waited < 30.0
    assert "legws/sawyer/bridge/state" in str(info.value)
    assert "0.4 s" in str(info.value)
    assert not adapter.connected


def test_heartbeat_loss_and_estop_are_hardware_errors(desk: Scene) -> None:
    profile = sawyer_profile(heartbeat_timeout=0.3)
    with (
        peers() as (daemon, robot),
        FakeBridge(robot, "sawyer", desk) as fake,
        BridgeAdapter(profile, desk, daemon) as adapter,
    ):
        adapter.read_state()
        fake.stop_publishing()
        lost = time.monotonic()
        assert wait_for(faulted_with(adapter, "heartbeat"), 2.0)
        assert time.monotonic() - lost < profile.link.heartbeat_timeout + 0.2
        with pytest.raises(HardwareError, match="heartbeat"):
            adapter.send_velocity(adapter.read_state(), [0.01, 0.0, 0.0])

        fake.resume_publishing()  # recovery: fresh states are usable again
        assert wait_for(partial(healthy, adapter))

        fake.set_estop(True)
        assert wait_for(faulted_with(adapter, "emergency stop"))
        fake.set_estop(False)
        assert wait_for(faulted_with(adapter, "disabled"))
        fake.set_enabled(True)
        assert wait_for(partial(healthy, adapter))


def healthy(adapter: Adapter) -> bool:
    """``read_state`` succeeds."""
    try:
        adapter.read_state()
    except HardwareError:
        return False
    return True


def faulted_with(adapter: Adapter, needle: str) -> Callable[[], bool]:
    """A condition: ``read_state`` raises a HardwareError containing ``needle``."""

    def check() -> bool:
        try:
            adapter.read_state()
        except HardwareError as err:
            return needle in str(err)
        return False

    return check


def test_invalid_states_are_counted_and_ignored(desk: Scene) -> None:
    profile = sawyer_profile(bridge_timeout=0.5)
    bad = [b"not json", b'{"schema": 1}', b'{"schema": 2, "seq": 0}', b"[1, 2]"]
    with peers() as (daemon, robot):
        adapter = BridgeAdapter(profile, desk, daemon)
        stop = threading.Event()

        def publish_garbage() -> None:
            while not stop.wait(0.02):
                robot.put(KEYS["state"], bad[0])

        thread = threading.Thread(target=publish_garbage)
        thread.start()
        try:
            # a bridge that answers wrongly is there: never a reason to fall back to the sim
            with pytest.raises(HardwareError, match="invalid message") as info:
                adapter.connect()
            assert not isinstance(info.value, BridgeTimeoutError)
        finally:
            stop.set()
            thread.join(timeout=5.0)
        assert adapter.rejected > 0

        with FakeBridge(robot, "sawyer", desk) as fake, adapter:
            before = adapter.rejected
            for payload in bad:
                robot.put(KEYS["state"], payload)
            assert wait_for(lambda: adapter.rejected == before + len(bad))
            assert adapter.last_rejection is not None
            assert adapter.last_rejection.startswith("legws/sawyer/bridge/state: ")
            np.testing.assert_allclose(adapter.read_state().q, fake.q, atol=1e-12)
