"""Every error shown, each with its line; a typo says ``did you mean``; a busy port is one line.

Through the real command line (the installed ``legws`` script as a subprocess, or its
``run`` in-process): exit 2, nothing on stdout, the exact ``legws: error:`` lines on
stderr — one per error, ``FILE:LINE: field: what was expected`` — and no traceback or
library source path.
"""

from __future__ import annotations

import json
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from legws_daemon.formats.scene_file import MARKER_DICTIONARIES
from legws_daemon.scene.catalog import load_scene, scene_names
from legws_daemon.task.plan_file import plan_to_data
from legws_daemon.tracking.calibration import DEFAULT_BOARD, Calibration, calibration_to_data
from legws_daemon.tracking.camera import Intrinsics
from tests.cli.helpers import EXAMPLE_GOALSET, LEGWS, Result, run_script
from tests.net import free_port
from tests.task.test_plan_file import feeding_plan

Cli = Callable[..., Result]
REPO = Path(__file__).parents[2]


def _line(text: str, needle: str, after: int = 0) -> int:
    """The 1-based line of the first ``needle`` at or after line ``after``."""
    lines = text.splitlines()
    return next(i + 1 for i in range(after, len(lines)) if needle in lines[i])


def assert_errors(result: Result, *lines: str) -> None:
    """Exit 2, nothing on stdout, exactly these ``legws: error:`` lines, nothing else."""
    assert result.code == 2, result
    assert result.out == "", result
    assert result.err == "".join(f"legws: error: {line}\n" for line in lines), result.err
    for word in ("Traceback", ".rs:", ".cargo", "site-packages"):
        assert word not in result.err, result.err


def test_a_renamed_key_in_a_task_graph(tmp_path: Path) -> None:
    """The issue's case: ``legws taskgraph check`` once said ``stages[1].action: Field
    required [and 1 more error]``, with no line and the cause (``acton``) hidden."""
    text = (REPO / "taskgraphs" / "tea.toml").read_text(encoding="utf-8")
    bad = tmp_path / "tea.toml"
    bad.write_text(text.replace('action = "place"', 'acton = "place"', 1), encoding="utf-8")
    stage = _line(text, "[[stages]]", _line(text, "[[stages]]"))
    typo = _line(text, 'action = "place"')
    assert_errors(
        run_script("taskgraph", "check", bad, cwd=tmp_path),
        f"{bad}:{stage}: stages[1].action: Field required (one of 'pick', 'place', 'dip', "
        f"'feed', 'return'); is 'acton' on line {typo} a misspelling of it?",
        f"{bad}:{typo}: stages[1].acton: Extra inputs are not permitted; did you mean 'action'?",
    )


def test_every_error_of_a_task_graph(cli: Cli, tmp_path: Path) -> None:
    text = (REPO / "taskgraphs" / "feeding.toml").read_text(encoding="utf-8")
    edited = text.replace('action = "dip"', 'action = "dunk"', 1).replace(
        'prompt = "', 'promt = "', 1
    )
    bad = tmp_path / "feeding.toml"
    bad.write_text(edited, encoding="utf-8")
    promt, dunk = _line(edited, "promt ="), _line(edited, 'action = "dunk"')
    assert_errors(
        cli("taskgraph", "check", bad),
        f"{bad}:{promt}: stages[0].promt: Extra inputs are not permitted; did you mean 'prompt'?",
        f"{bad}:{dunk}: stages[1].action: Input should be 'pick', 'place', 'dip', 'feed' or "
        "'return' (got 'dunk')",
    )


def test_every_error_of_a_scene(cli: Cli, tmp_path: Path) -> None:
    text = (REPO / "scenes" / "desk.toml").read_text(encoding="utf-8")
    shape = _line(text, "shape = ", _line(text, "[[objects]]"))
    lines = text.splitlines(keepends=True)
    lines[shape - 1] = 'shape = "cube"\n'
    edited = "".join(lines).replace("min_clearance =", "min_clearence =", 1)
    bad = tmp_path / "desk.toml"
    bad.write_text(edited, encoding="utf-8")
    assert_errors(
        cli("certify", "--scene", bad),
        f"{bad}:{_line(edited, 'min_clearence')}: workspace.min_clearence: Extra inputs are not "
        "permitted; did you mean 'min_clearance'?",
        f"{bad}:{shape}: objects[0].shape: Input should be 'box', 'cylinder' or 'sphere' (got "
        "'cube')",
    )


