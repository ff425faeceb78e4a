"""The robot side of a person's session: the command lines of the daemon and the calibration
(checked against the real commands' options), and the child processes."""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path
from typing import Any

import click
import pytest

from legws_daemon.cli.daemon import daemon_cmd
from legws_daemon.cli.operator_calibrate import calibrate_cmd
from legws_daemon.errors import InputError
from legws_daemon.study import rig
from legws_daemon.study.rig import Child, RigSpec

GRPC = "rerun+http://127.0.0.1:9091/proxy"


def parsed(command: click.Command, args: list[str]) -> dict[str, Any]:
    """The options ``command`` parses from ``args`` (it is not run)."""
    with command.make_context(command.name or "x", list(args)) as ctx:
        return dict(ctx.params)


def test_a_scene_trial_is_the_scene_its_assistance_and_its_recording(tmp_path: Path) -> None:
    rec = tmp_path / "recordings" / "step-003.rrd"
    args = RigSpec("sim").daemon_args("scene", "desk", "commit", rec)
    assert args == ["daemon", "--profile", "sim", "--scene", "desk", "--assist", "commit",
                    "--rerun", f"save:{rec}"]  # fmt: skip
    params = parsed(daemon_cmd, args[1:])
    assert params["scene"] == "desk" and params["taskgraph"] is None
    assert params["assist"] == "commit" and params["rerun_target"] == (f"save:{rec}",)
    assert params["plan_arg"] is None and params["layout_file"] is None
    assert not params["allow_motion"] and not params["insecure_transport"]
    # a layout file for the scene; a plan is a task graph's only
    layout = tmp_path / "layouts" / "step-003.json"
    args = RigSpec("sim").daemon_args("scene", "desk", "blend", rec, layout=layout, plan=tmp_path)
    assert "--plan" not in args
    params = parsed(daemon_cmd, args[1:])
    assert params["layout_file"] == layout and params["assist"] == "blend"


def test_a_task_graph_trial_runs_its_plan_or_none(tmp_path: Path) -> None:
    rec = tmp_path / "r.rrd"
    spec = RigSpec("sim")
    layout = tmp_path / "layout.json"
    args = spec.daemon_args("taskgraph", "tea", "hindsight", rec, layout=layout)
    params = parsed(daemon_cmd, args[1:])
    assert params["taskgraph"] == "tea" and params["scene"] is None
    assert params["plan_arg"] == "none" and params["layout_file"] == layout
    plan = tmp_path / "plan"
    args = spec.daemon_args("taskgraph", "taskgraphs/tea.toml", "commit", rec, plan=plan)
    assert args[args.index("--plan") + 1] == str(plan)
    params = parsed(daemon_cmd, args[1:])
    assert params["plan_arg"] == str(plan) and params["layout_file"] is None
    assert params["taskgraph"] == "taskgraphs/tea.toml"


def test_the_operator_the_arm_and_the_profile_flags_are_passed_on(tmp_path: Path) -> None:
    rec, op, zenoh = tmp_path / "r.rrd", tmp_path / "operator.json", tmp_path / "z.json5"
    spec = RigSpec("hw_profiles/sawyer.toml", zenoh, robot="sawyer_real", arm="panda",
                   allow_motion=True, insecure_transport=True)  # fmt: skip
    args = spec.daemon_args("scene", "desk", "commit", rec, operator=op)
    params = parsed(daemon_cmd, args[1:])
    assert params["profile"] == "hw_profiles/sawyer.toml" and params["zenoh_config"] == zenoh
    assert params["robot"] == "panda" and params["operator_file"] == op
    assert params["allow_motion"] and params["insecure_transport"]
    assert args.count("--allow-motion") == 1 and args.count("--insecure-transport") == 1
    # the defaults pass none of these
    plain = RigSpec("sim").daemon_args("scene", "desk", "commit", rec)
    for flag in ("--zenoh-config", "--robot", "--operator", "--allow-motion",
                 "--insecure-transport", "--layout"):  # fmt: skip
        assert flag not in plain, flag


def test_with_a_viewer_every_process_also_logs_into_it(tmp_path: Path) -> None:
    rec = tmp_path / "r.rrd"
    spec = RigSpec("sim", viewer=GRPC)
    args = spec.daemon_args("scene", "desk", "commit", rec)
    assert args[-4:] == ["--rerun", f"save:{rec}", "--rerun", f"connect:{GRPC}"]
    assert parsed(daemon_cmd, args[1:])["rerun_target"] == (f"save:{rec}", f"connect:{GRPC}")
    cal = spec.calibrate_args(tmp_path / "operator.json", "P07", "desk", 20, 3, rec)
    assert cal.count("--rerun") == 2 and cal[-1] == f"connect:{GRPC}"


