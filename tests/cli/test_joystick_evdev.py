"""``legws joystick evdev``: --list, one-line errors (exit 2), --help, and a recorded run.

The input devices are the fakes of tests/joystick/fake_evdev.py (``LEGWS_INPUT_DIR`` points
at their folder and the device opener is swapped); everything else is the real command.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from evdev import ecodes

from legws_daemon.formats.messages import Buttons, JoystickMessage, parse
from legws_daemon.joystick import evdev_input
from tests.cli.helpers import Result, assert_bad_input
from tests.joystick.fake_evdev import FakeInputDir, keyboard, spacemouse_rel, xbox_pad
from tests.joystick.helpers import daemon_side
from tests.net import free_port

Cli = Callable[..., Result]


@pytest.fixture
def devices(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeInputDir]:
    """An empty fake input folder the command looks in, with the fake opener."""
    folder = tmp_path / "input"
    folder.mkdir()
    fake = FakeInputDir(folder)
    monkeypatch.setenv("LEGWS_INPUT_DIR", str(folder))
    monkeypatch.setattr(evdev_input, "open_device", fake.open)
    try:
        yield fake
    finally:
        fake.close_all()


def loopback_profile(tmp_path: Path, port: int) -> Path:
    """A stand-in profile of the test robot whose daemon listens on a loopback port."""
    path = tmp_path / "profile.toml"
    path.write_text(
        'schema_version = 1\nname = "test"\nrobot = "test_robot"\nadapter = "sim"\n'
        "[control]\nrate_hz = 50.0\n"
        f'[transport]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = []\n'
        "multicast_scouting = false\n",
        encoding="utf-8",
    )
    return path


def test_list_without_devices_exits_0_and_says_why(
    cli: Cli, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    empty = tmp_path / "input"
    empty.mkdir()
    monkeypatch.setenv("LEGWS_INPUT_DIR", str(empty))
    result = cli("joystick", "evdev", "--list")
    assert result.code == 0, result
    assert result.err == ""
    assert result.out.startswith(f"no input devices found in {empty}: none plugged in, or")
    assert "'input' group" in result.out
    assert result.out.count("\n") == 1
    monkeypatch.setenv("LEGWS_INPUT_DIR", str(tmp_path / "nope"))
    result = cli("joystick", "evdev", "--list")
    assert result.code == 0, result
    assert "does not exist" in result.out


def test_list_shows_each_device_and_its_mapping(cli: Cli, devices: FakeInputDir) -> None:
    devices.plug(0, keyboard())
    devices.plug(4, xbox_pad())
    devices.plug(11, spacemouse_rel())
    devices.forbid(5)
    result = cli("joystick", "evdev", "--list", "--profile", "no-such-profile")  # not loaded
    assert result.code == 0, result
    lines = result.out.splitlines()
    assert len(lines) == 4
    assert lines[0].endswith("mapping: none")
    assert '"Microsoft X-Box 360 pad" 045e:028e' in lines[1]
    assert lines[1].endswith("mapping: xbox")
    assert lines[2].startswith(f"{devices.path(5)}: cannot open: permission denied")
    assert lines[3].endswith("mapping: spacemouse")


def test_bad_input_is_one_line_and_exit_2(cli: Cli, devices: FakeInputDir, tmp_path: Path) -> None:
    assert_bad_input(cli("joystick", "evdev"), "no input devices found in")
    missing = devices.path(9)
    assert_bad_input(cli("joystick", "evdev", "--device", missing), missing, "no such device")
    assert_bad_input(
        cli("joystick", "evdev", "--mapping", "xbox"), "no input device matches mapping 'xbox'"
    )
    assert_bad_input(
        cli("joystick", "evdev", "--mapping", "ps5"), "unknown input mapping 'ps5'", "xbox"
    )
    bad = tmp_path / "bad.toml"
    bad.write_text('schema_version = 1\n[device]\nname = "x"\nmatch = ["x"]\n', encoding="utf-8")
    assert_bad_input(cli("joystick", "evdev", "--mapping", bad), str(bad), "buttons.enable")
    kbd = devices.plug(1, keyboard())
    assert_bad_input(
        cli("joystick", "evdev", "--device", kbd), kbd, "no shipped mapping", "--mapping"
    )
    assert_bad_input(
        cli("joystick", "evdev", "--device", kbd, "--mapping", "xbox"), kbd, "lacks BTN_TL"
    )
    assert_bad_input(cli("joystick", "evdev", "--rate", "0"), "--rate")


def test_help_explains_hold_to_run_and_the_options(cli: Cli) -> None:
    result = cli("joystick", "evdev", "--help")
    assert result.code == 0
    text = " ".join(result.out.split())
    for needle in (
        "gamepad",
        "SpaceMouse",
        "Hold-to-run",
        "enable released",
        "Unplugging",
        "--mapping NAME|FILE",
        "--device PATH",
        "--list",
        "'input' group",
        "--duration",
    ):
        assert needle in text, needle


def test_a_run_publishes_the_pad_and_stops_on_unplug(
    cli: Cli, devices: FakeInputDir, tmp_path: Path
) -> None:
    node = xbox_pad()
    path = devices.plug(3, node)
    out = tmp_path / "out.jsonl"

    def lines() -> int:
        return len(out.read_text().splitlines()) if out.exists() else 0

    def wait_lines(count: int) -> None:
        deadline = time.monotonic() + 10.0
        while lines() < count and time.monotonic() < deadline:
            time.sleep(0.005)

    def play() -> None:
        wait_lines(3)  # the run publishes (after the command's wait for a subscriber)
        node.frame(
            (ecodes.EV_KEY, ecodes.BTN_TL, 1),
            (ecodes.EV_ABS, ecodes.ABS_Y, -32768),
            (ecodes.EV_KEY, ecodes.BTN_SOUTH, 1),
        )
        wait_lines(lines() + 10)
        devices.unplug(path)

    port = free_port()
    player = threading.Thread(target=play)
    with daemon_side(port, status_fields={}):  # the daemon's side: a subscriber, a status
        player.start()
        try:
            result = cli(
                "joystick",
                "evdev",
                "--profile",
                loopback_profile(tmp_path, port),
                "--duration",
                "1.5",
                "--record",
                out,
            )
        finally:
            player.join(10.0)
    assert result.code == 0, result
    assert result.out == ""
    err = result.err.splitlines()
    assert any('xbox mapping on "Microsoft X-Box 360 pad"' in line for line in err), err
    assert any("hold BTN_TL to steer" in line for line in err)
    assert any(line.startswith("legws: input device lost") for line in err)
    assert "1 unplugged, 0 reconnected" in err[-1]
    assert err[-1].startswith("legws: evdev joystick stopped: 4 events, 0 dropped")
    messages = [parse(JoystickMessage, line, "out") for line in out.read_text().splitlines()]
    steering = [m for m in messages if m.buttons.enable]
    assert steering
    assert all(m.axes == pytest.approx((1.0, 0.0, 0.0), abs=1e-4) for m in steering)
    assert all(m.buttons == Buttons(enable=True, confirm=True) for m in steering)
    first, last = messages.index(steering[0]), messages.index(steering[-1])
    assert all(not m.buttons.enable and m.axes == (0.0, 0.0, 0.0) for m in messages[:first])
    after = messages[last + 1 :]
    assert len(after) >= 5  # unplugged for the rest of the run: no input
    assert all(not m.buttons.enable and m.axes == (0.0, 0.0, 0.0) for m in after)
    assert messages[-1].bye
    assert [m.seq for m in messages] == list(range(len(messages)))
    assert messages[0].source.startswith("evdev-xbox:")
