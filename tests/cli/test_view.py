"""``legws view RECORDING.rrd``, run as the installed script: a PNG with ``--screenshot``,
the web viewer's page with ``--web`` until Ctrl-C, and one-line errors otherwise."""

from __future__ import annotations

import os
import signal
import subprocess
import urllib.request
from pathlib import Path

import pytest
from PIL import Image

from legws_daemon.telemetry.web_viewer import accepting
from tests.browser import require, vulkan_missing
from tests.cli.helpers import LEGWS, assert_bad_input, run_script
from tests.net import free_port_pair
from tests.telemetry.test_screenshot import write_moving_box


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    return write_moving_box(tmp_path / "moving.rrd")


@pytest.mark.slow
def test_screenshot_writes_a_png_and_prints_its_path(recording: Path, tmp_path: Path) -> None:
    require(vulkan_missing())
    out = tmp_path / "shot.png"
    result = run_script(
        "view", recording, "--screenshot", out, "--time", "1", "--size", "800x500", cwd=tmp_path
    )
    assert result.code == 0, result
    assert result.out == f"{out}\n"
    with Image.open(out) as picture:
        assert picture.format == "PNG"
        assert picture.size == (800, 500)


def test_time_without_screenshot_is_a_usage_error(recording: Path, tmp_path: Path) -> None:
    result = run_script("view", recording, "--time", "1", cwd=tmp_path)
    assert_bad_input(result, "--time", "--screenshot")


def test_a_time_that_is_not_finite_is_refused(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "shot.png"
    result = run_script("view", recording, "--screenshot", out, "--time", "nan", cwd=tmp_path)
    assert_bad_input(result, "--time", "finite")
    assert not out.exists()


def test_a_bad_size_is_refused(recording: Path, tmp_path: Path) -> None:
    result = run_script("view", recording, "--screenshot", "x.png", "--size", "big", cwd=tmp_path)
    assert_bad_input(result, "--size", "WIDTHxHEIGHT")


def test_not_a_recording_is_one_line(tmp_path: Path) -> None:
    notes = tmp_path / "notes.rrd"
    notes.write_text("hello\n")
    result = run_script("view", notes, "--screenshot", tmp_path / "x.png", cwd=tmp_path)
    assert_bad_input(result, str(notes), "not a rerun recording")


def test_without_a_display_it_suggests_screenshot_or_web(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    result = run_script("view", recording, cwd=tmp_path)
    assert_bad_input(result, "no display", "--screenshot", "--web")


def test_a_bad_web_target_names_the_option(recording: Path, tmp_path: Path) -> None:
    result = run_script("view", recording, "--web", "example.com:8000", cwd=tmp_path)
    assert_bad_input(result, "--web:", "IPv4")


def test_web_and_screenshot_exclude_each_other(recording: Path, tmp_path: Path) -> None:
    result = run_script("view", recording, "--web", "9000", "--screenshot", "x.png", cwd=tmp_path)
    assert_bad_input(result, "--web", "--screenshot")


def _terminal_ctrl_c() -> None:
    """In the child: SIGINT as a terminal delivers it (default action, not blocked), whatever
    the test runner's process inherited or set."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@pytest.mark.slow
def test_web_serves_the_file_on_loopback_until_ctrl_c(recording: Path, tmp_path: Path) -> None:
    port = free_port_pair()
    errors = (tmp_path / "view.err").open("w")  # a file: a full pipe would block the child
    proc = subprocess.Popen(
        [str(LEGWS), "view", str(recording), "--web", f"127.0.0.1:{port}"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=errors,
        text=True,
        env=os.environ.copy(),
        preexec_fn=_terminal_ctrl_c,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # printed once both ports accept connections
        assert line == (
            f"http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{port + 1}%2Fproxy\n"
        )
        with urllib.request.urlopen(line.strip(), timeout=10) as answer:
            assert answer.status == 200
        assert not accepting("127.0.0.2", port)
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            status = Path(f"/proc/{proc.pid}/status").read_text().splitlines()
            masks = [line for line in status if line.startswith(("SigBlk", "SigIgn", "State"))]
            pytest.fail(f"no exit 20 s after SIGINT ({masks}); stderr: "
                        f"{(tmp_path / 'view.err').read_text()[-2000:]}")  # fmt: skip
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        errors.close()
    assert code == 130
    for p in (port, port + 1):
        assert not accepting("127.0.0.1", p)
