"""The ``legws`` group: every command is found by name and loads only what it needs."""

from __future__ import annotations

import subprocess
import sys

import click
import pytest

from legws_daemon.cli.main import COMMANDS, cli, run


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_is_found_under_its_own_name(name: str) -> None:
    command = cli.get_command(click.Context(cli), name)
    assert isinstance(command, click.Command)
    assert command.name == name


def test_help_lists_every_command_and_an_unknown_one_is_one_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert run(["--help"]) == 0
    listed = capsys.readouterr().out.split("Commands:")[1].split()
    assert set(COMMANDS) <= set(listed)
    assert run(["certfy"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No such command 'certfy'" in err


def test_sim_user_is_a_joystick_publisher(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["joystick", "--help"]) == 0
    out = capsys.readouterr().out
    for publisher in ("sim-user", "keyboard", "can", "evdev", "replay"):
        assert publisher in out


def test_a_publisher_does_not_load_the_optimiser_rerun_or_mujoco() -> None:
    probe = (
        "import sys\n"
        "from legws_daemon.cli.main import run\n"
        "code = run(['joystick', 'keyboard', '--help'])\n"
        "heavy = [m for m in ('ribs', 'rerun', 'mujoco', 'matplotlib') if m in sys.modules]\n"
        "print(code, ','.join(heavy))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True
    ).stdout
    assert out.splitlines()[-1].strip() == "0"
