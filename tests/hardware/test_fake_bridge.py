"""The fake bridge keeps the robot side of the contract: deadman, limits, faults, state.

Two zenoh peers on loopback (scouting off, always closed); commands are published raw, as
the daemon would, and states are read back through the legws validator. Time is a clock
the test holds (no sleeps, no wall-clock rates): the fake runs without its thread, the test
advances the clock to move the arm and calls ``tick()`` to publish a state; only the
arrival of messages is waited for. One test runs the real thread (the transport).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import zenoh

from legws_daemon.arms import arm
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.bridge_messages import bridge_keys, stop_key
from legws_daemon.formats.profile import ProfileSpec, WorkspaceBox
from legws_daemon.hardware.fake_bridge import GRIPPER_TIME, FakeBridge
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from tests.hardware.helpers import StateLog, peers, wait_for

KEYS = bridge_keys("sawyer")


class Clock:
    """A monotonic clock the test sets."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def desk() -> Scene:
    return load_scene("desk")


def command(dq: list[float], ttl: float, seq: int = 0, gripper: str | None = None) -> bytes:
    doc: dict[str, Any] = {
        "schema": 1,
        "seq": seq,
        "stamp": time.time(),
        "mode": "joint_velocity",
        "dq": dq,
        "ttl": ttl,
        "gripper": gripper,
    }
    return json.dumps(doc).encode()  # NaN and Infinity are written as literals


