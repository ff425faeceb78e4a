"""Issue 16's reproductions, each a regression test: devices and links as outputs, endless
and blocking files as inputs, full disks, terminal escapes, duplicate keys, a Dask
scheduler that is not there. (Task graphs, the robot model, cached plans and the caps
on goals and parameters have their own tests beside their modules; the generated
corpus in ``test_hostile_corpus.py`` runs all of it through real processes.)
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from legws_daemon.cli.main import run
from tests.cli.helpers import EXAMPLE_GOALSET, LEGWS, Result, assert_bad_input
from tests.daemon.procs import monitor, ready, start, stop, write_profile
from tests.net import free_port

REPO = Path(__file__).parents[2]


Cli = Callable[..., Result]


@pytest.fixture
def cli(capfd: pytest.CaptureFixture[str]) -> Iterator[Cli]:
    def call(*argv: str | Path) -> Result:
        code = run([str(a) for a in argv])
        out, err = capfd.readouterr()
        return Result(code, out, err)

    return call


@pytest.fixture
def device(tmp_path: Path) -> Path:
    """A character device with /dev/null's numbers, private to the test (as root), so that
    a regression harms only it; else a link to /dev/null (never written: refused)."""
    node = tmp_path / "null"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        node.symlink_to("/dev/null")
    return node


def unchanged(path: Path, before: os.stat_result) -> bool:
    after = os.lstat(path)
    return (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)


# --- outputs: nothing but a regular file is ever replaced -------------------------------------


def test_export_goals_onto_a_device_or_a_link_to_one_is_refused(
    cli: Cli, tmp_path: Path, device: Path
) -> None:
    link = tmp_path / "goals.json"
    link.symlink_to(device)
    for target in (device, link):
        before = os.lstat(target)
        line = assert_bad_input(cli("certify", "--scene", "desk", "--export-goals", target))
        assert "character device" in line and "refusing to write over it" in line
        assert unchanged(target, before)


def test_export_goals_through_a_link_replaces_its_target(cli: Cli, tmp_path: Path) -> None:
    target = tmp_path / "real.json"
    target.write_text("{}")
    link = tmp_path / "goals.json"
    link.symlink_to(target)
    result = cli("certify", "--scene", "desk", "--export-goals", link)
    assert result.code == 0, result
    assert link.is_symlink() and "goals" in json.loads(target.read_text())


def test_render_and_the_diagram_refuse_a_device(cli: Cli, device: Path) -> None:
    before = os.lstat(device)
    assert_bad_input(cli("render", "--scene", "desk", "-o", device), "character device")
    assert_bad_input(cli("taskgraph", "show", "tea", "--png", device), "character device")
    assert unchanged(device, before)


def test_eval_out_naming_an_existing_file_is_one_line(cli: Cli, tmp_path: Path) -> None:
    existing = tmp_path / "results"
    existing.write_text("keep me\n")
    result = cli("eval", "--scene", "desk", "--layouts", "random:1", "--out", existing, "--quiet")
    assert_bad_input(result, "--out", "is a file")
    assert existing.read_text() == "keep me\n"


def test_recording_finish_on_a_device_says_what_it_is(cli: Cli, device: Path) -> None:
    line = assert_bad_input(cli("recording", "finish", device))
    assert "character device" in line and "does not exist" not in line


# --- inputs: endless and blocking files are refused at once -----------------------------------


def test_goal_set_from_dev_zero_is_refused_without_reading(cli: Cli, tmp_path: Path) -> None:
    link = tmp_path / "goals.json"
    link.symlink_to("/dev/zero")
    assert_bad_input(cli("certify", link), "is a character device, expected a regular file")
    assert_bad_input(cli("certify", "/dev/zero"), "character device")


def test_a_fifo_as_input_does_not_block(cli: Cli, tmp_path: Path) -> None:
    fifo = tmp_path / "goals.json"
    os.mkfifo(fifo)
    assert_bad_input(cli("certify", fifo), "is a FIFO, expected a regular file")


def test_a_plan_linked_to_dev_zero_or_a_fifo_is_refused(cli: Cli, tmp_path: Path) -> None:
    profile = tmp_path / "sim.toml"
    text = (REPO / "hw_profiles" / "sim.toml").read_text()
    profile.write_text(text.replace("7447", str(free_port())))
    for what in ("zero", "fifo"):
        folder = tmp_path / what
        folder.mkdir()
        if what == "zero":
            (folder / "plan.json").symlink_to("/dev/zero")
        else:
            os.mkfifo(folder / "plan.json")
        result = cli("daemon", "--profile", profile, "--taskgraph", "tea", "--plan", folder)
        assert_bad_input(result, "plan.json", "expected a regular file")


def test_a_huge_input_is_refused_by_its_size(cli: Cli, tmp_path: Path) -> None:
    big = tmp_path / "goals.json"
    with big.open("wb") as f:
        f.truncate(2 * 1024 * 1024)
    assert_bad_input(cli("certify", big), "more than the 1 MiB allowed for a goal set file")


# --- text: duplicate keys, terminal escapes ---------------------------------------------------


def test_duplicate_json_keys_are_refused(cli: Cli, tmp_path: Path) -> None:
    text = json.dumps(EXAMPLE_GOALSET)
    doubled = tmp_path / "goals.json"
    doubled.write_text('{"x0": {"position": [0, 0, 0.3], "quaternion": [0, 1, 0, 0]}, ' + text[1:])
    assert_bad_input(cli("certify", doubled), "the key 'x0' appears twice")


@pytest.mark.parametrize("bad", ["\x1b[2J", "\r", "\x00", "\u202e", "\u2066", "\x9b"])
def test_control_and_bidi_characters_in_names_are_refused(
    cli: Cli, tmp_path: Path, bad: str
) -> None:
    doc = json.loads(json.dumps(EXAMPLE_GOALSET))
    doc["goals"][0]["name"] = f"mug{bad}evil"
    path = tmp_path / "goals.json"
    path.write_text(json.dumps(doc))
    line = assert_bad_input(cli("certify", path), "goals[0].name", f"U+{ord(bad[0]):04X}")
    assert bad not in line


def test_an_error_line_never_carries_a_terminal_escape(cli: Cli) -> None:
    line = assert_bad_input(cli("certify", "--scene", "desk\x1b[2J\u202e"))
    assert "\x1b" not in line and "\u202e" not in line and "\\x1b" in line


# --- full disks: whole lines, one error -------------------------------------------------------


def test_sim_user_record_onto_a_full_disk_is_one_error_line(
    tmp_path: Path, small_disk: Path
) -> None:
    with (small_disk / "filler").open("wb") as f:  # leave a few messages' worth of room
        f.write(b"x" * (1024 * 1024 - 6 * 1024))
    record = small_disk / "session.jsonl"
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(["daemon", "--profile", str(profile), "--scene", "desk"], tmp_path / "d.log")
    try:
        with monitor(port, "sawyer_sim") as m:  # the user steers once the daemon is up
            assert m.wait_for(ready, 30), (tmp_path / "d.log").read_text()
        out = subprocess.run(
            [str(LEGWS), "joystick", "sim-user", "--profile", str(profile), "--record",
             str(record), "--duration", "30"],
            capture_output=True, text=True, timeout=90, check=False,
        )  # fmt: skip
    finally:
        stop(daemon)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith(f"legws: error: {record}: cannot write: No space left"), out.stderr
    lines = record.read_text().splitlines(keepends=True)
    assert lines and all(line.endswith("\n") for line in lines)
    assert all(json.loads(line)["schema"] == 1 for line in lines)


# --- a Dask scheduler that is not there -------------------------------------------------------


def test_dask_pointing_at_nothing_prints_only_the_error(tmp_path: Path) -> None:
    port = free_port()
    out = subprocess.run(
        [str(LEGWS), "optimize", "--all", "--scene", "desk", "--dask", f"tcp://127.0.0.1:{port}",
         "--iterations", "1", "--out", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert_bad_input(Result(out.returncode, out.stdout, out.stderr), "cannot reach the Dask")
    assert "runs" not in out.stderr.split("--dask")[0]  # no progress bar before it


def test_dask_address_that_is_not_one_is_refused(cli: Cli) -> None:
    result = cli("optimize", "--all", "--scene", "desk", "--dask", "nowhere at all")
    assert_bad_input(result, "--dask", "expected tcp://HOST:PORT")


# --- numbers that are not numbers -------------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["daemon", "--scene", "desk", "--duration", "inf"],
        ["daemon", "--scene", "desk", "--rate", "nan"],
        ["joystick", "sim-user", "--sigma", "nan"],
        ["replay", "x.rrd", "--beta", "inf"],
    ],
)
def test_non_finite_options_are_refused(cli: Cli, argv: list[str]) -> None:
    assert_bad_input(cli(*argv), "is not a finite number")
