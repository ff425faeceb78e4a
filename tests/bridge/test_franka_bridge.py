"""The Franka bridge's own logic, in legws' venv (no pylibfranka: it is imported at start-up
only). The bridge against the robot, through pylibfranka and franka-sim, is
``test_franka_e2e.py``; here are its tables, its message checks, its ramp and limits (pure
functions, no device at all), and its refusals at start-up (the real program, exit 2)."""

from __future__ import annotations

import ast
import contextlib
import importlib
import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.formats import bridge_messages as contract

BRIDGE = Path(__file__).parents[2] / "bridge" / "franka_bridge.py"


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location("franka_bridge", BRIDGE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["franka_bridge"] = module  # dataclasses resolve their module's names
    spec.loader.exec_module(module)
    return module


fb = _load()

COMMAND = {
    "schema": 1,
    "seq": 1,
    "stamp": 100.0,
    "mode": "joint_velocity",
    "dq": [0.1, -0.2, 0.0, 0.3, 0.0, 0.0, 0.5],
    "ttl": 0.1,
    "gripper": None,
}


def payload(**changes: object) -> bytes:
    return json.dumps({**COMMAND, **changes}).encode()


def _registry() -> ModuleType:
    """legws' arm registry (``legws_daemon.arms``; ``legws_daemon.robot.arms`` before)."""
    for name in ("legws_daemon.arms", "legws_daemon.robot.arms"):
        with contextlib.suppress(ModuleNotFoundError):
            return importlib.import_module(name)
    raise AssertionError("no arm registry in legws_daemon")


def test_the_tables_are_the_registrys_panda_and_the_contracts() -> None:
    panda = _registry().arm("panda")
    assert panda.hardware_joints == fb.JOINT_NAMES
    assert panda.speed_limits == fb.SPEED_LIMITS
    assert tuple(zip(fb.LOWER, fb.UPPER, strict=True)) == panda.position_limits
    assert (panda.mount.x, panda.mount.y, panda.mount.z, panda.mount.yaw) == fb.MOUNT
    assert fb.STOP_ROLES == contract.STOP_ROLES
    assert fb.MAX_TTL == contract.MAX_TTL
    assert fb.LIMITS == ("joint_speed", "ee_speed", "workspace", "ttl", "rate")
    assert set(fb.LIMITS) == set(contract.Limit.__args__)  # type: ignore[attr-defined]


def test_a_valid_command_and_what_is_refused() -> None:
    command = fb.parse_command(payload())
    assert command.dq == tuple(COMMAND["dq"])  # type: ignore[arg-type]
    # the Panda's own limits, not the Sawyer's: 2.0 rad/s on joint 1 is within 2.175
    assert fb.parse_command(payload(dq=[2.0, 0, 0, 0, 0, 0, 0])).dq[0] == 2.0
    bad = {
        "dq[0]": payload(dq=[2.2, 0, 0, 0, 0, 0, 0]),
        "dq[6]": payload(dq=[0, 0, 0, 0, 0, 0, 2.7]),
        "dq": payload(dq=[0.0] * 6),
        "ttl": payload(ttl=1.5),
        "mode": payload(mode="torque"),
        "gripper": payload(gripper="half"),
        "seq": payload(seq=True),
        "extra": payload(extra=1),
        "payload": b'{"schema": 1, "schema": 1}',
    }
    for field, raw in bad.items():
        with pytest.raises(fb.CommandError) as err:
            fb.parse_command(raw)
        assert err.value.field == field
    with pytest.raises(fb.CommandError):
        fb.parse_command(b'{"dq": [NaN]}')


def test_the_commands_the_daemon_sends_pass() -> None:
    message = contract.bridge_contract("panda").Command.model_validate(COMMAND)
    raw = message.model_dump_json(by_alias=True).encode()
    assert fb.parse_command(raw).ttl == 0.1
    state = fb.state_message(
        3, 1.0, [0.0] * 7, [0.0] * 7, "open", True, False, "operator", ["rate"]
    )
    parsed = contract.bridge_contract("panda").parse_state(state, "test")
    assert parsed.stopped_by == "operator" and parsed.limited == ("rate",)


@settings(max_examples=15, deadline=None)
@given(
    st.lists(st.floats(-2.0, 2.0), min_size=7, max_size=7),
    st.lists(st.floats(-2.0, 2.0), min_size=7, max_size=7),
)
def test_the_ramp_keeps_to_the_fci_limits(start: list[float], goal: list[float]) -> None:
    """From any target to any other and back to rest: every cycle's acceleration and jerk
    within the limits libfranka enforces, and the target reached."""
    ramp = fb.default_ramp()
    dt = fb.CONTROL_PERIOD
    v = [np.zeros(7)]
    for target in (start, goal, [0.0] * 7):
        for _ in range(1300):
            v.append(np.array(ramp.step(target, dt)))
        assert np.allclose(v[-1], target, atol=1e-3)
    assert ramp.at_rest()
    velocity = np.array(v)
    accel = np.diff(velocity, axis=0) / dt
    jerk = np.diff(accel, axis=0) / dt
    assert np.all(np.abs(accel) <= np.array(fb.ACCEL_LIMITS) * fb.ACCEL_FRACTION + 1e-6)
    assert np.all(np.abs(jerk) <= np.array(fb.JERK_LIMITS) + 1e-3)


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.floats(-1.5, 1.5), min_size=7, max_size=7),
    st.lists(st.integers(1, 20), min_size=40, max_size=40),
)
def test_late_commands_keep_to_the_fci_limits_as_the_robot_sees_them(
    goal: list[float], lateness: list[int]
) -> None:
    """Commands that come some cycles late, differenced as the FCI does: it applies one
    command per 1 ms cycle, extrapolates a missed one at the last acceleration, and takes
    the late command's acceleration and jerk over one cycle from that extrapolation. (Each
    late command is followed by one on time: back to back, the robot's differences of
    differences amplify rounding by the lateness each time, a model of nothing.)"""
    ramp = fb.default_ramp()
    dt = fb.CONTROL_PERIOD
    accel_limit = np.array(fb.ACCEL_LIMITS)
    jerk_limit = np.array(fb.JERK_LIMITS)
    value, first = np.zeros(7), np.zeros(7)  # the robot's reference and its acceleration
    worst_a, worst_j = 0.0, 0.0
    pattern = iter([k for late in lateness for k in (late, 1)] * 20)
    for target in (goal, [-g for g in goal], [0.0] * 7):
        for _ in range(300):
            cycles = next(pattern, 1)
            for _ in range(cycles - 1):  # the missed ones, extrapolated
                value = value + first * dt
            command = np.array(ramp.step(target, cycles * dt))
            accel = (command - value) / dt
            jerk = (accel - first) / dt
            worst_a = max(worst_a, float(np.max(np.abs(accel) / accel_limit)))
            worst_j = max(worst_j, float(np.max(np.abs(jerk) / jerk_limit)))
            value, first = command, accel
    assert worst_a <= fb.ACCEL_FRACTION + 1e-6
    assert worst_j <= 1.0 + 1e-6