def joint0(speed: float) -> list[float]:
    return [speed, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


@contextmanager
def manual(desk: Scene, **kw: Any) -> Iterator[tuple[zenoh.Session, FakeBridge, Clock, StateLog]]:
    """Two loopback peers and a fake on a held clock (no thread), connected: the daemon
    side hears its state and it hears the daemon's commands."""
    clock = Clock()
    with peers() as (daemon, robot):
        fake = FakeBridge(robot, "sawyer", desk, clock=clock, **kw)
        fake.start(thread=False)
        try:
            log = StateLog(daemon)
            assert wait_for(lambda: fake.tick() and log.count() > 0), "no state from the fake"

            sent = 0

            def first_command_arrives() -> bool:
                nonlocal sent
                daemon.put(KEYS["command"], command([0.0] * 7, 0.05))
                sent += 1
                return wait_for(lambda: fake.received > 0, 0.1)

            assert wait_for(first_command_arrives), "the fake bridge receives no command"
            # every retry arrived too: a late zero command would replace a test's own (it
            # did once in CI, under load: the arm never moved)
            assert wait_for(lambda: fake.received >= sent), (fake.received, sent)
            clock.now += 1.0  # the bucket full again, the zero commands expired
            yield daemon, fake, clock, log
        finally:
            fake.close()


def send(daemon: zenoh.Session, fake: FakeBridge, payload: bytes, key: str = "command") -> None:
    """Publish on the fake's ``key`` and wait until it has taken the message."""
    before = fake.received + fake.rejected + fake.stops + fake.resumes + fake.rejected_resumes
    daemon.put(KEYS.get(key, key), payload)
    assert wait_for(
        lambda: (
            fake.received + fake.rejected + fake.stops + fake.resumes + fake.rejected_resumes
            > before
        )
    ), "the message did not arrive"


def settled(log: StateLog, quiet: float = 0.2, timeout: float = 5.0) -> int:
    """How many states the log holds once none has arrived for ``quiet`` s."""
    deadline = time.monotonic() + timeout
    n = log.count()
    while time.monotonic() < deadline:
        time.sleep(quiet)
        now = log.count()
        if now == n:
            return n
        n = now
    raise AssertionError("the bridge's states never stopped arriving")


def published(fake: FakeBridge, log: StateLog) -> None:
    """Publish one state and wait for it."""
    n = log.count()
    assert fake.tick()
    assert wait_for(lambda: log.count() > n)


def test_starts_at_the_scene_home_and_validates_its_options(desk: Scene) -> None:
    with peers() as (_, robot):
        fake = FakeBridge(robot, "sawyer", desk)
        world = World(desk, visual=False)
        world.set_q(fake.q)
        np.testing.assert_allclose(world.ee_position(), desk.home.position, atol=1e-3)
        assert fake.gripper == "open"
        with pytest.raises(InputError, match="q0"):
            FakeBridge(robot, "sawyer", desk, q0=[0.0] * 6)
        with pytest.raises(InputError, match="q0"):
            FakeBridge(robot, "sawyer", desk, q0=[9.0] + [0.0] * 6)
        with pytest.raises(InputError, match="rate_hz"):
            FakeBridge(robot, "sawyer", desk, rate_hz=0.0)


def test_the_thread_publishes_its_state_over_zenoh(desk: Scene) -> None:
    """The real thread on the wall clock (the transport; no rate is asserted): states
    arrive, valid and in order, and stop with close()."""
    with peers() as (daemon, robot):
        fake = FakeBridge(robot, "sawyer", desk)
        with fake:
            log = StateLog(daemon)
            assert wait_for(lambda: log.count() > 3)
        assert fake.tick() is False  # closed: nothing more is published
        fake.close()  # idempotent
        assert not robot.is_closed()  # the caller owns the session
    seqs = [s.seq for s in log.states]
    assert seqs == sorted(seqs)
    assert log.errors == []


def test_integrates_a_command_until_its_ttl(desk: Scene) -> None:
    with manual(desk) as (daemon, fake, clock, log):
        q0 = fake.q
        # 0.3 rad/s: the endpoint (0.55 m out) moves 0.17 m/s, under the bridge's 0.2 m/s
        send(daemon, fake, command(joint0(0.3), ttl=0.2, seq=1))
        clock.now += 0.35  # past the ttl: the deadman has stopped the joint
        q1 = fake.q
        assert q1[0] - q0[0] == pytest.approx(0.3 * 0.2, abs=1e-9)
        assert fake.limited == dict.fromkeys(fake.limited, 0)  # nothing was over a limit
        np.testing.assert_allclose(q1[1:], q0[1:], atol=1e-12)
        clock.now += 0.1
        np.testing.assert_array_equal(fake.q, q1)  # no motion without a fresh command
        published(fake, log)
        np.testing.assert_allclose(log.last().q, q1, atol=1e-12)
        assert log.errors == []
        assert fake.rejected == 0


def test_invalid_commands_are_rejected_and_stop_the_arm(desk: Scene) -> None:
    with manual(desk) as (daemon, fake, clock, _):
        bad_commands = [joint0(math.nan), joint0(2.0), [0.0] * 6 + [math.inf]]
        # NaN, over right_j0's limit (1.74 rad/s), infinite
        for n, bad in enumerate(bad_commands, start=1):
            start = float(fake.q[0])
            send(daemon, fake, command(joint0(0.3), ttl=1.0))
            clock.now += 0.05
            assert fake.q[0] == pytest.approx(start + 0.015)
            send(daemon, fake, command(bad, ttl=1.0))
            assert fake.rejected == n
            q_stopped = fake.q
            clock.now += 0.1
            np.testing.assert_array_equal(fake.q, q_stopped)
        send(daemon, fake, b"{not json")
        assert fake.rejected == 4
        assert fake.last_rejection is not None
        assert "legws/sawyer/bridge/command" in fake.last_rejection


def test_joint_position_limits_clip(desk: Scene) -> None:
    upper = arm("sawyer").upper[0]
    q0 = [upper - 0.01, -1.0, 0.0, 1.5, 0.0, 1.0, 0.0]
    with manual(desk, q0=q0) as (daemon, fake, clock, _):
        send(daemon, fake, command(joint0(1.0), ttl=0.3))
        clock.now += 0.5
        assert fake.q[0] == upper  # 0.3 rad commanded, stopped at the limit


def test_estop_and_disable_hold_the_arm(desk: Scene) -> None:
    with manual(desk) as (daemon, fake, clock, log):
        fake.set_estop(True)
        published(fake, log)
        assert log.last().estop and not log.last().enabled
        q0 = fake.q
        send(daemon, fake, command(joint0(0.5), ttl=0.5))
        clock.now += 0.2
        np.testing.assert_array_equal(fake.q, q0)
        with pytest.raises(LegwsError, match="emergency stop"):
            fake.set_enabled(True)
        fake.set_estop(False)
        published(fake, log)
        assert not log.last().estop
        assert not log.last().enabled  # releasing the e-stop does not re-enable
        fake.set_enabled(True)
        send(daemon, fake, command(joint0(0.5), ttl=0.2))
        clock.now += 0.2
        assert fake.q[0] > q0[0] + 0.05


def test_heartbeat_can_be_stopped_and_resumed(desk: Scene) -> None:
    """One state per tick: at the fake's 200 Hz, 100 ticks are 0.5 s of its clock; none
    while the heartbeat is stopped."""
    with manual(desk) as (_, fake, clock, log):
        n0 = settled(log)  # the set-up's states all heard (one may still be on its way)
        for _ in range(100):
            clock.now += fake.period
            assert fake.tick()
        assert wait_for(lambda: log.count() >= n0 + 100)
        assert settled(log) == n0 + 100
        ticks = [s.seq for s in log.states[n0:]]
        assert ticks == list(range(ticks[0], ticks[0] + 100))
        fake.stop_publishing()
        for _ in range(20):
            clock.now += fake.period
            fake.tick()
        fake.resume_publishing()
        published(fake, log)
        assert log.count() == n0 + 101  # the one after the resume, none before it
        seqs = [s.seq for s in log.states]
        assert seqs == sorted(seqs)
        assert log.errors == []


def test_gripper_moves_then_reports_the_request(desk: Scene) -> None:
    with manual(desk) as (daemon, fake, clock, log):
        send(daemon, fake, command([0.0] * 7, ttl=0.1, gripper="closed"))
        assert fake.gripper == "moving"
        clock.now += GRIPPER_TIME
        published(fake, log)
        assert log.last().gripper == "closed"
        send(daemon, fake, command([0.0] * 7, ttl=0.1, gripper=None))
        assert fake.gripper == "closed"  # null: no request, no change


# --- the bridge's own limits, stops and resumes --------------------------------------
def test_defaults_are_the_profile_defaults(desk: Scene) -> None:
    with peers() as (_, robot):
        fake = FakeBridge(robot, "sawyer", desk)
        assert fake.limits == ProfileSpec.model_fields["bridge"].default
        assert fake.workspace == ProfileSpec.model_fields["workspace"].default
        assert fake.stop_key == "legws/sawyer/stop/*"
        assert fake.resume_key == "legws/sawyer/bridge/resume"
        assert fake.stopped_by is None
        assert fake.limited == dict.fromkeys(fake.limited, 0)


def test_a_hostile_command_is_held_to_the_limits_and_reported(desk: Scene) -> None:
    """right_j0 at 1.5 rad/s for 1 s: capped to 0.8 rad/s, and then to the endpoint's
    0.2 m/s (0.55 m from the axis: ~0.36 rad/s), for max_ttl 0.2 s, not 1 s."""
    with manual(desk) as (daemon, fake, clock, log):
        q0 = fake.q
        world = World(desk, visual=False)
        world.set_q(q0)
        p0 = world.ee_position()
        send(daemon, fake, command(joint0(1.5), ttl=1.0, seq=1))
        clock.now += 0.4
        q1 = fake.q
        world.set_q(q1)
        travelled = 0.2 * 0.2  # the endpoint at 0.2 m/s for 0.2 s, along an arc
        radius = float(np.hypot(*p0[:2]))
        assert q1[0] - q0[0] == pytest.approx(travelled / radius, rel=0.02)
        np.testing.assert_allclose(q1[1:], q0[1:], atol=1e-12)
        assert np.linalg.norm(world.ee_position() - p0) <= travelled
        counts = fake.limited
        assert counts["joint_speed"] == 1 and counts["ttl"] == 1 and counts["ee_speed"] >= 40
        published(fake, log)
        assert log.limited() == {"joint_speed", "ee_speed", "ttl"}
        assert log.errors == []


def test_any_stop_latches_until_a_valid_resume(desk: Scene) -> None:
    resume = json.dumps({"schema": 1, "seq": 0, "stamp": 1.0}).encode()
    with manual(desk) as (daemon, fake, clock, log):
        start = float(fake.q[0])
        send(daemon, fake, command(joint0(0.3), ttl=0.2))
        clock.now += 0.05
        assert fake.q[0] > start
        send(daemon, fake, b"{not json", stop_key("sawyer", "operator"))  # stops all the same
        assert fake.stopped_by == "operator"
        published(fake, log)
        assert log.last().stopped_by == "operator"
        held = fake.q
        send(daemon, fake, command(joint0(0.3), ttl=0.2, gripper="closed"))
        send(daemon, fake, b"", stop_key("sawyer", "safety"))
        send(daemon, fake, b'{"schema": 1, "seq": 0}', "resume")  # no stamp: not a resume
        clock.now += 0.2
        np.testing.assert_array_equal(fake.q, held)
        assert fake.gripper == "open"  # the ignored command did not move the gripper either
        assert (fake.stops, fake.invalid_stops, fake.rejected_resumes) == (2, 1, 1)
        assert fake.stopped_by == "operator"  # the first stop's role
        send(daemon, fake, resume, "resume")
        assert fake.stopped_by is None
        published(fake, log)
        assert log.last().stopped_by is None
        clock.now += 0.05
        np.testing.assert_array_equal(fake.q, held)  # no command comes back
        send(daemon, fake, command(joint0(0.3), ttl=0.2))
        clock.now += 0.05
        assert fake.q[0] > held[0]
        send(daemon, fake, b"", "legws/sawyer/stop/somebody")  # not a known role: stops too
        published(fake, log)
        assert log.last().stopped_by == "unknown"
        assert fake.resumes == 1
        assert log.errors == []


def test_a_workspace_step_out_stops_the_arm(desk: Scene) -> None:
    """A box whose face is 5 mm (+ the 2 cm margin) beyond the endpoint in x: pushed out,
    the arm stops inside; pulled back, it moves."""
    with peers() as (_, robot):
        q0 = FakeBridge(robot, "sawyer", desk).q
    world = World(desk, visual=False)
    world.set_q(q0)
    p0 = world.ee_position()
    box = WorkspaceBox(x=(0.2, float(p0[0]) + 0.005), y=(-0.55, 0.55), z=(0.0, 0.6))
    out = list(np.linalg.pinv(world.jacobian()[:3]) @ np.array([0.1, 0.0, 0.0]))
    with manual(desk, workspace=box) as (daemon, fake, clock, log):
        for seq in range(40):  # 0.8 s at 50 Hz: 8 cm if nothing stopped it
            send(daemon, fake, command(out, ttl=0.1, seq=seq))
            clock.now += 0.02
        world.set_q(fake.q)
        x = float(world.ee_position()[0])
        assert p0[0] + 0.02 < x <= box.x[1] + 0.02  # it came to the face, not past it
        assert fake.limited["workspace"] > 0
        published(fake, log)
        assert "workspace" in log.limited()
        send(daemon, fake, command([-v for v in out], ttl=0.1, seq=99))
        clock.now += 0.15
        world.set_q(fake.q)
        assert world.ee_position()[0] < x - 0.005