def test_every_error_of_a_goal_set(cli: Cli, tmp_path: Path) -> None:
    doc = json.loads(json.dumps(EXAMPLE_GOALSET))
    doc["params"]["sigm"] = doc["params"].pop("sigma")
    doc["goals"][0]["symmetry"] = -1
    text = json.dumps(doc, indent=2)
    bad = tmp_path / "goals.json"
    bad.write_text(text, encoding="utf-8")
    symmetry, sigm = _line(text, '"symmetry"'), _line(text, '"sigm"')
    assert_errors(
        cli("certify", bad, "--json"),
        f"{bad}:{symmetry}: goals[0].symmetry: Input should be greater than or equal to 0 (got -1)",
        f"{bad}:{sigm}: params.sigm: Extra inputs are not permitted; did you mean 'sigma'?",
    )


def test_every_error_of_a_profile(cli: Cli, tmp_path: Path) -> None:
    text = (REPO / "hw_profiles" / "sim.toml").read_text(encoding="utf-8")
    edited = text.replace("deadman_timeout =", "deadman_timout =", 1).replace(
        'mode = "peer"', 'mode = "peers"', 1
    )
    bad = tmp_path / "sim.toml"
    bad.write_text(edited, encoding="utf-8")
    assert_errors(
        cli("daemon", "--profile", bad, "--duration", "1"),
        f"{bad}:{_line(edited, 'deadman_timout')}: control.deadman_timout: Extra inputs are not "
        "permitted; did you mean 'deadman_timeout'?",
        f"{bad}:{_line(edited, 'mode = ')}: transport.mode: Input should be 'peer' or 'client' "
        "(got 'peers'; did you mean 'peer'?)",
    )


def test_a_profile_name_typo_says_did_you_mean(tmp_path: Path) -> None:
    assert_errors(
        run_script("daemon", "--profile", "simm", "--duration", "1", cwd=tmp_path),
        "profile: unknown hardware profile 'simm'; did you mean 'sim'? known: "
        "panda, panda_sim, sawyer, sim",
    )


def test_a_profile_file_name_typo_says_did_you_mean(cli: Cli, tmp_path: Path) -> None:
    assert_errors(
        run_script("daemon", "--profile", "hw_profiles/simm.toml", "--duration", "1", cwd=REPO),
        "hw_profiles/simm.toml: no such file; did you mean 'hw_profiles/sim.toml'?",
    )
    assert_errors(
        cli("bridge", "fake", "--profile", "sawyr"),
        "profile: unknown hardware profile 'sawyr'; did you mean 'sawyer'? known: "
        "panda, panda_sim, sawyer, sim",
    )


def test_every_error_of_a_layout(cli: Cli, tmp_path: Path) -> None:
    """An unknown key close to a known one, and an object name close to a movable one."""
    doc = {
        "white_mug": {"x": 0.45, "y": -0.35, "yw": 0.3},
        "black_stapler": {"x": 0.7, "y": 0.0},
        "maroon_pen_cp": {"x": 0.5, "y": 0.1},
    }
    text = json.dumps(doc, indent=2)
    bad = tmp_path / "layout.json"
    bad.write_text(text, encoding="utf-8")
    objects = ", ".join(load_scene("desk").objects)
    yw, name = _line(text, '"yw"'), _line(text, '"maroon_pen_cp"')
    assert_errors(
        cli("certify", "--scene", "desk", "--layout", bad, "--json"),
        f"{bad}:{yw}: white_mug.yw: Extra inputs are not permitted; did you mean 'yaw'?",
        f"{bad}:{name}: maroon_pen_cp: unknown object 'maroon_pen_cp' in layout; did you mean "
        f"'maroon_pen_cup'? scene 'desk' has: {objects}",
    )


