"""The robot-side Intera bridge, imported with fake ``rospy`` and ROS message modules.

Only the hardware edge is faked (ROS and the robot; the bridge's own ROS layer is replaced
by look-alikes of Intera's ``Limb``, ``RobotEnable`` and gripper; it meets a real ROS master
and a simulated Sawyer in ``test_ros_e2e.py``): the fake limb follows the
velocities it is sent at once, and reports its endpoint from legws's kinematic model of
the Sawyer. zenoh is real (a session without endpoints, or two loopback peers), and what
the bridge publishes is checked with the daemon's own validator.
"""

from __future__ import annotations

import ast
import contextlib
import importlib.util
import json
import math
import sys
import threading
import time
import types
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.formats import bridge_messages as contract
from legws_daemon.formats.bridge_messages import BridgeCommand, BridgeState, bridge_contract
from legws_daemon.formats.messages import dump
from legws_daemon.formats.profile import (
    COMMAND_BURST,
    BridgeLimitsSpec,
    TransportSpec,
    WorkspaceBox,
    load_profile,
)
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.transport.session import config_from_spec, open_session
from tests.net import free_port

SAWYER = bridge_contract("sawyer")  # the daemon's side of the contract, on the Sawyer
BRIDGE = Path(__file__).parents[2] / "bridge" / "intera_bridge.py"
PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sawyer.toml"
HOME_Q = [-0.16, -1.30, -0.19, 1.73, 0.06, 1.14, -0.19]
COMMAND = {
    "schema": 1,
    "seq": 1,
    "stamp": 100.0,
    "mode": "joint_velocity",
    "dq": [0.1, -0.2, 0.0, 0.3, 0.0, 0.0, 0.5],
    "ttl": 0.1,
    "gripper": None,
}


# --- the fake hardware edge ---------------------------------------------------------
class Kinematics:
    """legws's model of the Sawyer (the same description as the robot's): the fake
    limb's endpoint. One model for all limbs, behind a lock."""

    _lock = threading.Lock()
    _world: World | None = None

    @classmethod
    def endpoint(cls, q: list[float], dq: list[float]) -> tuple[np.ndarray, np.ndarray]:
        """The endpoint's position and linear velocity (base frame) at ``q``, ``dq``."""
        with cls._lock:
            if cls._world is None:
                cls._world = World(load_scene("desk"), visual=False)
            cls._world.set_q(q)
            return cls._world.ee_position(), cls._world.jacobian()[:3] @ np.asarray(dq)


def vector(v: np.ndarray) -> types.SimpleNamespace:
    """A ``geometry_msgs`` Point / Vector3 look-alike."""
    return types.SimpleNamespace(x=float(v[0]), y=float(v[1]), z=float(v[2]))


class FakeLimb:
    """``intera_interface.Limb``: an arm that follows the joint velocities it is sent at
    once (integrated on the given clock), its endpoint from the kinematic model; every
    command recorded."""

    def __init__(self, side: str = "right", clock: Callable[[], float] = time.monotonic) -> None:
        assert side == "right"
        self.q = list(HOME_Q)
        self.v = [0.0] * 7  # the joint velocities being applied
        self.clock = clock
        self.endpoint_known = True  # False: Intera has no endpoint state yet ({})
        self.calls: list[tuple[str, dict[str, float] | None]] = []
        self._t = clock()
        self._lock = threading.Lock()

    def _advance(self) -> None:
        now = self.clock()
        if now > self._t:
            self.q = [q + v * (now - self._t) for q, v in zip(self.q, self.v, strict=True)]
            self._t = now

    def joint_angles(self) -> dict[str, float]:
        with self._lock:
            self._advance()
            return {f"right_j{i}": v for i, v in enumerate(self.q)}

    def joint_velocities(self) -> dict[str, float]:
        with self._lock:
            return {f"right_j{i}": v for i, v in enumerate(self.v)}

    def endpoint_pose(self) -> dict[str, types.SimpleNamespace]:
        with self._lock:
            self._advance()
            if not self.endpoint_known:
                return {}
            p, _ = Kinematics.endpoint(self.q, self.v)
            quaternion = types.SimpleNamespace(x=0.0, y=1.0, z=0.0, w=0.0)
            return {"position": vector(p), "orientation": quaternion}

    def endpoint_velocity(self) -> dict[str, types.SimpleNamespace]:
        with self._lock:
            self._advance()
            if not self.endpoint_known:
                return {}
            _, v = Kinematics.endpoint(self.q, self.v)
            return {"linear": vector(v), "angular": vector(np.zeros(3))}

    def ee(self) -> tuple[np.ndarray, np.ndarray]:
        """The endpoint's position and linear velocity now (for the tests' checks)."""
        with self._lock:
            self._advance()
            return Kinematics.endpoint(self.q, self.v)

    def set_joint_velocities(self, velocities: dict[str, float]) -> None:
        with self._lock:
            self._advance()
            self.v = [float(velocities[f"right_j{i}"]) for i in range(7)]
            self.calls.append(("velocities", dict(velocities)))

    def exit_control_mode(self) -> None:
        with self._lock:
            self._advance()
            self.v = [0.0] * 7  # Intera's position hold
            self.calls.append(("exit_control_mode", None))

    def recorded(self) -> list[tuple[str, dict[str, float] | None]]:
        with self._lock:
            return list(self.calls)


