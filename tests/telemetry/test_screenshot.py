"""``screenshot_recording``: the headless native viewer draws a recording at the time asked
(a magenta box that moves right between 0 and 2 s is seen further right at 1.8 s than at
0.5 s), by default at its last posterior, without notification toasts, and bad inputs are
one-line errors."""

from __future__ import annotations

import contextlib
import io
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import psutil
import pytest
import rerun as rr
import rerun.blueprint as rrb
from PIL import Image

from legws_daemon.errors import InputError
from legws_daemon.telemetry.rerun_log import _PALETTE, RerunLog
from legws_daemon.telemetry.screenshot import _drive, last_posterior_time, screenshot_recording
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.browser import require, vulkan_missing
from tests.telemetry.helpers import arm_visual, log_episode, straight_episode, tick_kwargs

SIZE = (960, 600)
_CUBE_FACES = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
               (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]  # fmt: skip


def write_moving_box(path: Path) -> Path:
    """A recording with timelines ``tick`` and ``time``: a solid magenta box moving along +x
    from x=-2 at 0 s to x=+2 at 2 s (21 steps), and static grey points that fix the view."""
    rec = rr.RecordingStream("legws-screenshot-test", recording_id="moving-box")
    rec.save(path)
    rec.send_blueprint(
        rrb.Blueprint(rrb.Spatial3DView(origin="/world", name="3D"), collapse_panels=True)
    )
    rec.log("world/frame", rr.Points3D([[-3, -1, -1], [3, 1, 1]], radii=0.02), static=True)
    h = 0.5
    corners = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)], np.float32)
    for i in range(21):
        rec.set_time("tick", sequence=i)
        rec.set_time("time", duration=i * 0.1)
        rec.log(
            "world/box",
            rr.Mesh3D(
                vertex_positions=corners + np.array([-2 + 0.2 * i, 0, 0], np.float32),
                triangle_indices=np.array(_CUBE_FACES, np.uint32),
                albedo_factor=[255, 0, 255],
            ),
        )
    rec.flush()
    rec.disconnect()
    return path


@pytest.fixture(scope="module")
def moving_box(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_moving_box(tmp_path_factory.mktemp("rrd") / "moving.rrd")


def magenta(rgb: np.ndarray) -> np.ndarray:
    a = rgb.astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    mask: np.ndarray = (r > 120) & (b > 120) & (g < 0.35 * np.minimum(r, b)) & (abs(r - b) < 50)
    return mask


def _box_x(png: Path) -> float:
    """The mean column of the magenta pixels of a picture."""
    rgb = np.asarray(Image.open(png).convert("RGB"))
    assert rgb.shape == (SIZE[1], SIZE[0], 3)
    _, xs = np.nonzero(magenta(rgb))
    assert xs.size > 2000, f"no box in {png}"
    return float(xs.mean())


def _no_viewer_left() -> None:
    alive = []
    for child in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error):
            if child.status() != psutil.STATUS_ZOMBIE and "--headless" in child.cmdline():
                alive.append(child)
    assert not alive, alive


@pytest.mark.slow
def test_the_time_given_is_the_time_drawn(moving_box: Path, tmp_path: Path) -> None:
    require(vulkan_missing())
    early, late, end = tmp_path / "early.png", tmp_path / "late.png", tmp_path / "end.png"
    assert screenshot_recording(moving_box, early, time=0.5, size=SIZE) == early
    screenshot_recording(moving_box, late, time=1.8, size=SIZE)
    screenshot_recording(moving_box, end, size=SIZE)  # the end: 2 s
    x_early, x_late, x_end = _box_x(early), _box_x(late), _box_x(end)
    assert x_late - x_early > 0.08 * SIZE[0], (x_early, x_late)  # ~0.12 here
    assert x_end > x_late, (x_late, x_end)
    _no_viewer_left()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["early.png", "end.png", "late.png"]  # no temporary file left