def test_braking_comes_within_its_time() -> None:
    ramp = fb.default_ramp()
    for _ in range(2000):
        ramp.step([0.8] * 7, fb.CONTROL_PERIOD)
    budget = ramp.braking_time([0.8] * 7)
    steps = 0
    while not ramp.at_rest():
        ramp.step([0.0] * 7, fb.CONTROL_PERIOD)
        steps += 1
    assert steps * fb.CONTROL_PERIOD <= budget + 0.2  # the last millimetres at low speed
    assert budget < 0.3


def test_no_joint_is_driven_into_its_limit() -> None:
    accel = [a * fb.ACCEL_FRACTION for a in fb.ACCEL_LIMITS]
    q = [0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.0]
    q[0] = fb.UPPER[0] - 0.05  # 0.5 rad/s needs 0.025 rad to brake, plus the guard
    out = fb.guard_joint_limits(q, [0.5, 0, 0, 0, 0, 0, 0], accel, 0.01)
    assert out[0] == 0.0
    assert fb.guard_joint_limits(q, [-0.5, 0, 0, 0, 0, 0, 0], accel, 0.01)[0] == -0.5
    assert fb.guard_joint_limits(q, [0.1, 0, 0, 0, 0, 0, 0], accel, 0.01)[0] == 0.1