class FakeGripper:
    """``intera_interface.Gripper``: open/close recorded, never moving."""

    def __init__(self) -> None:
        self.calls: list[str] = []

    def open(self) -> None:
        self.calls.append("open")

    def close(self) -> None:
        self.calls.append("close")

    def is_moving(self) -> bool:
        return False


class FakeEnable:
    """``intera_interface.RobotEnable``: its ``state()`` is an AssemblyState look-alike."""

    def __init__(self, *args: object) -> None:
        self.enabled = True
        self.stopped = False
        self.enable_calls = 0

    def enable(self) -> None:
        self.enable_calls += 1
        self.enabled = True

    def state(self) -> types.SimpleNamespace:
        return types.SimpleNamespace(
            enabled=self.enabled, stopped=self.stopped, estop_button=0, ESTOP_BUTTON_PRESSED=1
        )


class FakeRos:
    """The parts of ``rospy`` the bridge uses; shuts down after ``ticks`` loop checks."""

    class ROSInterruptException(Exception):  # noqa: N818 (rospy's name)
        pass

    def __init__(self, ticks: int = 10**9) -> None:
        self.ticks = ticks
        self.hooks: list[Callable[[], None]] = []
        self.logs: list[str] = []
        self.node: str | None = None

    def module(self) -> types.ModuleType:
        m = types.ModuleType("rospy")
        m.ROSInterruptException = FakeRos.ROSInterruptException  # type: ignore[attr-defined]
        for name in ("loginfo", "logwarn", "logerr"):
            setattr(m, name, self.logs.append)
        for name in ("logwarn_throttle", "logerr_throttle"):
            setattr(m, name, lambda period, text: self.logs.append(text))
        m.myargv = lambda argv: [a for a in argv if ":=" not in a]  # type: ignore[attr-defined]
        m.init_node = self.init_node  # type: ignore[attr-defined]
        m.on_shutdown = self.hooks.append  # type: ignore[attr-defined]
        m.is_shutdown = self.is_shutdown  # type: ignore[attr-defined]
        m.Rate = FakeRate  # type: ignore[attr-defined]
        return m

    def init_node(self, name: str) -> None:
        self.node = name

    def is_shutdown(self) -> bool:
        self.ticks -= 1
        if self.ticks == 0:  # like rospy's SIGINT handler: the hooks run first
            for hook in self.hooks:
                hook()
        return self.ticks <= 0


class FakeRate:
    def __init__(self, hz: float) -> None:
        self.period = 1.0 / hz

    def sleep(self) -> None:
        time.sleep(self.period)


def fake_intera(gripper: object | None) -> tuple[types.ModuleType, dict[str, Any]]:
    """The robot's side as ``intera_interface`` had it (``Limb``, ``RobotEnable``,
    ``get_current_gripper_interface``) and the objects it hands out: :func:`load_bridge`
    puts them in place of the bridge's ROS layer."""
    made: dict[str, Any] = {}
    m = types.ModuleType("intera_interface")
    m.CHECK_VERSION = True  # type: ignore[attr-defined]

    def limb(side: str) -> FakeLimb:
        made["limb"] = FakeLimb(side)
        return made["limb"]  # type: ignore[no-any-return]

    def enable(*args: object) -> FakeEnable:
        made["enable"] = FakeEnable(*args)
        return made["enable"]  # type: ignore[no-any-return]

    def get_gripper() -> object:
        if gripper is None:
            raise OSError("Failed to get gripper. No gripper attached on the robot.")
        return gripper

    m.Limb = limb  # type: ignore[attr-defined]
    m.RobotEnable = enable  # type: ignore[attr-defined]
    m.get_current_gripper_interface = get_gripper  # type: ignore[attr-defined]
    return m, made


def load_bridge(
    monkeypatch: pytest.MonkeyPatch, ros: FakeRos, intera: types.ModuleType
) -> types.ModuleType:
    """Import ``bridge/intera_bridge.py`` with the fakes in ``sys.modules``."""
    monkeypatch.setitem(sys.modules, "rospy", ros.module())
    for name, classes in MESSAGES.items():
        package = types.ModuleType(name)
        msg = types.ModuleType(f"{name}.msg")
        for cls in classes:
            setattr(msg, cls, type(cls, (), {}))
        package.msg = msg  # type: ignore[attr-defined]
        monkeypatch.setitem(sys.modules, name, package)
        monkeypatch.setitem(sys.modules, f"{name}.msg", msg)
    spec = importlib.util.spec_from_file_location("intera_bridge_under_test", BRIDGE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "RosLimb", lambda: intera.Limb("right"))
    monkeypatch.setattr(module, "RosEnable", lambda: intera.RobotEnable())
    monkeypatch.setattr(module, "find_gripper", intera.get_current_gripper_interface)
    return module


#: The ROS messages the bridge imports, faked (the real ones: test_ros_e2e.py).
MESSAGES = {
    "intera_core_msgs": (
        "EndpointState",
        "IOComponentCommand",
        "IODeviceStatus",
        "IONodeStatus",
        "JointCommand",
        "RobotAssemblyState",
    ),
    "sensor_msgs": ("JointState",),
    "std_msgs": ("Bool", "Empty", "Float64"),
}