@pytest.mark.slow
def test_the_picture_has_no_notification_toasts(moving_box: Path, tmp_path: Path) -> None:
    """The viewer shows its gRPC address as a toast at start-up, top right, light text on a
    dark card over the (dark) 3D view; the picture is taken once it is gone."""
    require(vulkan_missing())
    out = screenshot_recording(moving_box, tmp_path / "shot.png", time=0.0, size=SIZE)
    rgb = np.asarray(Image.open(out).convert("RGB"))
    corner = rgb[40:160, SIZE[0] - 360 : SIZE[0] - 20]
    bright = (corner.max(axis=2) > 150).sum()
    assert bright < 50, f"{bright} bright pixels where a toast would be, see {out}"


@pytest.mark.slow
def test_a_time_outside_the_recording_is_one_line(moving_box: Path, tmp_path: Path) -> None:
    require(vulkan_missing())
    for t in (2.5, -0.1):
        with pytest.raises(InputError) as info:
            screenshot_recording(moving_box, tmp_path / "out.png", time=t, size=SIZE)
        text = str(info.value)
        assert "\n" not in text
        assert text.startswith("--time: ") and "outside the recording" in text and "0-2 s" in text
    assert not (tmp_path / "out.png").exists()
    _no_viewer_left()


@pytest.mark.parametrize("t", [float("nan"), float("inf"), -float("inf")])
def test_the_time_must_be_finite(moving_box: Path, tmp_path: Path, t: float) -> None:
    with pytest.raises(InputError, match=r"^--time: expected a finite number"):
        screenshot_recording(moving_box, tmp_path / "out.png", time=t)


def test_not_a_recording_is_one_line(tmp_path: Path) -> None:
    text_file = tmp_path / "notes.rrd"
    text_file.write_text("not a recording\n")
    with pytest.raises(InputError) as info:
        screenshot_recording(text_file, tmp_path / "out.png")
    assert str(info.value) == (
        f"{text_file}: is not a rerun recording (it does not start with b'RRF2')"
    )


def test_a_missing_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(InputError) as info:
        screenshot_recording(tmp_path / "gone.rrd", tmp_path / "out.png")
    assert (
        str(info.value)
        == f"{tmp_path / 'gone.rrd'}: no such file; expected a rerun recording (.rrd)"
    )