def test_libfrankas_column_major_jacobian() -> None:
    """42 values, column by column (joint by joint), linear rows first in each column."""
    jacobian = [float(10 * joint + row) for joint in range(7) for row in range(6)]
    rows = fb.linear_jacobian(jacobian)
    assert rows[0] == [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    assert rows[2] == [2.0, 12.0, 22.0, 32.0, 42.0, 52.0, 62.0]
    pose = [float(i) for i in range(16)]
    assert fb.endpoint_position(pose) == [12.0, 13.0, 14.0]


def test_the_endpoint_rules_on_the_arms_jacobian() -> None:
    """legws' guard judging the commanded step on the bridge's first-order kinematics
    (libfranka's endpoint and zero Jacobian at the measured joints, in table coordinates)."""
    limits = fb.Limits(workspace=((0.2, 1.0), (-0.6, 0.6), (0.0, 0.95)), mount=(0.12, 0, 0, 0))
    config = fb.zenoh_config(None, [], [])
    with contextlib.closing(zenoh.open(config)) as session:
        arm = fb.FrankaArm(robot=None, library=None)
        bridge = fb.FrankaBridge(
            session, "panda", arm, None, fb.GripperDriver(None), limits=limits, clock=lambda: 0.0
        )
        guard = bridge.guard
        q0 = (0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785)
        # joint 1 turns the endpoint, 0.55 m out, sideways: 0.8 rad/s is 0.44 m/s
        rows = [[0.0] * 7, [0.55] + [0.0] * 6, [0.0] * 7]
        try:
            bridge._linear = (q0, [0.67, 0.0, 0.73], rows)
            guard.command([0.8, 0, 0, 0, 0, 0, 0], 0.1, 0.0)
            step = guard.step(q0, 0.0, 0.01)
            assert step.moving and step.velocity[0] * 0.55 == pytest.approx(0.2, rel=1e-6)
            assert guard.take_limited() == ("ee_speed",)
            # at the box's side (y 0.62 with the margin): outward refused, inward allowed
            bridge._linear = (q0, [0.67, 0.61, 0.73], rows)
            guard.command([0.3, 0, 0, 0, 0, 0, 0], 0.1, 0.0)
            assert not guard.step(q0, 0.0, 0.01, horizon=0.1).moving
            assert guard.take_limited() == ("workspace",) and guard.live is None
            guard.command([-0.3, 0, 0, 0, 0, 0, 0], 0.1, 0.0)
            assert guard.step(q0, 0.0, 0.01, horizon=0.1).moving
            # no Jacobian yet: no endpoint to judge by, no motion
            bridge._linear = None
            guard.command([0.3, 0, 0, 0, 0, 0, 0], 0.1, 0.0)
            assert guard.step(q0, 0.0, 0.01).reason == "no endpoint"
        finally:
            bridge.close()
    # the mount turned a quarter: the base's x is the table's y
    turned = fb.TableFrame((0.12, 0.0, 0.0, math.pi / 2))
    assert turned.to_table([0.5, 0.0, 0.7], True) == pytest.approx([0.12, 0.5, 0.7])


def test_the_robot_modes() -> None:
    assert fb.robot_status("Idle", None) == (True, False)
    assert fb.robot_status("Move", None) == (True, False)
    assert fb.robot_status("Move", "ControlException: reflex") == (False, False)
    assert fb.robot_status("Reflex", None) == (False, False)
    assert fb.robot_status("UserStopped", None) == (False, True)
    assert fb.robot_status("Guiding", None) == (False, False)


def test_the_limits_from_a_profile(tmp_path: Path) -> None:
    profile = tmp_path / "p.toml"
    profile.write_text("[bridge]\njoint_speed_cap = 0.5\n[workspace]\nz = [0.0, 0.9]\n")
    limits = fb.profile_limits(str(profile))
    assert limits.joint_speed_cap == 0.5 and limits.workspace[2] == (0.0, 0.9)
    profile.write_text("[bridge]\nspeed = 1\n")
    with pytest.raises(ValueError, match=r"bridge\.speed: unknown field"):
        fb.profile_limits(str(profile))


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(BRIDGE), *args],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
        check=False,
    )