@pytest.fixture(scope="module")
def bridge_module() -> Iterator[types.ModuleType]:
    """The bridge, imported once with fakes (removed from ``sys.modules`` afterwards)."""
    intera, _ = fake_intera(FakeGripper())
    with pytest.MonkeyPatch.context() as mp:
        yield load_bridge(mp, FakeRos(), intera)


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    """A zenoh session without endpoints: local publications reach local subscribers."""
    with open_session(config_from_spec(TransportSpec(listen=[], connect=[]))) as s:
        yield s


class States:
    """Every state the bridge publishes, validated by the daemon's parser."""

    def __init__(self, session: zenoh.Session, robot: str = "sawyer") -> None:
        self.key = f"legws/{robot}/bridge/state"
        self.states: list[BridgeState] = []
        self.errors: list[str] = []
        self._lock = threading.Lock()
        self.subscriber = session.declare_subscriber(self.key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            state = SAWYER.parse_state(sample.payload.to_bytes(), self.key)
        except InputError as err:
            with self._lock:
                self.errors.append(str(err))
            return
        with self._lock:
            self.states.append(state)

    def snapshot(self) -> list[BridgeState]:
        with self._lock:
            return list(self.states)


def wait_for(condition: Callable[[], bool], timeout: float = 3.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def payload(**change: object) -> bytes:
    return json.dumps({**COMMAND, **change}).encode()  # NaN/Infinity written as literals


# --- the file itself ---------------------------------------------------------------
def test_standalone_and_python_3_8_syntax() -> None:
    source = BRIDGE.read_text(encoding="utf-8")
    tree = ast.parse(source, feature_version=(3, 8))  # ROS Noetic's Python
    imported: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    outside = imported - set(sys.stdlib_module_names) - {"__future__"}
    # legws_daemon: the standard-library limit module and arm tables every bridge shares
    # (tests/safety/test_limits.py runs them under Python 3.8)
    assert outside == {
        "rospy",
        "intera_core_msgs",
        "sensor_msgs",
        "std_msgs",
        "zenoh",
        "legws_daemon",
    }
    assert "from legws_daemon.safety import limits as guard_limits" in source


def test_constants_are_the_contract(bridge_module: types.ModuleType) -> None:
    b = bridge_module
    assert SAWYER.arm.hardware_joints == b.JOINT_NAMES
    assert SAWYER.arm.speed_limits == b.SPEED_LIMITS
    assert SAWYER.arm.lower == b.LOWER
    assert SAWYER.arm.upper == b.UPPER
    assert b.MAX_TTL == contract.MAX_TTL
    assert b.SPEED_TOLERANCE == contract.SPEED_TOLERANCE


# --- message checks ----------------------------------------------------------------
def test_accepts_what_the_daemon_sends(bridge_module: types.ModuleType) -> None:
    sent = SAWYER.Command.model_validate({**COMMAND, "dq": list(SAWYER.arm.speed_limits)})
    command = bridge_module.parse_command(dump(sent))
    assert command.dq == SAWYER.arm.speed_limits
    assert command.ttl == 0.1
    assert command.gripper is None
    assert bridge_module.parse_command(payload(gripper="closed")).gripper == "closed"


@pytest.mark.parametrize(
    ("raw", "field"),
    [
        (payload(dq=[math.nan, 0, 0, 0, 0, 0, 0]), "dq[0]"),
        (payload(dq=[0, 0, 0, 0, 0, 0, -math.inf]), "dq[6]"),
        (payload(dq=[0, 1.4, 0, 0, 0, 0, 0]), "dq[1]"),  # over right_j1's 1.328 rad/s
        (payload(dq=[0, 0, 0, 0, 0, 0, True]), "dq[6]"),
        (payload(dq=[0.0] * 6), "dq"),
        (payload(ttl=0), "ttl"),
        (payload(ttl=2.0), "ttl"),
        (payload(ttl=math.nan), "ttl"),
        (payload(mode="ee_velocity"), "mode"),
        (payload(schema=2), "schema"),
        (payload(seq=-1), "seq"),
        (payload(gripper="half"), "gripper"),
        (payload(extra=1), "extra"),
        (json.dumps({k: v for k, v in COMMAND.items() if k != "ttl"}).encode(), "ttl"),
        (b"\xff\xfe{", "payload"),
        (b"[1, 2]", "payload"),
        (b" " * (65 * 1024), "payload"),
    ],
)
def test_rejects_with_the_field(bridge_module: types.ModuleType, raw: bytes, field: str) -> None:
    with pytest.raises(bridge_module.CommandError) as info:
        bridge_module.parse_command(raw)
    assert info.value.field == field
    assert "\n" not in str(info.value)


_SCALARS = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6)


@settings(max_examples=1500, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from([*COMMAND, "x"]),
        _SCALARS | st.lists(_SCALARS | st.floats(-5, 5), min_size=6, max_size=8),
    ),
    st.booleans(),
)
def test_agrees_with_the_daemons_validator(
    bridge_module: types.ModuleType, doc: dict[str, object], based: bool
) -> None:
    """The bridge accepts exactly the commands the daemon's contract accepts."""
    raw = json.dumps({**COMMAND, **doc} if based else doc).encode()
    ours: BridgeCommand | None = None
    theirs: Any = None
    with contextlib.suppress(InputError):
        ours = SAWYER.parse_command(raw, "fuzz")
    with contextlib.suppress(bridge_module.CommandError):
        theirs = bridge_module.parse_command(raw)
    assert (ours is None) == (theirs is None), raw
    if ours is not None:
        assert theirs.dq == ours.dq
        assert theirs.ttl == ours.ttl
        assert theirs.gripper == ours.gripper


