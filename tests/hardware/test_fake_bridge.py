"""The fake bridge keeps the robot side of the contract: deadman, limits, faults, state.

Two zenoh peers on loopback (scouting off, always closed); commands are published raw, as
the daemon would, and states are read back through the legws validator.
"""

from __future__ import annotations

import json
import math
import time
from functools import partial
from typing import Any

import numpy as np
import pytest
import zenoh

from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.bridge_messages import (
    JOINT_UPPER,
    bridge_keys,
    stop_key,
)
from legws_daemon.formats.profile import ProfileSpec, WorkspaceBox
from legws_daemon.hardware.fake_bridge import GRIPPER_TIME, FakeBridge
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from tests.hardware.helpers import StateLog, peers, wait_for

KEYS = bridge_keys("sawyer")


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


def moved(fake: FakeBridge, start: float) -> bool:
    return float(fake.q[0]) > start + 1e-3


def rejected(fake: FakeBridge, n: int) -> bool:
    return fake.rejected == n


def connected(daemon: zenoh.Session, fake: FakeBridge) -> StateLog:
    """Wait until the daemon side hears the fake (the peers connect in the background)."""
    log = StateLog(daemon)
    assert wait_for(lambda: log.count() > 0), "no state from the fake bridge"

    def first_command_arrives() -> bool:
        daemon.put(KEYS["command"], command([0.0] * 7, 0.05))
        return wait_for(lambda: fake.received > 0, 0.1)

    assert wait_for(first_command_arrives), "the fake bridge receives no command"
    return log


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


def test_integrates_a_command_until_its_ttl(desk: Scene) -> None:
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk) as fake:
        log = connected(daemon, fake)
        q0 = fake.q
        # 0.3 rad/s: the endpoint (0.55 m out) moves 0.17 m/s, under the bridge's 0.2 m/s
        daemon.put(KEYS["command"], command(joint0(0.3), ttl=0.2, seq=1))
        assert wait_for(lambda: fake.received >= 2)
        time.sleep(0.35)  # past the ttl: the deadman has stopped the joint
        q1 = fake.q
        assert q1[0] - q0[0] == pytest.approx(0.3 * 0.2, abs=3e-3)
        assert fake.limited == dict.fromkeys(fake.limited, 0)  # nothing was over a limit
        np.testing.assert_allclose(q1[1:], q0[1:], atol=1e-12)
        time.sleep(0.1)
        np.testing.assert_array_equal(fake.q, q1)  # no motion without a fresh command
        assert wait_for(lambda: np.allclose(log.last().q, q1, atol=1e-12))
        assert log.errors == []
        assert fake.rejected == 0


def test_invalid_commands_are_rejected_and_stop_the_arm(desk: Scene) -> None:
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk) as fake:
        connected(daemon, fake)
        bad_commands = [joint0(math.nan), joint0(2.0), [0.0] * 6 + [math.inf]]
        # NaN, over right_j0's limit (1.74 rad/s), infinite
        for n, bad in enumerate(bad_commands, start=1):
            start = float(fake.q[0])
            daemon.put(KEYS["command"], command(joint0(0.3), ttl=1.0))
            assert wait_for(partial(moved, fake, start))
            daemon.put(KEYS["command"], command(bad, ttl=1.0))
            assert wait_for(partial(rejected, fake, n))
            q_stopped = fake.q
            time.sleep(0.1)
            np.testing.assert_array_equal(fake.q, q_stopped)
        daemon.put(KEYS["command"], b"{not json")
        assert wait_for(lambda: fake.rejected == 4)
        assert fake.last_rejection is not None
        assert "legws/sawyer/bridge/command" in fake.last_rejection


def test_joint_position_limits_clip(desk: Scene) -> None:
    upper = JOINT_UPPER[0]
    q0 = [upper - 0.01, -1.0, 0.0, 1.5, 0.0, 1.0, 0.0]
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk, q0=q0) as fake:
        connected(daemon, fake)
        daemon.put(KEYS["command"], command(joint0(1.0), ttl=0.3))
        time.sleep(0.5)
        assert fake.q[0] == upper  # 0.3 rad commanded, stopped at the limit


def test_estop_and_disable_hold_the_arm(desk: Scene) -> None:
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk) as fake:
        log = connected(daemon, fake)
        fake.set_estop(True)
        assert wait_for(lambda: log.last().estop and not log.last().enabled)
        q0 = fake.q
        daemon.put(KEYS["command"], command(joint0(0.5), ttl=0.5))
        time.sleep(0.2)
        np.testing.assert_array_equal(fake.q, q0)
        with pytest.raises(LegwsError, match="emergency stop"):
            fake.set_enabled(True)
        fake.set_estop(False)
        assert wait_for(lambda: not log.last().estop)
        assert not log.last().enabled  # releasing the e-stop does not re-enable
        fake.set_enabled(True)
        daemon.put(KEYS["command"], command(joint0(0.5), ttl=0.2))
        assert wait_for(lambda: fake.q[0] > q0[0] + 0.05)


def test_heartbeat_can_be_stopped_and_resumed(desk: Scene) -> None:
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk) as fake:
        log = connected(daemon, fake)
        t0, n0 = time.monotonic(), log.count()
        time.sleep(0.5)
        rate = (log.count() - n0) / (time.monotonic() - t0)
        assert rate > 100.0  # the contract's >= 100 Hz (nominal 200 Hz)
        fake.stop_publishing()
        time.sleep(0.05)
        n1 = log.count()
        time.sleep(0.3)
        assert log.count() == n1
        fake.resume_publishing()
        assert wait_for(lambda: log.count() > n1)
        seqs = [s.seq for s in log.states]
        assert seqs == sorted(seqs)
    assert log.errors == []