def test_the_calibration_is_legws_operator_calibrate_of_the_participant(tmp_path: Path) -> None:
    out, rec, zenoh = tmp_path / "P07" / "operator.json", tmp_path / "cal.rrd", tmp_path / "z"
    spec = RigSpec("sim", zenoh, allow_motion=True)
    args = spec.calibrate_args(out, "P07", "breakfast", 12, 42, rec)
    assert args[:2] == ["operator", "calibrate"]
    params = parsed(calibrate_cmd, args[2:])
    assert params["out"] == out and params["name"] == "P07"
    assert params["scene"] == "breakfast" and params["count"] == 12 and params["seed"] == 42
    assert params["rerun_target"] == (f"save:{rec}",)
    assert params["profile"] == "sim" and params["zenoh_config"] == zenoh
    assert params["allow_motion"] and not params["insecure_transport"]


def wait_exit(child: Child, timeout: float = 30.0) -> int:
    deadline = time.monotonic() + timeout
    while (code := child.poll()) is None:
        assert time.monotonic() < deadline, "the child did not exit"
        time.sleep(0.02)
    return code


def test_a_legws_child_runs_this_interpreters_package_into_its_log(tmp_path: Path) -> None:
    assert (sys.executable, "-m", "legws_daemon") == rig.LEGWS
    log = tmp_path / "version.log"
    log.write_text("an earlier run\n")
    child = Child(["--version"], log, "the version")
    assert child.pid > 0
    assert wait_exit(child) == 0
    assert child.last_line().startswith("legws, version ")
    assert log.read_text().startswith("an earlier run\n")  # appended, not replaced
    assert child.stop() == 0  # an exited process: its code, nothing sent
    assert child.stop(signal.SIGINT, grace=0.1) == 0


def test_an_early_exit_is_an_error_quoting_the_last_line(tmp_path: Path) -> None:
    log = tmp_path / "daemon.log"
    child = Child(["no-such-command"], log, "the daemon of step 3")
    assert wait_exit(child) == 2
    err = child.failed()
    assert isinstance(err, InputError) and err.source == str(log)
    assert "the daemon of step 3 exited (code 2): legws: error: No such command" in str(err)


def test_the_last_line_is_terminal_safe_and_empty_without_a_log(tmp_path: Path) -> None:
    log = tmp_path / "x.log"
    child = Child(["--version"], log, "x")
    wait_exit(child)
    with log.open("ab") as f:
        f.write(b"bad \x1b[2J\x07 line\n\n   \n")
    line = child.last_line()
    assert line.startswith("bad ") and "\x1b" not in line and "\x07" not in line
    assert "line" in line
    log.unlink()
    assert child.last_line() == ""
    assert "no output" in str(child.failed())


PROBE = (
    "import os, sys; "
    "print(os.environ.get('PYTHONUNBUFFERED'), repr(sys.stdin.read()), "
    "os.getpgid(0) == os.getpid(), sys.argv[1:])"
)


def test_a_child_leads_its_own_group_unbuffered_with_no_stdin(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(rig, "LEGWS", (sys.executable, "-c", PROBE))
    child = Child(["daemon", "--scene", "desk"], tmp_path / "probe.log", "probe")
    assert wait_exit(child) == 0
    assert child.last_line() == "1 '' True ['daemon', '--scene', 'desk']"


def started(child: Child, log: Path, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while "ready" not in log.read_text():
        assert child.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.02)


def test_stop_ends_a_running_child_with_sigterm(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    code = "import time; print('ready'); time.sleep(60)"
    monkeypatch.setattr(rig, "LEGWS", (sys.executable, "-c", code))
    log = tmp_path / "sleep.log"
    child = Child([], log, "sleeper")
    started(child, log)
    began = time.monotonic()
    assert child.stop(grace=10.0) == -signal.SIGTERM
    assert time.monotonic() - began < 5.0
    assert child.poll() == -signal.SIGTERM


def test_stop_kills_a_child_that_does_not_exit_within_the_grace(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    code = (
        "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
        "print('ready'); time.sleep(60)"
    )
    monkeypatch.setattr(rig, "LEGWS", (sys.executable, "-c", code))
    log = tmp_path / "stubborn.log"
    child = Child([], log, "stubborn")
    started(child, log)
    began = time.monotonic()
    assert child.stop(grace=0.3) == -signal.SIGKILL
    assert 0.3 <= time.monotonic() - began < 5.0