def test_state_messages_are_valid_for_the_daemon(bridge_module: types.ModuleType) -> None:
    raw = bridge_module.state_message(5, 12.5, HOME_Q, [0.0] * 7, "unknown", True, False)
    state = SAWYER.parse_state(raw, "state")
    assert list(state.q) == HOME_Q
    assert state.gripper == "unknown"
    with pytest.raises(ValueError, match="Out of range float"):
        bridge_module.state_message(6, 12.5, [math.nan] * 7, [0.0] * 7, "open", True, False)


# --- the bridge at work ------------------------------------------------------------
class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def make_bridge(
    b: types.ModuleType,
    session: zenoh.Session,
    limits: Any = None,
    measured: bool = False,
    period: float = 0.01,
) -> tuple[Any, FakeLimb, FakeEnable, FakeGripper, Clock]:
    """The bridge as it runs (its endpoint by the arm's chain), or in the weaker measured
    mode (``measured``: Intera's endpoint twist)."""
    clock = Clock()
    limb, enable, gripper = FakeLimb(clock=clock), FakeEnable(), FakeGripper()
    bridge = b.SawyerBridge(
        session,
        "sawyer",
        limb,
        b.GripperDriver(gripper),
        enable,
        clock=clock,
        wall=clock,
        limits=limits,
        period=period,
        chain=None if measured else b.load_chain(),
    )
    assert (bridge.chain is None) is measured
    return bridge, limb, enable, gripper, clock


def velocities(limb: FakeLimb) -> list[list[float]]:
    return [[v[f"right_j{i}"] for i in range(7)] for kind, v in limb.recorded() if v is not None]