def test_gripper_moves_then_reports_the_request(desk: Scene) -> None:
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk) as fake:
        log = connected(daemon, fake)
        daemon.put(KEYS["command"], command([0.0] * 7, ttl=0.1, gripper="closed"))
        assert wait_for(lambda: fake.gripper == "moving")
        assert wait_for(lambda: log.last().gripper == "closed", GRIPPER_TIME + 1.0)
        daemon.put(KEYS["command"], command([0.0] * 7, ttl=0.1, gripper=None))
        time.sleep(0.05)
        assert fake.gripper == "closed"  # null: no request, no change


def test_close_stops_publishing(desk: Scene) -> None:
    with peers() as (daemon, robot):
        fake = FakeBridge(robot, "sawyer", desk)
        with fake:
            log = connected(daemon, fake)
        time.sleep(0.05)
        n = log.count()
        time.sleep(0.2)
        assert log.count() == n
        fake.close()  # idempotent
        assert not robot.is_closed()  # the caller owns the session


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
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk) as fake:
        log = connected(daemon, fake)
        q0 = fake.q
        world = World(desk, visual=False)
        world.set_q(q0)
        p0 = world.ee_position()
        daemon.put(KEYS["command"], command(joint0(1.5), ttl=1.0, seq=1))
        time.sleep(0.4)
        q1 = fake.q
        world.set_q(q1)
        travelled = 0.2 * 0.2  # the endpoint at 0.2 m/s for 0.2 s, along an arc
        radius = float(np.hypot(*p0[:2]))
        assert q1[0] - q0[0] == pytest.approx(travelled / radius, rel=0.02)
        np.testing.assert_allclose(q1[1:], q0[1:], atol=1e-12)
        assert np.linalg.norm(world.ee_position() - p0) <= travelled
        counts = fake.limited
        assert counts["joint_speed"] == 1 and counts["ttl"] == 1 and counts["ee_speed"] > 30
        assert wait_for(lambda: log.limited() == {"joint_speed", "ee_speed", "ttl"})
        assert log.errors == []


def test_any_stop_latches_until_a_valid_resume(desk: Scene) -> None:
    resume = json.dumps({"schema": 1, "seq": 0, "stamp": 1.0}).encode()
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk) as fake:
        log = connected(daemon, fake)
        start = float(fake.q[0])
        daemon.put(KEYS["command"], command(joint0(0.3), ttl=0.2))
        assert wait_for(partial(moved, fake, start))
        daemon.put(stop_key("sawyer", "operator"), b"{not json")  # stops all the same
        assert wait_for(lambda: fake.stopped_by == "operator")
        assert wait_for(lambda: log.last().stopped_by == "operator")
        held = fake.q
        daemon.put(KEYS["command"], command(joint0(0.3), ttl=0.2, gripper="closed"))
        daemon.put(stop_key("sawyer", "safety"), b"")
        daemon.put(KEYS["resume"], b'{"schema": 1, "seq": 0}')  # no stamp: not a resume
        time.sleep(0.2)
        np.testing.assert_array_equal(fake.q, held)
        assert fake.gripper == "open"  # the ignored command did not move the gripper either
        assert (fake.stops, fake.invalid_stops, fake.rejected_resumes) == (2, 1, 1)
        assert fake.stopped_by == "operator"  # the first stop's role
        daemon.put(KEYS["resume"], resume)
        assert wait_for(lambda: fake.stopped_by is None)
        assert wait_for(lambda: log.last().stopped_by is None)
        time.sleep(0.05)
        np.testing.assert_array_equal(fake.q, held)  # no command comes back
        daemon.put(KEYS["command"], command(joint0(0.3), ttl=0.2))
        assert wait_for(partial(moved, fake, float(held[0])))
        daemon.put("legws/sawyer/stop/somebody", b"")  # not a known role: stops too
        assert wait_for(lambda: log.last().stopped_by == "unknown")
        assert fake.resumes == 1
        assert log.errors == []


def test_a_workspace_step_out_stops_the_arm(desk: Scene) -> None:
    """A box whose face is 5 mm (+ the 2 cm margin) beyond the endpoint in x: pushed out,
    the arm stops inside; pulled back, it moves."""
    q0 = None
    with peers() as (daemon, robot):
        probe = FakeBridge(robot, "sawyer", desk)
        q0 = probe.q
    world = World(desk, visual=False)
    world.set_q(q0)
    p0 = world.ee_position()
    box = WorkspaceBox(x=(0.2, float(p0[0]) + 0.005), y=(-0.55, 0.55), z=(0.0, 0.6))
    out = list(np.linalg.pinv(world.jacobian()[:3]) @ np.array([0.1, 0.0, 0.0]))
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", desk, workspace=box) as fake:
        log = connected(daemon, fake)
        for seq in range(40):  # 0.8 s at 50 Hz: 8 cm if nothing stopped it
            daemon.put(KEYS["command"], command(out, ttl=0.1, seq=seq))
            time.sleep(0.02)
        world.set_q(fake.q)
        x = float(world.ee_position()[0])
        assert p0[0] + 0.02 < x <= box.x[1] + 0.02  # it came to the face, not past it
        assert fake.limited["workspace"] > 0
        assert wait_for(lambda: "workspace" in log.limited())
        daemon.put(KEYS["command"], command([-v for v in out], ttl=0.1, seq=99))
        time.sleep(0.15)
        world.set_q(fake.q)
        assert world.ee_position()[0] < x - 0.005