def test_every_error_of_a_plan(cli: Cli, tmp_path: Path) -> None:
    """``legws daemon --taskgraph T --plan DIR``: the plan.json of the folder, line by line,
    before anything starts."""
    doc = plan_to_data(feeding_plan())
    doc["decisions"][1]["layout"]["grape"]["x"] = "far"
    doc["decisions"][2]["inferenc"] = doc["decisions"][2].pop("inference")
    text = json.dumps(doc, indent=2)
    folder = tmp_path / "plan"
    folder.mkdir()
    (folder / "plan.json").write_text(text, encoding="utf-8")
    bad = folder / "plan.json"
    third = _line(text, '"label": "feed"') - 1  # the "{" of decisions[2]
    assert text.splitlines()[third - 1].strip() == "{"
    typo, far = _line(text, '"inferenc"'), _line(text, '"far"')
    assert_errors(
        cli("daemon", "--taskgraph", "feeding", "--plan", folder, "--duration", "1"),
        f"{bad}:{far}: decisions[1].layout.grape.x: Input should be a valid number (got 'far')",
        f"{bad}:{third}: decisions[2].inference: Field required; is 'inferenc' on line {typo} a "
        "misspelling of it?",
        f"{bad}:{typo}: decisions[2].inferenc: Extra inputs are not permitted; did you mean "
        "'inference'?",
    )


def test_every_error_of_a_camera_calibration(cli: Cli, tmp_path: Path) -> None:
    cal = Calibration(
        Intrinsics.pinhole(50.0, 640, 480), 0.2, 10, (0.2,) * 10, DEFAULT_BOARD,
        "2026-12-02T12:00:00+00:00",
    )  # fmt: skip
    doc = calibration_to_data(cal)
    doc["height"] = 480.0
    doc["board"]["dictionary"] = "5X5_1OO"  # letters O for zeros
    text = json.dumps(doc, indent=2)
    bad = tmp_path / "calib.json"
    bad.write_text(text, encoding="utf-8")
    height = _line(text, '"height"')
    assert_errors(  # the fields first; the checks across them once the fields are valid
        cli("track", "--camera", "0", "--scene", "tea", "--calibration", bad),
        f"{bad}:{height}: height: Input should be a valid integer (got 480.0)",
    )
    doc["height"] = 480
    text = json.dumps(doc, indent=2)
    bad.write_text(text, encoding="utf-8")
    dictionary = _line(text, '"5X5_1OO"')
    assert_errors(
        cli("track", "--camera", "0", "--scene", "tea", "--calibration", bad),
        f"{bad}:{dictionary}: board.dictionary: unknown marker dictionary '5X5_1OO'; "
        f"did you mean '5X5_100'? known: {', '.join(MARKER_DICTIONARIES)}",
    )


def test_a_scene_name_typo_says_did_you_mean(tmp_path: Path) -> None:
    known = ", ".join(scene_names())
    assert_errors(
        run_script("daemon", "--scene", "deks", "--duration", "1", cwd=tmp_path),
        f"scene: unknown scene 'deks'; did you mean 'desk'? known: {known}",
    )


def _profile_on(tmp_path: Path, port: int) -> Path:
    """The sim profile listening on ``tcp/127.0.0.1:PORT`` (loopback, multicast off)."""
    text = (REPO / "hw_profiles" / "sim.toml").read_text(encoding="utf-8")
    assert 'listen = ["tcp/127.0.0.1:7447"]' in text and "multicast_scouting = false" in text
    path = tmp_path / "sim.toml"
    path.write_text(text.replace(":7447", f":{port}", 1), encoding="utf-8")
    return path


def test_a_port_held_by_a_plain_socket_is_one_line(tmp_path: Path) -> None:
    port = free_port()
    profile = _profile_on(tmp_path, port)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", port))
        held.listen()
        result = run_script("daemon", "--profile", profile, "--duration", "5", cwd=tmp_path)
    assert_errors(result, f"tcp/127.0.0.1:{port} is in use — another daemon?")


@contextmanager
def _daemon(profile: Path, log: Path) -> Iterator[subprocess.Popen[bytes]]:
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [str(LEGWS), "daemon", "--profile", str(profile), "--duration", "60"],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        yield proc
    finally:
        proc.terminate()  # SIGTERM: the daemon stops the robot and exits 0
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def _listening(port: int, proc: subprocess.Popen[bytes], seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and proc.poll() is None:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.settimeout(0.5)
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return True
        time.sleep(0.1)
    return False


def test_a_second_daemon_on_the_same_port_is_one_line(tmp_path: Path) -> None:
    port = free_port()
    profile = _profile_on(tmp_path, port)
    log = tmp_path / "first.log"
    with _daemon(profile, log) as first:
        assert _listening(port, first, 60), log.read_text(errors="replace")
        second = run_script("daemon", "--profile", profile, "--duration", "5", cwd=tmp_path)
        assert first.poll() is None  # the first one runs on
    assert_errors(second, f"tcp/127.0.0.1:{port} is in use — another daemon?")
    assert first.returncode == 0, log.read_text(errors="replace")