def test_applies_velocities_until_the_ttl(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    bridge.tick()
    assert limb.recorded() == []  # no command, nothing sent
    bridge.handle_command(payload(), clock.now)
    for t in (0.01, 0.05, 0.09):
        clock.now = t
        bridge.tick()
    assert velocities(limb) == [COMMAND["dq"]] * 3
    clock.now = 0.1  # the ttl is over: zero, then Intera's position hold, once
    bridge.tick()
    bridge.tick()
    assert velocities(limb)[-1] == [0.0] * 7
    assert [kind for kind, _ in limb.recorded()][-2:] == ["velocities", "exit_control_mode"]
    assert len(limb.recorded()) == 5
    bridge.close()


def test_rejected_commands_stop_the_arm(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    for n, bad in enumerate(
        [payload(dq=[math.nan] * 7), payload(dq=[2.0, 0, 0, 0, 0, 0, 0]), b"garbage"], start=1
    ):
        bridge.handle_command(payload(ttl=1.0), clock.now)
        clock.now += 0.01
        bridge.tick()
        assert velocities(limb)[-1] == COMMAND["dq"]
        bridge.handle_command(bad, clock.now)
        clock.now += 0.01
        bridge.tick()
        assert velocities(limb)[-1] == [0.0] * 7
        assert limb.recorded()[-1][0] == "exit_control_mode"
        assert bridge.rejected == n
    bridge.close()


def test_never_moves_when_disabled_or_estopped(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, enable, _, clock = make_bridge(bridge_module, session)
    states = States(session)
    enable.stopped = True
    bridge.handle_command(payload(ttl=1.0), clock.now)
    bridge.tick()
    enable.stopped, enable.enabled = False, False
    bridge.handle_command(payload(ttl=1.0), clock.now)
    bridge.tick()
    assert limb.recorded() == []
    assert wait_for(lambda: len(states.snapshot()) == 2)
    first, second = states.snapshot()
    assert first.estop and not second.estop and not second.enabled
    bridge.close()


def test_joints_at_a_limit_are_not_driven_further(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    # this pose has the endpoint at x = 0.17 m, outside the default box: a wider one here
    wide = bridge_module.Limits(workspace=((-1.0, 1.0), (-1.0, 1.0), (-0.5, 1.0)))
    bridge, limb, _, _, clock = make_bridge(bridge_module, session, wide)
    limb.q[0] = SAWYER.arm.upper[0]
    limb.q[3] = SAWYER.arm.lower[3] + 0.005
    bridge.handle_command(payload(dq=[0.1, 0.1, 0, -0.2, 0, 0, 0]), clock.now)
    bridge.tick()
    assert velocities(limb)[-1] == [0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0]
    bridge.handle_command(payload(dq=[-0.1, 0, 0, 0.2, 0, 0, 0]), clock.now)
    bridge.tick()  # away from the limits: allowed
    assert velocities(limb)[-1] == [-0.1, 0.0, 0.0, 0.2, 0.0, 0.0, 0.0]
    bridge.close()


def test_publishes_valid_states_and_drives_the_gripper(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, _, _, gripper, clock = make_bridge(bridge_module, session)
    states = States(session)
    bridge.tick()
    bridge.handle_command(payload(gripper="closed"), clock.now)
    bridge.tick()
    bridge.handle_command(payload(gripper="closed"), clock.now)
    bridge.tick()  # the same request again: no new gripper command
    bridge.handle_command(payload(gripper="open"), clock.now)
    bridge.tick()
    assert gripper.calls == ["close", "open"]
    assert wait_for(lambda: len(states.snapshot()) == 4)
    got = states.snapshot()
    assert [s.gripper for s in got] == ["unknown", "closed", "closed", "open"]
    assert [s.seq for s in got] == [0, 1, 2, 3]
    assert list(got[0].q) == HOME_Q
    assert states.errors == []
    bridge.close()


def test_halt_is_final(bridge_module: types.ModuleType, session: zenoh.Session) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    bridge.handle_command(payload(ttl=1.0), clock.now)
    bridge.tick()
    bridge.halt()  # e.g. rospy shutting down
    assert velocities(limb)[-1] == [0.0] * 7
    n = len(limb.recorded())
    bridge.handle_command(payload(ttl=1.0), clock.now)
    bridge.tick()
    assert len(limb.recorded()) == n
    bridge.close()


def test_no_gripper_reports_unknown(bridge_module: types.ModuleType) -> None:
    driver = bridge_module.GripperDriver(None)
    driver.command("closed")
    assert driver.status() == "unknown"


# --- the bridge's own limits -------------------------------------------------------
def test_default_limits_are_the_profiles(bridge_module: types.ModuleType) -> None:
    b = bridge_module
    spec, box = BridgeLimitsSpec(), WorkspaceBox()
    limits = b.Limits()
    assert set(b.guard_limits._PROFILE_BRIDGE_KEYS) == set(BridgeLimitsSpec.model_fields)
    for name in BridgeLimitsSpec.model_fields:
        assert getattr(limits, name) == getattr(spec, name), name
    assert limits.workspace == (box.x, box.y, box.z)
    assert limits.burst == COMMAND_BURST
    assert b.parse_args([]).limits == limits
    assert b.STOP_ROLES == contract.STOP_ROLES
    assert typing.get_args(contract.Limit) == b.LIMITS
    assert limits.joint_caps(b.SPEED_LIMITS) == tuple(min(0.8, s) for s in b.SPEED_LIMITS)


def test_limits_from_a_profile_and_flags(bridge_module: types.ModuleType, tmp_path: Path) -> None:
    b = bridge_module
    profile = load_profile(PROFILE)
    ws = profile.workspace
    expected = b.Limits(
        **profile.bridge.model_dump(), workspace=(ws.x, ws.y, ws.z), burst=COMMAND_BURST
    )
    assert b.parse_args(["--profile", str(PROFILE)]).limits == expected
    args = b.parse_args(
        ["--profile", str(PROFILE), "--max-ttl", "0.1", "--ee-speed-cap", "0.3",
         "--workspace", "0.3", "0.8", "-0.4", "0.4", "0.05", "0.5"]
    )  # fmt: skip
    assert args.limits.max_ttl == 0.1
    assert args.limits.ee_speed_cap == 0.3
    assert args.limits.workspace == ((0.3, 0.8), (-0.4, 0.4), (0.05, 0.5))
    assert args.limits.joint_speed_cap == profile.bridge.joint_speed_cap
    unknown = tmp_path / "unknown.toml"
    unknown.write_text("[bridge]\njoint_speed = 0.5\n")
    text = tmp_path / "text.toml"
    text.write_text('[bridge]\nmax_ttl = "long"\n')
    for argv in (
        ["--joint-speed-cap", "0"],
        ["--joint-speed-cap", "5"],
        ["--max-ttl", "2"],
        ["--command-rate", "nan"],
        ["--workspace-margin", "-0.1"],
        ["--workspace", "1", "0", "-1", "1", "0", "1"],
        ["--profile", str(tmp_path / "missing.toml")],
        ["--profile", str(unknown)],
        ["--profile", str(text)],
        ["--profile", "/dev/zero"],  # a device: refused before it is opened
        ["--listen", "tcp/127.0.0.1:99999"],
        ["--connect", "tcp/127.0.0.1:0"],
        ["--connect", "tcp/127.0.0.1:7447\n"],
        ["--listen", "nowhere"],
    ):
        with pytest.raises(SystemExit) as info:
            b.parse_args(argv)
        assert info.value.code == 2, argv


def test_without_tomllib_the_profile_flag_says_so(
    bridge_module: types.ModuleType, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(bridge_module.guard_limits, "tomllib", None)  # Python 3.8
    with pytest.raises(ValueError, match=r"Python >= 3\.11"):
        bridge_module.profile_limits(str(PROFILE))


def test_joint_speeds_are_capped_uniformly(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    states = States(session)
    # the wrist: right_j6 over its cap, the endpoint slow (it sits on right_j6's axis)
    bridge.handle_command(payload(dq=[0.0, 0.0, 0.0, 0.0, 0.0, -0.4, 1.6]), clock.now)
    bridge.tick()
    assert velocities(limb)[-1] == pytest.approx([0.0, 0.0, 0.0, 0.0, 0.0, -0.2, 0.8])
    bridge.handle_command(payload(seq=2), clock.now)  # within the caps: unchanged
    bridge.tick()
    assert velocities(limb)[-1] == COMMAND["dq"]
    assert wait_for(lambda: len(states.snapshot()) == 2)
    assert [s.limited for s in states.snapshot()] == [("joint_speed",), ()]
    assert bridge.counts["joint_speed"] == 1
    bridge.close()


def test_a_command_moves_the_arm_at_most_max_ttl(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    states = States(session)
    bridge.handle_command(payload(ttl=1.0), clock.now)
    for t in (0.0, 0.1, 0.19):
        clock.now = t
        bridge.tick()
    assert velocities(limb) == [COMMAND["dq"]] * 3
    clock.now = 0.2  # max_ttl, not the command's 1 s
    bridge.tick()
    assert limb.recorded()[-1][0] == "exit_control_mode"
    assert wait_for(lambda: len(states.snapshot()) == 4)
    assert states.snapshot()[0].limited == ("ttl",)
    bridge.close()


def test_commands_over_the_rate_are_refused_and_stop_the_arm(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    states = States(session)
    for seq in range(COMMAND_BURST):  # a burst: accepted
        bridge.handle_command(payload(seq=seq), clock.now)
    bridge.tick()
    assert velocities(limb)[-1] == COMMAND["dq"]
    bridge.handle_command(payload(seq=5), clock.now)  # one more at once: refused
    clock.now = 0.005
    bridge.tick()
    assert limb.recorded()[-1][0] == "exit_control_mode"
    clock.now = 1.0 / 60.0  # a token back
    bridge.handle_command(payload(seq=6), clock.now)
    bridge.tick()
    assert velocities(limb)[-1] == COMMAND["dq"]
    assert wait_for(lambda: len(states.snapshot()) == 3)
    assert [s.limited for s in states.snapshot()] == [(), ("rate",), ()]
    assert bridge.counts["rate"] == 1
    assert bridge.accepted == 7  # every valid command is counted
    bridge.close()


def test_the_endpoint_speed_is_held_to_the_cap_from_the_first_tick(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    """The base joint at 0.8 rad/s would swing the endpoint at ~0.44 m/s: the chain's
    forward kinematics of the commanded step holds it to 0.2 m/s from the first tick."""
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    states = States(session)
    speeds = []
    for k in range(20):
        if k % 5 == 0:
            bridge.handle_command(payload(seq=k, dq=[0.8, 0, 0, 0, 0, 0, 0], ttl=0.1), clock.now)
        bridge.tick()
        speeds.append(float(np.linalg.norm(limb.ee()[1])))
        clock.now += 0.01
    assert max(speeds) <= 0.2 * (1 + 1e-3)
    assert min(speeds) >= 0.2 * 0.99
    assert wait_for(lambda: len(states.snapshot()) == 20)
    assert all(s.limited == ("ee_speed",) for s in states.snapshot())
    bridge.close()


def test_the_measured_endpoint_speed_is_held_to_the_cap(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    """The weaker mode (no chain): the first tick is a tick behind the measurement; from
    the next one the arm is scaled to 0.2 m/s."""
    bridge, limb, _, _, clock = make_bridge(bridge_module, session, measured=True)
    states = States(session)
    speeds = []
    for k in range(20):
        if k % 5 == 0:
            bridge.handle_command(payload(seq=k, dq=[0.8, 0, 0, 0, 0, 0, 0], ttl=0.1), clock.now)
        bridge.tick()
        speeds.append(float(np.linalg.norm(limb.ee()[1])))
        clock.now += 0.01
    assert speeds[0] == pytest.approx(0.44, abs=0.02)  # not measured yet
    assert max(speeds[1:]) <= 0.2 * (1 + 1e-3)
    assert min(speeds[1:]) >= 0.2 * 0.99  # scaled to the cap, not below
    applied = velocities(limb)
    assert all(v[1:] == [0.0] * 6 for v in applied)  # the direction kept
    assert wait_for(lambda: len(states.snapshot()) == 20)
    got = states.snapshot()
    assert got[0].limited == ()
    assert all(s.limited == ("ee_speed",) for s in got[1:])
    bridge.close()


@pytest.mark.parametrize("measured", [False, True])
def test_a_predicted_step_out_of_the_workspace_stops_the_arm(
    bridge_module: types.ModuleType, session: zenoh.Session, measured: bool
) -> None:
    """The endpoint 1 cm from the box's (+ margin) face, pushed out at 0.1 m/s: it stops
    at the face; each new push out moves it at most a tick's travel; back in is allowed."""
    b = bridge_module
    p0, _ = FakeLimb().ee()
    face = float(p0[0]) + 0.01
    limits = b.Limits(workspace=((0.2, face - 0.02), (-0.55, 0.55), (0.0, 0.6)))
    bridge, limb, _, _, clock = make_bridge(b, session, limits, measured=measured)
    world = World(load_scene("desk"), visual=False)
    world.set_q(HOME_Q)
    out = list(np.linalg.pinv(world.jacobian()[:3]) @ np.array([0.1, 0.0, 0.0]))
    x = []
    for k in range(40):
        if k % 2 == 0:  # a command every other tick (50 Hz)
            bridge.handle_command(payload(seq=k, dq=out, ttl=0.2), clock.now)
        bridge.tick()
        clock.now += 0.01
        x.append(float(limb.ee()[0][0]))
    assert bridge.counts["workspace"] >= 1
    # the chain: never past the face; measured: at most one tick of travel past it
    assert max(x) <= face + (0.1 * 0.01 + 1e-4 if measured else 1e-9)
    assert x[-1] == pytest.approx(max(x), abs=1e-6)  # stopped, not drifting on
    assert limb.recorded()[-1][0] == "exit_control_mode"
    back = [-v for v in out]
    for k in range(5):
        bridge.handle_command(payload(seq=100 + k, dq=back, ttl=0.2), clock.now)
        bridge.tick()
        clock.now += 0.02
    assert limb.ee()[0][0] < x[-1] - 0.005
    bridge.close()


@pytest.mark.parametrize("measured", [False, True])
@pytest.mark.parametrize("pattern", ["same", "in-and-out"])
def test_pushing_out_again_and_again_stays_within_a_bound(
    bridge_module: types.ModuleType, session: zenoh.Session, pattern: str, measured: bool
) -> None:
    """A sender that keeps pushing out (a fresh command after every stop, or one out and
    one in): each motion not yet measured may pass the face by PROBE; outside by
    OUTSIDE_LIMIT less PROBE, nothing new moves. 5 s of it at 60 commands/s."""
    b = bridge_module
    p0, _ = FakeLimb().ee()
    face = float(p0[0]) + 0.01
    limits = b.Limits(workspace=((0.2, face - 0.02), (-0.55, 0.55), (0.0, 0.6)))
    # the chain's check looks one period ahead: the period of these ticks, 60 Hz
    period = 0.01 if measured else 1.0 / 60.0
    bridge, limb, _, _, clock = make_bridge(b, session, limits, measured=measured, period=period)
    world = World(load_scene("desk"), visual=False)
    world.set_q(HOME_Q)
    inverse = np.linalg.pinv(world.jacobian()[:3])
    x = []
    for k in range(300):
        push = [0.2, 0.0, 0.0] if pattern == "same" or k % 2 else [-0.05, 0.0, 0.0]
        bridge.handle_command(payload(seq=k, dq=list(inverse @ push), ttl=0.2), clock.now)
        bridge.tick()
        clock.now += 1.0 / 60.0
        x.append(float(limb.ee()[0][0]))
    bound = b.guard_limits.OUTSIDE_LIMIT + 1e-4 if measured else 1e-9
    assert max(x) <= face + bound  # the chain: never past the face
    assert bridge.counts["workspace"] > 100
    bridge.close()


def test_no_endpoint_state_no_motion(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    states = States(session)
    limb.endpoint_known = False  # Intera's endpoint_pose() is {} until the robot reports
    bridge.handle_command(payload(), clock.now)
    bridge.tick()
    assert limb.recorded() == []
    assert wait_for(lambda: len(states.snapshot()) == 1)  # the heartbeat goes on
    bridge.close()


def test_a_stop_latches_until_a_valid_resume(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    states = States(session)
    resume = json.dumps({"schema": 1, "seq": 1, "stamp": 5.0}).encode()
    bridge.handle_command(payload(ttl=0.2), clock.now)
    bridge.tick()
    assert velocities(limb)[-1] == COMMAND["dq"]
    bridge.handle_stop("legws/sawyer/stop/observer", b"")
    clock.now = 0.01
    bridge.tick()
    assert limb.recorded()[-1][0] == "exit_control_mode"
    n = len(limb.recorded())
    bridge.handle_command(payload(seq=2, ttl=0.2, gripper="closed"), clock.now)  # ignored
    bridge.handle_stop("legws/sawyer/stop/operator", b"{not json")  # stops all the same
    bridge.handle_resume(b'{"schema": 1, "seq": -1, "stamp": 0}')  # invalid: still latched
    bridge.tick()
    assert len(limb.recorded()) == n
    assert (bridge.stops, bridge.invalid_stops, bridge.rejected_resumes) == (2, 1, 1)
    assert bridge.stopped_by == "observer"  # the first stop's role
    bridge.handle_resume(resume)
    bridge.tick()  # no command comes back
    assert len(limb.recorded()) == n
    bridge.handle_command(payload(seq=3, ttl=0.2), clock.now)
    bridge.tick()
    assert velocities(limb)[-1] == COMMAND["dq"]
    bridge.handle_stop("legws/sawyer/stop/intruder", b"")  # no known role: stops too
    bridge.tick()
    assert wait_for(lambda: len(states.snapshot()) == 6)
    got = states.snapshot()
    assert [s.stopped_by for s in got] == [None, "observer", "observer", None, None, "unknown"]
    assert [s.gripper for s in got] == ["unknown"] * 6  # the ignored request did nothing
    assert states.errors == []
    bridge.close()


def test_stops_and_resumes_arrive_over_zenoh(
    bridge_module: types.ModuleType, session: zenoh.Session
) -> None:
    bridge, _, _, _, _ = make_bridge(bridge_module, session)
    session.put(contract.stop_key("sawyer", "safety"), b'{"schema": 1, "reason": "test"}')
    assert wait_for(lambda: bridge.stopped_by == "safety")
    session.put("legws/sawyer/bridge/resume", b'{"schema": 1, "seq": 0, "stamp": 1.5}')
    assert wait_for(lambda: bridge.stopped_by is None)
    assert (bridge.stops, bridge.resumes) == (1, 1)
    bridge.close()


_TEXTS = st.text(min_size=60, max_size=205) | st.text(max_size=3)


@settings(max_examples=1500, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["schema", "seq", "stamp", "source", "reason", "x"]),
        _SCALARS | _TEXTS | st.lists(_SCALARS, max_size=2),
    ),
    st.sampled_from([{}, {"schema": 1}, {"schema": 1, "seq": 3, "stamp": 1.0}]),
    st.booleans(),
)
def test_stop_and_resume_checks_agree_with_the_contract(
    bridge_module: types.ModuleType, doc: dict[str, object], base: dict[str, object], raw: bool
) -> None:
    b = bridge_module
    data = json.dumps({**base, **doc}).encode() if not raw else json.dumps(doc).encode()[:7]
    for ours, theirs in (
        (contract.parse_stop, b.check_stop),
        (contract.parse_resume, b.check_resume),
    ):
        ok_ours = ok_theirs = True
        try:
            ours(data, "fuzz")
        except InputError:
            ok_ours = False
        try:
            theirs(data)
        except b.CommandError:
            ok_theirs = False
        assert ok_ours == ok_theirs, (ours.__name__, data)


# --- main: arguments, the ROS loop, a clean exit -------------------------------------
def test_bad_arguments_exit_2(bridge_module: types.ModuleType) -> None:
    for argv in (["--zenoh-config", "x.json5", "--connect", "tcp/127.0.0.1:1"], ["--rate", "0"]):
        with pytest.raises(SystemExit) as info:
            bridge_module.parse_args(argv)
        assert info.value.code == 2
    args = bridge_module.parse_args(["--robot", "arm"])
    assert args.connect == ["tcp/127.0.0.1:7447"]
    assert args.robot == "arm"


def test_main_publishes_applies_and_exits_cleanly(monkeypatch: pytest.MonkeyPatch) -> None:
    port = free_port()
    ros = FakeRos(ticks=60)  # ~0.6 s at 100 Hz, then "SIGINT"
    intera, made = fake_intera(None)  # no gripper attached
    b = load_bridge(monkeypatch, ros, intera)
    listen = TransportSpec(listen=[f"tcp/127.0.0.1:{port}"])
    with open_session(config_from_spec(listen)) as daemon:
        states = States(daemon, "arm")
        stop = threading.Event()

        def send_commands() -> None:  # the daemon's control loop
            seq = 0
            while not stop.wait(0.02):
                daemon.put("legws/arm/bridge/command", payload(seq=seq))
                seq += 1

        sender = threading.Thread(target=send_commands)
        sender.start()
        try:
            code = b.main(
                ["--robot", "arm", "--connect", f"tcp/127.0.0.1:{port}", "--insecure-transport",
                 "__ns:=x"]
            )  # fmt: skip
        finally:
            stop.set()
            sender.join(timeout=5.0)
        assert code == 0
        assert ros.node == "legws_bridge"
        assert made["enable"].enable_calls == 1
        assert wait_for(lambda: len(states.snapshot()) > 10)
        assert states.errors == []
        assert all(s.gripper == "unknown" for s in states.snapshot())
        applied = velocities(made["limb"])
        assert COMMAND["dq"] in applied
        assert applied[-1] == [0.0] * 7  # stopped on the way out
        assert made["limb"].recorded()[-1][0] == "exit_control_mode"
        assert any("no gripper" in text for text in ros.logs)


def test_main_fails_in_one_line(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    good = tmp_path / "robot.json5"
    good.write_text('{ mode: "peer", scouting: { multicast: { enabled: false } } }')
    intera, _ = fake_intera(FakeGripper())

    def estopped(*args: object) -> FakeEnable:
        raise OSError("Robot is E-Stopped\nsecond line")

    intera.RobotEnable = estopped  # type: ignore[attr-defined]
    b = load_bridge(monkeypatch, FakeRos(), intera)
    assert isinstance(b.zenoh_config(str(good), [], []), zenoh.Config)
    for argv, needle in (
        (["--zenoh-config", str(bad)], "invalid zenoh configuration"),
        (["--zenoh-config", str(good)], "the transport is not authenticated"),
        (
            ["--zenoh-config", str(good), "--insecure-transport"],
            "cannot reach the robot: Robot is E-Stopped",
        ),
    ):
        capsys.readouterr()
        assert b.main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"intera_bridge.py: error: {needle}")
        assert err.count("\n") == 1


def test_refuses_an_unauthenticated_transport(
    bridge_module: types.ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before ROS or the robot: one line, exit 2 — the loopback default is not
    authenticated; the files of `legws secure init` are, by the same rule as the daemon's."""
    from legws_daemon.cli.main import run as legws
    from legws_daemon.transport.security import authentication_problem

    port = free_port()
    assert bridge_module.main(["--connect", f"tcp/127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "not authenticated: endpoint tcp/127.0.0.1:" in err and "--insecure-transport" in err
    assert legws(["secure", "init", str(tmp_path / "dep"), "--port", str(port)]) == 0
    for name in ("bridge", "daemon", "operator"):
        config = zenoh.Config.from_file(str(tmp_path / "dep" / f"{name}.json5"))
        assert bridge_module.authentication_problem(config) is None
    plain = bridge_module.zenoh_config(None, [f"tcp/127.0.0.1:{port}"], [])
    assert bridge_module.authentication_problem(plain) == authentication_problem(plain)
    assert json.loads(plain.get_json("scouting/gossip/enabled")) is False