def test_it_refuses_an_unauthenticated_transport_before_it_reaches_the_arm() -> None:
    done = _run("--robot-ip", "127.0.0.1")
    assert done.returncode == 2
    assert "the transport is not authenticated" in done.stderr
    assert "--insecure-transport" in done.stderr
    assert done.stderr.count("\n") == 1


def test_bad_limits_exit_2_naming_the_flag() -> None:
    done = _run("--robot-ip", "127.0.0.1", "--joint-speed-cap", "5", "--insecure-transport")
    assert done.returncode == 2
    assert "joint_speed_cap must be in" in done.stderr


def test_standalone_and_python_3_9_syntax() -> None:
    """pylibfranka's floor is Python 3.9; the file imports zenoh and the standard library
    at its top, pylibfranka in main()."""
    tree = ast.parse(BRIDGE.read_text(encoding="utf-8"), feature_version=(3, 9))
    top: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.Import):
            top |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            top.add(node.module.split(".")[0])
        elif isinstance(node, ast.Try):  # tomllib, optional
            continue
    assert top - set(sys.stdlib_module_names) - {"__future__"} == {"zenoh"}
    inner = {
        alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.Import)
        for alias in node.names
    }
    assert "pylibfranka" in inner


def test_the_deployment_files_are_authenticated_by_the_daemons_rule(tmp_path: Path) -> None:
    from legws_daemon.cli.main import run as legws
    from legws_daemon.transport.security import authentication_problem

    assert legws(["secure", "init", str(tmp_path / "dep"), "--port", "7447"]) == 0
    for name in ("bridge", "daemon", "operator"):
        config = zenoh.Config.from_file(str(tmp_path / "dep" / f"{name}.json5"))
        assert fb.authentication_problem(config) is None
    plain = fb.zenoh_config(None, ["tcp/127.0.0.1:7447"], [])
    assert fb.authentication_problem(plain) == authentication_problem(plain)
    assert json.loads(plain.get_json("scouting/multicast/enabled")) is False
    assert json.loads(plain.get_json("scouting/gossip/enabled")) is False


def test_the_rate_the_latch_and_the_ttl_on_receipt() -> None:
    """The receipt rules of :class:`FrankaBridge`, legws' guard behind the contract's checks
    (its control loop not started: no arm)."""
    config = fb.zenoh_config(None, [], [])
    with contextlib.closing(zenoh.open(config)) as session:
        arm = fb.FrankaArm(robot=None, library=None)
        bridge = fb.FrankaBridge(session, "panda", arm, model=None, gripper=fb.GripperDriver(None))
        guard = bridge.guard
        try:
            now = 10.0
            for _ in range(fb.COMMAND_BURST):  # the burst passes at once
                bridge.handle_command(payload(), now)
            assert guard.live is not None
            bridge.handle_command(payload(), now)  # one more: refused, the arm stops
            assert bridge.counts["rate"] == 1 and guard.live is None
            later = now + 1.0  # the bucket refilled; a long ttl is cut to max_ttl
            bridge.handle_command(payload(ttl=0.9), later)
            assert bridge.counts["ttl"] == 1
            assert guard.live is not None
            assert guard.live.expires == pytest.approx(later + fb.TTL_CAP)
            bridge.handle_stop("legws/panda/stop/observer", b"not json")
            assert bridge.stopped_by == "observer" and bridge.invalid_stops == 1
            assert guard.live is None
            bridge.handle_command(payload(), later + 0.1)  # ignored while stopped
            assert guard.live is None
            bridge.handle_resume(b'{"schema": 1}')  # no seq: rejected, still stopped
            assert bridge.stopped_by == "observer" and bridge.rejected_resumes == 1
            bridge.handle_resume(b'{"schema": 1, "seq": 1, "stamp": 0}')
            assert bridge.stopped_by is None
            bridge.handle_command(payload(dq=[1.5, 0, 0, 0, 0, 0, 0]), later + 0.2)
            assert guard.live is not None
            assert guard.live.dq[0] == pytest.approx(fb.JOINT_SPEED_CAP)
            assert bridge.counts["joint_speed"] == 1
            bridge.handle_command(b"{}", later + 0.3)  # rejected: the arm stops
            assert bridge.rejected == 1 and guard.live is None
        finally:
            bridge.close()


