"""The robot-side Intera bridge, imported with fake ``rospy``/``intera_interface`` modules.

Only the hardware edge is faked (ROS and the Intera SDK); zenoh is real (a session
without endpoints, or two loopback peers), and what the bridge publishes is checked with
the daemon's own validator.
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
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.formats import bridge_messages as contract
from legws_daemon.formats.bridge_messages import BridgeCommand, BridgeState, parse_state
from legws_daemon.formats.messages import dump
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.transport.session import config_from_spec, open_session
from tests.net import free_port

BRIDGE = Path(__file__).parents[2] / "bridge" / "intera_bridge.py"
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
class FakeLimb:
    """``intera_interface.Limb``: joint state in, every command recorded."""

    def __init__(self, side: str = "right") -> None:
        assert side == "right"
        self.q = list(HOME_Q)
        self.calls: list[tuple[str, dict[str, float] | None]] = []
        self._lock = threading.Lock()

    def joint_angles(self) -> dict[str, float]:
        return {f"right_j{i}": v for i, v in enumerate(self.q)}

    def joint_velocities(self) -> dict[str, float]:
        return {f"right_j{i}": 0.0 for i in range(7)}

    def set_joint_velocities(self, velocities: dict[str, float]) -> None:
        with self._lock:
            self.calls.append(("velocities", dict(velocities)))

    def exit_control_mode(self) -> None:
        with self._lock:
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
    """A fake ``intera_interface`` module and the objects it hands out."""
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
    monkeypatch.setitem(sys.modules, "intera_interface", intera)
    spec = importlib.util.spec_from_file_location("intera_bridge_under_test", BRIDGE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    return module


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
            state = parse_state(sample.payload.to_bytes(), self.key)
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
    assert outside == {"rospy", "intera_interface", "zenoh"}


def test_constants_are_the_contract(bridge_module: types.ModuleType) -> None:
    b = bridge_module
    assert b.JOINT_NAMES == contract.JOINT_NAMES
    assert b.SPEED_LIMITS == contract.JOINT_SPEED_LIMITS
    assert b.LOWER == contract.JOINT_LOWER
    assert b.UPPER == contract.JOINT_UPPER
    assert b.MAX_TTL == contract.MAX_TTL
    assert b.SPEED_TOLERANCE == contract.SPEED_TOLERANCE


# --- message checks ----------------------------------------------------------------
def test_accepts_what_the_daemon_sends(bridge_module: types.ModuleType) -> None:
    sent = BridgeCommand.model_validate({**COMMAND, "dq": list(contract.JOINT_SPEED_LIMITS)})
    command = bridge_module.parse_command(dump(sent))
    assert command.dq == contract.JOINT_SPEED_LIMITS
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
        ours = contract.parse_command(raw, "fuzz")
    with contextlib.suppress(bridge_module.CommandError):
        theirs = bridge_module.parse_command(raw)
    assert (ours is None) == (theirs is None), raw
    if ours is not None:
        assert theirs.dq == ours.dq
        assert theirs.ttl == ours.ttl
        assert theirs.gripper == ours.gripper


def test_state_messages_are_valid_for_the_daemon(bridge_module: types.ModuleType) -> None:
    raw = bridge_module.state_message(5, 12.5, HOME_Q, [0.0] * 7, "unknown", True, False)
    state = parse_state(raw, "state")
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
    b: types.ModuleType, session: zenoh.Session
) -> tuple[Any, FakeLimb, FakeEnable, FakeGripper, Clock]:
    limb, enable, gripper, clock = FakeLimb(), FakeEnable(), FakeGripper(), Clock()
    bridge = b.SawyerBridge(
        session, "sawyer", limb, b.GripperDriver(gripper), enable, clock=clock, wall=clock
    )
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
    bridge, limb, _, _, clock = make_bridge(bridge_module, session)
    limb.q[0] = contract.JOINT_UPPER[0]
    limb.q[3] = contract.JOINT_LOWER[3] + 0.005
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
            code = b.main(["--robot", "arm", "--connect", f"tcp/127.0.0.1:{port}", "__ns:=x"])
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
        (["--zenoh-config", str(good)], "cannot reach the robot: Robot is E-Stopped"),
    ):
        capsys.readouterr()
        assert b.main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"intera_bridge.py: error: {needle}")
        assert err.count("\n") == 1
