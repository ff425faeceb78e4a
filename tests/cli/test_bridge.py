"""``legws bridge fake``: bad input is one line and exit 2; a real run serves the adapter
and stops cleanly on SIGTERM or SIGINT."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.cli.bridge import bridge_transport, limits_line
from legws_daemon.formats.bridge_messages import bridge_keys
from legws_daemon.formats.profile import TransportSpec, load_profile
from legws_daemon.hardware.bridge import BridgeAdapter
from legws_daemon.scene.catalog import load_scene
from legws_daemon.transport.session import config_from_spec, open_session
from tests.cli.helpers import LEGWS, Result, assert_bad_input
from tests.net import free_port

REPO = Path(__file__).parents[2]
PROFILE = REPO / "hw_profiles" / "sawyer.toml"

Cli = Callable[..., Result]


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["--profile", "missing.toml"], ["missing.toml", "no such file"]),
        (["--profile", "moon"], ["unknown hardware profile 'moon'", "sawyer"]),
        (["--profile", PROFILE, "--listen", "tcp/localhost"], ["--listen", "invalid endpoint"]),
        (["--profile", PROFILE, "--connect", "http://x:1"], ["--connect", "invalid endpoint"]),
        (
            ["--profile", PROFILE, "--zenoh-config", "z.json5", "--connect", "tcp/1.2.3.4:7447"],
            ["--zenoh-config", "--connect"],
        ),
        (["--profile", PROFILE, "--scene", "moon"], ["unknown scene 'moon'", "desk"]),
        (["--profile", PROFILE, "--zenoh-config", "nowhere.json5"], ["nowhere.json5"]),
        (["--profile", PROFILE, "--rate", "0"], ["--rate"]),
        ([], ["--profile"]),
    ],
)
def test_bad_input_is_one_line(cli: Cli, argv: list[str | Path], needles: list[str]) -> None:
    assert_bad_input(cli("bridge", "fake", *argv), *needles)


def test_bad_profile_names_the_field(cli: Cli, tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(PROFILE.read_text(encoding="utf-8").replace('mode = "peer"', 'mode = "p"'))
    assert_bad_input(cli("bridge", "fake", "--profile", bad), str(bad), "transport.mode")


def test_transport_connects_to_the_daemon_by_default() -> None:
    profile = load_profile(PROFILE)
    spec = bridge_transport(profile, (), ())
    assert spec.listen == []
    assert spec.connect == ["tcp/127.0.0.1:7447"]
    assert spec.multicast_scouting is False
    spec = bridge_transport(profile, ("tcp/127.0.0.1:17690",), ())
    assert (spec.listen, spec.connect) == (["tcp/127.0.0.1:17690"], [])


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_serves_the_sawyer_adapter_and_stops_on_a_signal(signum: int) -> None:
    port = free_port()
    keys = bridge_keys("sawyer")
    heard = threading.Event()
    listen = TransportSpec(listen=[f"tcp/127.0.0.1:{port}"])
    with open_session(config_from_spec(listen)) as daemon:
        probe = daemon.declare_subscriber(keys["state"], lambda sample: heard.set())
        proc = subprocess.Popen(
            # the profile by name, as README and docs/daemon.md write it
            [str(LEGWS), "bridge", "fake", "--profile", "sawyer",
             "--connect", f"tcp/127.0.0.1:{port}", "--rate", "150"],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert heard.wait(60.0), "no state from `legws bridge fake`"
            probe.undeclare()  # type: ignore[no-untyped-call]
            with BridgeAdapter(load_profile(PROFILE), load_scene("desk"), daemon) as adapter:
                s0 = adapter.read_state()
                for _ in range(10):
                    adapter.send_velocity(adapter.read_state(), [0.0, 0.03, 0.0])
                    time.sleep(adapter.dt)
                adapter.stop()
                time.sleep(0.05)
                moved = adapter.read_state().ee_position - s0.ee_position
                assert moved[1] == pytest.approx(0.015, abs=5e-3)
                np.testing.assert_allclose(moved[[0, 2]], 0.0, atol=2e-3)
            proc.send_signal(signum)
            out, err = proc.communicate(timeout=20.0)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10.0)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert "fake bridge for 'sawyer'" in out
    assert f"connect tcp/127.0.0.1:{port}" in out
    assert "fake bridge stopped" in out
    # the profile's [bridge] limits and [workspace] box, printed at the start
    assert limits_line(load_profile(PROFILE)) in out.splitlines()
    assert "limits enforced: none" in out  # the adapter kept to them


def test_the_limits_line_names_every_limit() -> None:
    line = limits_line(load_profile(PROFILE))
    assert line == (
        "limits: joint speed <= 0.8 rad/s, EE speed <= 0.2 m/s, EE in x [0.3, 0.9] "
        "y [-0.5, 0.5] z [0.02, 0.55] m + 0.02 m, ttl <= 0.2 s, <= 60 commands/s (burst 5)"
    )


def test_the_command_module_loads_neither_zenoh_nor_mujoco() -> None:
    """``legws --help`` and the other commands do not pay for the bridge's imports."""
    code = (
        "import sys, legws_daemon.cli.bridge\n"
        "print('mujoco' in sys.modules, 'zenoh' in sys.modules)"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert proc.stdout.split() == ["False", "False"], proc.stderr


def test_a_bundle_runs_the_bridge_without_legws(tmp_path: Path) -> None:
    """``legws bridge bundle``: the bundled intera_bridge.py imports its guard, arm tables
    and chain from the bundle (ROS faked, zenoh real), not from this checkout."""
    out = tmp_path / "bundle"
    done = subprocess.run(
        [str(LEGWS), "bridge", "bundle", "--out", str(out)], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert (out / "bridge" / "chains" / "sawyer.json").is_file()
    stubs = tmp_path / "stubs"
    for pkg, names in {
        "rospy": [],
        "intera_core_msgs": ["EndpointState", "IOComponentCommand", "IODeviceStatus",
                             "IONodeStatus", "JointCommand", "RobotAssemblyState"],
        "sensor_msgs": ["JointState"],
        "std_msgs": ["Bool", "Empty", "Float64"],
    }.items():  # fmt: skip
        (stubs / pkg).mkdir(parents=True)
        (stubs / pkg / "__init__.py").write_text("")
        if names:
            (stubs / pkg / "msg.py").write_text("".join(f"class {n}: pass\n" for n in names))
    script = (
        "import sys, importlib.util\n"
        f"sys.path.insert(0, {str(stubs)!r})\n"
        f"path = {str(out / 'bridge/intera_bridge.py')!r}\n"
        "spec = importlib.util.spec_from_file_location('b', path)\n"
        "b = sys.modules['b'] = importlib.util.module_from_spec(spec)\n"
        "spec.loader.exec_module(b)\n"
        "print(b.guard_limits.__file__)\n"
        "print(b.arm.__module__, sys.modules['legws_daemon.arms'].__file__)\n"
        "print(b.load_chain().position([0.0] * 7))\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path, timeout=60
    )
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    assert lines[0] == str(out / "legws_daemon" / "safety" / "limits.py")
    assert lines[1].endswith(str(out / "legws_daemon" / "arms" / "__init__.py"))
    assert len(eval(lines[2])) == 3  # the chain's endpoint at zero
