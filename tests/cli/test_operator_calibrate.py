"""``legws operator calibrate``: bad input is one line and exit 2 before anything moves; an
interrupted calibration keeps the reaches done; and, end to end over loopback zenoh, a
simulated operator of known O calibrated with ``legws joystick sim-user``, then ``legws
daemon --operator`` on the file it wrote shows that operator's certificates in status."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.autonomy.calibration import Reach
from legws_daemon.cli.main import run
from legws_daemon.cli.operator_calibrate import EXIT_INTERRUPTED, _default_name, _interrupted
from legws_daemon.core.certificate import certify
from legws_daemon.core.params import Params
from legws_daemon.formats.operator_file import load_operator
from legws_daemon.formats.trace import read_trace
from legws_daemon.scene.catalog import load_scene
from legws_daemon.telemetry.operator_trace import recorded_segments
from tests.daemon.procs import LEGWS, env, monitor, ready, start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer_sim"


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--targets", "1"], "--targets"),
        (["--targets", "201"], "--targets"),
        (["--name", "al ice"], "--name"),
        (["--profile", "nosuch"], "unknown hardware profile"),
        (["--scene", "nosuch"], "nosuch"),
        (["--profile", "sawyer"], "--allow-motion"),
    ],
)
def test_bad_input_is_one_line_and_exit_2_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str
) -> None:
    code = run(["operator", "calibrate", "--out", str(tmp_path / "alice.json"), *args])
    err = capsys.readouterr().err
    assert code == 2, err
    (line,) = err.strip().splitlines()
    assert line.startswith("legws: error:") and says in line
    assert not (tmp_path / "alice.json").exists()


def test_the_output_folders_must_exist(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["operator", "calibrate", "--out", str(tmp_path / "no" / "a.json")]) == 2
    trace = str(tmp_path / "no" / "t.jsonl")
    assert run(["operator", "calibrate", "--out", str(tmp_path / "a.json"), "--trace", trace]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_the_name_defaults_to_the_files() -> None:
    assert _default_name(Path("out/alice.json")) == "alice"
    assert _default_name(Path("out/al ice.json")) == "operator"


def test_an_interrupted_calibration_writes_the_reaches_done_and_no_operator_file(
    tmp_path: Path,
) -> None:
    trace, out = tmp_path / "alice.trace.jsonl", tmp_path / "alice.json"
    assert _interrupted([], 20, trace, out) == EXIT_INTERRUPTED
    assert not trace.exists() and not out.exists()
    ee = np.linspace([0.55, 0.0, 0.3], [0.7, 0.1, 0.3], 40)
    u = np.tile([0.8, 0.53, 0.0], (40, 1))
    done = [Reach(1, ee, u, np.array([0.72, 0.11, 0.3]), 2.0),
            Reach(2, ee[::-1], -u, np.array([0.54, -0.01, 0.3]), 2.0)]  # fmt: skip
    assert _interrupted(done, 20, trace, out) == EXIT_INTERRUPTED
    segments = read_trace(trace)
    assert [s.label for s in segments] == [0, 1] and not out.exists()
    np.testing.assert_allclose(segments[1].u, -u, atol=1e-6)


# --- end to end --------------------------------------------------------------------------

#: A stand-in three times as fast at full deflection (v_max 0.15 m/s: reaches of 0.25-0.6 m
#: in 2-8 s, so that three of them and two process starts fit in ~30 s).
FAST = {"v_max = 0.05 ": "v_max = 0.15 "}


@pytest.mark.slow  # ~30 s: calibrate + sim-user (3 reaches), then the daemon on the file
def test_calibrate_a_simulated_operator_then_the_daemon_certifies_for_its_file(
    tmp_path: Path,
) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port, FAST)
    out, rrd = tmp_path / "alice.json", tmp_path / "calibration.rrd"
    t0 = time.monotonic()
    calibrate = start(
        ["operator", "calibrate", "--profile", str(profile), "--targets", "3", "--seed", "4",
         "--out", str(out), "--rerun", f"save:{rrd}", "--resamples", "200"],
        tmp_path / "calibrate.log",
    )  # fmt: skip
    try:
        # the simulated operator of known O: sigma 0.09 m/s (0.6 of full deflection, as the
        # paper's user at 0.05 m/s), rho 0.6, a 15° bias, free steering, 50 Hz
        user = subprocess.run(
            [*LEGWS, "joystick", "sim-user", "--profile", str(profile), "--sigma", "0.09",
             "--rho", "0.6", "--bias", "15", "--steering", "free", "--rate", "50",
             "--seed", "2", "--duration", "60"],
            capture_output=True, text=True, timeout=90, check=False, env=env(),
        )  # fmt: skip
        assert user.returncode == 0, user.stderr
        assert "calibrate -> idle" in user.stderr
        assert calibrate.wait(60) == 0, (tmp_path / "calibrate.log").read_text()
    finally:
        stop(calibrate)
    log = (tmp_path / "calibrate.log").read_text()
    for i in (1, 2, 3):  # the terminal: each target as it appears, and reached in ... s
        assert f"target {i} of 3 at (" in log and f"target {i} of 3 reached in " in log
    file = load_operator(out)
    assert file.name == "alice" and file.segments == 3
    assert file.extra is not None and file.extra["targets"] == 3
    # the fit found O (loosely: three reaches)
    fitted = file.fitted
    assert fitted.steering == "free"
    assert abs(fitted.rho - 0.6) < 0.15 and abs(fitted.bias_deg - 15.0) < 10.0
    # the trace written is the recording's (legws operator trace reads the same reaches)
    trace = read_trace(tmp_path / "alice.trace.jsonl")
    recorded = recorded_segments(rrd)
    assert len(trace) == len(recorded) == 3
    for a, b in zip(trace, recorded, strict=True):
        np.testing.assert_allclose(a.ee, b.ee, atol=1e-6)
        np.testing.assert_allclose(a.u, b.u, atol=1e-6)
        np.testing.assert_allclose(a.goal, b.goal, atol=1e-6)

    # the daemon for this person: status names the model, and the certificate is theirs
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--operator", str(out),
         "--duration", "40"],
        tmp_path / "daemon.log",
    )  # fmt: skip
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            status = m.latest()
            assert status is not None
    finally:
        code, _ = stop(daemon)
    assert code == 0
    model = status["operator_model"]
    assert model["name"] == "alice" and model["file"] == str(out)
    assert model["model"] == json.loads(out.read_text())["certify_with"]
    assert model["watch"]["picks"] == 0 and model["watch"]["warning"] is None
    scene = load_scene("desk")
    goals = scene.goal_set()
    assert sorted(status["targets"]) == sorted(goals.names)
    for name, position in status["targets"].items():
        np.testing.assert_allclose(position, goals.positions[goals.index(name)])
    params = Params(v_max=0.15, dt=0.05)
    op = file.certify_with
    theirs = certify(goals, params, op, op.motion(params, clip=True)).objective
    assert status["certificate"] == pytest.approx(theirs, abs=1e-9)
    assert status["certificate"] != pytest.approx(certify(goals, params).objective, abs=1e-3)
    assert time.monotonic() - t0 < 90
