"""``legws joystick``: bad input exits 2 with one line; real runs publish and stop cleanly."""

from __future__ import annotations

import json
import os
import pty
import select
import signal
import subprocess
import termios
from collections.abc import Callable
from pathlib import Path

from legws_daemon.formats.messages import Buttons, JoystickMessage, parse
from tests.cli.helpers import LEGWS, Result, assert_bad_input
from tests.joystick.helpers import KEY, ROBOT, daemon_side
from tests.net import free_port

Cli = Callable[..., Result]
REPO = Path(__file__).resolve().parents[2]
SIM = REPO / "hw_profiles" / "sim.toml"


def profile(tmp_path: Path, listen: list[str], **control: float) -> Path:
    """A profile for the test robot whose daemon listens on ``listen``."""
    lines = [
        "schema_version = 1",
        'name = "test"',
        f'robot = "{ROBOT}"',
        'adapter = "sim"',
        "[control]",
        *(f"{k} = {v!r}" for k, v in control.items()),
        "[transport]",
        f"listen = {json.dumps(listen)}",
        "connect = []",
        "multicast_scouting = false",
    ]
    path = tmp_path / "profile.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def recording(tmp_path: Path, count: int, dt: float = 0.05) -> Path:
    path = tmp_path / "rec.jsonl"
    lines = [
        json.dumps(
            {
                "schema": 1,
                "seq": i,
                "stamp": 1000.0 + i * dt,
                "axes": [0.1 + 0.1 * (i % 5), 0.0, 0.0],  # never zero
                "buttons": {"cancel": i == 1, "confirm": False},
                "source": "rec",
            }
        )
        for i in range(count)
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_replay_of_a_missing_file(cli: Cli, tmp_path: Path) -> None:
    missing = tmp_path / "missing.jsonl"
    assert_bad_input(
        cli("joystick", "replay", missing, "--profile", SIM), str(missing), "no such file"
    )


def test_missing_profile(cli: Cli, tmp_path: Path) -> None:
    nope = tmp_path / "nope.toml"
    rec = recording(tmp_path, 2)
    assert_bad_input(cli("joystick", "replay", rec, "--profile", nope), str(nope), "no such file")


def test_bad_profile_names_file_and_field(cli: Cli, tmp_path: Path) -> None:
    bad = profile(tmp_path, ["tcp/127.0.0.1:7447"], rate_hz=-5.0)
    for argv in (
        ("replay", recording(tmp_path, 2)),
        ("can", "--interface", "virtual", "--channel", "x"),
        ("keyboard",),
    ):
        assert_bad_input(cli("joystick", *argv, "--profile", bad), str(bad), "control.rate_hz")


def test_bad_recording_line_names_file_line_and_field(cli: Cli, tmp_path: Path) -> None:
    rec = recording(tmp_path, 3)
    lines = rec.read_text().splitlines()
    data = json.loads(lines[1])
    data["axes"][1] = "fast"
    lines[1] = json.dumps(data)
    rec.write_text("\n".join(lines) + "\n")
    assert_bad_input(cli("joystick", "replay", rec, "--profile", SIM), f"{rec}:2", "axes[1]")


def test_keyboard_without_a_terminal(cli: Cli) -> None:
    assert_bad_input(cli("joystick", "keyboard", "--profile", SIM), "stdin", "not a terminal")


def test_can_on_a_missing_socketcan_device(cli: Cli) -> None:
    result = cli(
        "joystick", "can", "--interface", "socketcan", "--channel", "legwsnope0", "--profile", SIM
    )
    assert_bad_input(result, "cannot open socketcan channel 'legwsnope0'")


def test_bad_zenoh_config_and_bad_options(cli: Cli, tmp_path: Path) -> None:
    rec = recording(tmp_path, 2)
    bad = tmp_path / "z.json5"
    bad.write_text("{ mode: ")
    assert_bad_input(
        cli("joystick", "replay", rec, "--profile", SIM, "--zenoh-config", bad),
        str(bad),
        "invalid zenoh configuration",
    )
    assert_bad_input(cli("joystick", "replay", rec, "--speed", "0"), "--speed")
    assert_bad_input(cli("joystick", "keyboard", "--rate", "0"), "--rate")
    assert_bad_input(cli("joystick", "keyboard", "--step", "2"), "--step")
    assert_bad_input(cli("joystick", "can", "--profile", SIM), "--channel")
    assert_bad_input(cli("joystick", "replay", rec, "--rate", "5"), "--rate")  # no such option


def test_can_on_a_quiet_virtual_bus_publishes_only_the_final_zero(cli: Cli, tmp_path: Path) -> None:
    port = free_port()
    out = tmp_path / "out.jsonl"
    with daemon_side(port, KEY, status_fields={}):
        result = cli(
            "joystick",
            "can",
            "--interface",
            "virtual",
            "--channel",
            "legws-quiet",
            "--profile",
            profile(tmp_path, [f"tcp/127.0.0.1:{port}"]),
            "--duration",
            "0.3",
            "--record",
            out,
        )
    assert result.code == 0, result
    assert result.out == ""
    assert "0 frames, 0 rejected, 0 messages published" in result.err
    # what the daemon does, on one line (a pipe here: a line per change)
    assert "legws: daemon: teleop · top - · commit - · phase - · operator none" in result.err
    messages = [parse(JoystickMessage, line, "out") for line in out.read_text().splitlines()]
    assert [m.axes for m in messages] == [(0.0, 0.0, 0.0)]


def _start(*argv: str | Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [str(LEGWS), *map(str, argv)],
        cwd=REPO,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(proc: subprocess.Popen[str], timeout: float = 30.0) -> Result:
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
    return Result(proc.returncode, out, err)


def test_replay_process_reaches_a_listening_daemon(tmp_path: Path) -> None:
    port = free_port()
    prof = profile(tmp_path, [f"tcp/127.0.0.1:{port}"])
    rec = recording(tmp_path, 6)
    out = tmp_path / "out.jsonl"
    with daemon_side(port, KEY, status_fields={}) as inbox:
        proc = _start("joystick", "replay", rec, "--profile", prof, "--record", out)
        result = _finish(proc)
        got = inbox.wait_for(7)
    assert result.code == 0, result
    assert result.out == ""
    assert "replay stopped: 6 messages published" in result.err
    recorded = [parse(JoystickMessage, line, "rec") for line in rec.read_text().splitlines()]
    assert [m.axes for m in got] == [m.axes for m in recorded] + [(0.0, 0.0, 0.0)]
    assert got[1].buttons == Buttons(cancel=True)
    assert [m.seq for m in got] == list(range(7))
    assert got[0].source.startswith("replay:")
    written = [parse(JoystickMessage, line, "out") for line in out.read_text().splitlines()]
    assert written == got


def test_sigterm_ends_a_looping_replay_with_a_zero_message_and_exit_0(tmp_path: Path) -> None:
    port = free_port()
    prof = profile(tmp_path, [f"tcp/127.0.0.1:{port}"])
    rec = recording(tmp_path, 4)
    with daemon_side(port, KEY, status_fields={}) as inbox:
        proc = _start("joystick", "replay", rec, "--loop", "--profile", prof, "--duration", "60")
        try:
            inbox.wait_for(10, timeout=20.0)  # looping: more than the file holds
            proc.send_signal(signal.SIGTERM)
        finally:
            result = _finish(proc)
        got = inbox.wait_until(lambda m: m[-1].axes == (0.0, 0.0, 0.0))
    assert result.code == 0, result
    assert "Traceback" not in result.err
    assert all(m.axes != (0.0, 0.0, 0.0) for m in got[:-1])
    assert [m.seq for m in got] == list(range(len(got)))


def test_keyboard_process_on_a_pseudo_terminal(tmp_path: Path) -> None:
    """Keys typed on a real (pseudo-)terminal steer; q quits; the terminal is restored."""
    port = free_port()
    prof = profile(tmp_path, [f"tcp/127.0.0.1:{port}"])
    master, slave = pty.openpty()
    before = termios.tcgetattr(slave)
    try:
        with daemon_side(port, KEY, status_fields={}) as inbox:
            proc = subprocess.Popen(
                [str(LEGWS), "joystick", "keyboard", "--profile", prof],
                cwd=REPO,
                stdin=slave,
                stdout=subprocess.PIPE,
                stderr=slave,
                text=True,
            )
            try:
                inbox.wait_for(1, timeout=20.0)  # running: zero deflection until a key
                os.write(master, b"w")
                inbox.wait_until(lambda m: m[-1].axes == (1.0, 0.0, 0.0))
                os.write(master, b"c")
                inbox.wait_until(lambda m: m[-1].buttons.cancel)
                os.write(master, b"q")
            finally:
                result = _finish(proc)
            got = inbox.wait_until(lambda m: m[-1].axes == (0.0, 0.0, 0.0))
        assert result.code == 0, result
        assert termios.tcgetattr(slave) == before
        assert sum(m.buttons.cancel for m in got) == 1  # in one message only
        assert select.select([master], [], [], 5.0)[0]
        shown = os.read(master, 65536).decode(errors="replace")
        assert "keys: w/s +x/-x" in shown
        assert "x +1.00  y +0.00  z +0.00" in shown
        assert "Traceback" not in shown
    finally:
        os.close(master)
        os.close(slave)