def test_the_guard_is_legws_one() -> None:
    from legws_daemon.safety import limits

    assert fb.guard_module.Guard.__qualname__ == limits.Guard.__qualname__
    assert fb.guard_module.LIMITS == fb.LIMITS
    assert fb.guard_module.BridgeLimits().describe() == limits.BridgeLimits().describe()


def test_the_control_loop_cycle_by_cycle(monkeypatch: pytest.MonkeyPatch) -> None:
    """:meth:`FrankaArm.cycle` (the thread's one turn) on a fake arm at pylibfranka, on a
    held clock: idle reads until a live target, then one motion whose velocities ramp within
    libfranka's limits to the target, brake to rest once it expires and end the motion
    (``motion_finished`` at rest) after :data:`IDLE_FINISH`; a library error ends the motion,
    the fault kept (no new motion) until the recovery."""
    from legws_daemon.robot.world import World
    from legws_daemon.scene.catalog import load_scene
    from tests.hardware.fake_franka import CYCLE, LIBRARY, FakeFranka

    ready = _registry().arm("panda").ready_posture
    now = [10.0]
    robot = FakeFranka(World(load_scene("desk"), arm="panda", visual=False), ready)
    loop = fb.FrankaArm(robot, LIBRARY, clock=lambda: now[0])
    speeds: list[np.ndarray] = []

    def run(cycles: int) -> None:
        for _ in range(cycles):
            loop.cycle()
            now[0] += CYCLE
            speeds.append(robot.dq.copy())

    run(5)
    assert not robot.moving and loop.motions == 0 and robot.written == 0
    state = loop.latest()
    assert state is not None and state.mode == "Idle" and state.q == pytest.approx(ready)
    target = [0.2, -0.1, 0.0, 0.3, 0.0, 0.0, -0.4]
    loop.set_target(target, now[0] + 0.4)
    run(1)
    assert robot.moving and loop.motions == 1 and robot.written == 0  # started, nothing sent
    run(400)
    assert robot.written == 400 and loop.cycles == 400
    assert robot.dq == pytest.approx(target, abs=1e-3)  # reached in 0.4 s
    budget = loop.ramp.braking_time(target) + 0.2  # expired: braking (the slack as above)
    for _ in range(int(budget / CYCLE)):
        run(1)
        if loop.ramp.at_rest():
            break
    assert loop.ramp.at_rest() and not np.any(robot.dq) and loop.moving()
    run(int(fb.IDLE_FINISH / CYCLE) + 2)  # at rest that long: the motion ends
    assert not robot.moving and not loop.moving() and loop.motions == 1
    accel = np.diff(np.array(speeds), axis=0) / CYCLE
    assert np.all(np.abs(accel) <= np.array(fb.ACCEL_LIMITS) * fb.ACCEL_FRACTION + 1e-6)

    loop.set_target(target, now[0] + 1.0)
    run(50)
    assert robot.moving and loop.motions == 2 and np.any(robot.dq)

    def reflex(command: object) -> None:
        raise RuntimeError("cartesian_reflex")

    monkeypatch.setattr(robot, "writeOnce", reflex)
    loop.cycle()
    monkeypatch.undo()
    assert not loop.moving() and not any(loop.ramp.v)
    robot.moving = False  # libfranka ends the motion on a reflex
    run(20)
    state = loop.latest()
    assert state is not None and state.fault == "RuntimeError: cartesian_reflex"
    assert loop.motions == 2  # the target still live, but no motion with a fault kept
    loop.recover()
    run(2)
    state = loop.latest()
    assert state is not None and state.fault is None and loop.motions == 3 and robot.moving