def test_an_output_onto_a_folder_is_refused_before_rendering(
    moving_box: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "pictures"
    folder.mkdir()
    with pytest.raises(InputError) as info:
        screenshot_recording(moving_box, folder, size=SIZE)
    assert str(info.value) == f"{folder}: is a folder, expected a file to write"
    assert list(folder.iterdir()) == []


def test_a_missing_output_folder_is_refused(moving_box: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        screenshot_recording(moving_box, tmp_path / "no" / "out.png")


@pytest.mark.parametrize("size", [(10, 600), (960, 0), (100_000, 600)])
def test_a_bad_size_is_one_line(moving_box: Path, tmp_path: Path, size: tuple[int, int]) -> None:
    with pytest.raises(InputError, match=r"^--size: expected a width and height of 64-8192"):
        screenshot_recording(moving_box, tmp_path / "out.png", size=size)


def test_no_vulkan_names_the_package_to_install(
    moving_box: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("VK_ICD_FILENAMES", str(tmp_path / "no-such-driver.json"))
    monkeypatch.setenv("VK_DRIVER_FILES", str(tmp_path / "no-such-driver.json"))
    with pytest.raises(InputError) as info:
        screenshot_recording(moving_box, tmp_path / "out.png", size=SIZE, timeout=30)
    text = str(info.value)
    assert "\n" not in text
    assert "mesa-vulkan-drivers" in text and "graphics adapter" in text
    assert not (tmp_path / "out.png").exists()
    _no_viewer_left()


def test_a_viewer_that_dies_before_the_connection_is_its_exit_and_the_hint(
    moving_box: Path, tmp_path: Path
) -> None:
    """The race of the test above: the viewer listened, then panicked (no Vulkan) before the
    client connected. The connection's "transport error" is the viewer's exit and the hint."""
    log = tmp_path / "rerun.log"
    log.write_text("thread 'main' panicked at 'Failed to create a graphics adapter'\n")
    proc = subprocess.Popen([sys.executable, "-c", "raise SystemExit(101)"])
    proc.wait(30)
    with socket_closed() as port, pytest.raises(InputError) as info:
        _drive(proc, port, moving_box, None, log, deadline=float("inf"))
    text = str(info.value)
    assert "exited (code 101)" in text and "graphics adapter" in text
    assert "mesa-vulkan-drivers" in text and "transport error" not in text


@contextlib.contextmanager
def socket_closed() -> Iterator[int]:
    """A loopback port nothing listens on (bound and held without listen())."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


def test_the_png_is_written_atomically_over_an_old_file(moving_box: Path, tmp_path: Path) -> None:
    """A failed run leaves the old picture as it was."""
    out = tmp_path / "out.png"
    old = io.BytesIO()
    Image.new("RGB", (4, 4)).save(old, "PNG")
    out.write_bytes(old.getvalue())
    with pytest.raises(InputError):
        screenshot_recording(moving_box, out, time=99.0, size=SIZE)
    assert out.read_bytes() == old.getvalue()


@pytest.mark.slow
def test_a_cut_off_recording_says_why_in_one_line(moving_box: Path, tmp_path: Path) -> None:
    require(vulkan_missing())
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(moving_box.read_bytes()[: moving_box.stat().st_size // 2])
    with pytest.raises(InputError) as info:
        screenshot_recording(cut, tmp_path / "out.png", size=SIZE)
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"{cut}: the viewer found no recording in it: ")
    assert "exceeds file size" in text and "legws recording finish" in text
    _no_viewer_left()


#: Seconds the idle session below runs on after its last decision.
IDLE = 50.0


@pytest.fixture(scope="module")
def idle_after(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """A daemon session as :class:`RerunLog` writes it: a reach that commits on the
    banana, then :data:`IDLE` s without inference (the task done, the daemon left on)."""
    path = tmp_path_factory.mktemp("rrd") / "idle.rrd"
    ep = straight_episode("breakfast_easy", "banana")
    with RerunLog(f"save:{path}", robot="sawyer-sim", tick_period=0.05) as log:
        log.log_robot(arm_visual())
        log_episode(log, ep, stage="choose")
        first = len(ep.positions)
        for tick in range(first, first + round(IDLE / 0.05)):
            kwargs = {**tick_kwargs(ep, len(ep.positions) - 1, None), "mode": "idle"}
            log.log_tick(TickSnapshot(tick, tick * 0.05, **kwargs))
    return path, (first - 1) * 0.05


def test_the_default_time_is_the_last_posterior(idle_after: tuple[Path, float]) -> None:
    path, last = idle_after
    assert last_posterior_time(path) == pytest.approx(last)
    assert last_posterior_time(write_moving_box(path.with_name("box.rrd"))) is None


def posterior_pixels(png: Path, colours: list[int]) -> int:
    """Pixels of the posterior plot in the colours of its curves (``0xRRGGBBAA``): the
    right-hand column of the default layout, above its bottom quarter (slack, timing)."""
    rgb = np.asarray(Image.open(png).convert("RGB"), dtype=np.int16)
    height, width, _ = rgb.shape
    panel = rgb[int(0.12 * height) : int(0.62 * height), int(0.62 * width) :]
    count = 0
    for colour in colours:
        want = np.array([(colour >> s) & 0xFF for s in (24, 16, 8)], dtype=np.int16)
        count += int(np.sum(np.all(np.abs(panel - want) <= 24, axis=-1)))
    return count


@pytest.mark.slow
def test_the_default_picture_shows_the_posterior(
    idle_after: tuple[Path, float], tmp_path: Path
) -> None:
    """At the end of a session that idled after its last decision the plot (the seconds
    up to the cursor) is empty; by default the picture is taken at the last posterior."""
    require(vulkan_missing())
    path, last = idle_after
    curves = [_PALETTE[0], _PALETTE[1]]  # cereal_box, banana: the goals in their order
    default = screenshot_recording(path, tmp_path / "default.png", size=(800, 500))
    end = screenshot_recording(path, tmp_path / "end.png", time=last + IDLE, size=(800, 500))
    assert posterior_pixels(end, curves) < 30, "the curves at the end?"
    assert posterior_pixels(default, curves) > 150, f"no posterior in {default}"
