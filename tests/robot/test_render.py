"""``legws render`` (PNG pictures of a layout) and ``legws assets``, through the CLI."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from legws_daemon.arms import arm_names
from legws_daemon.cli.main import run
from legws_daemon.robot.render import top_pixel
from legws_daemon.scene.catalog import load_scene
from tests.cli.helpers import LEGWS, Result, assert_bad_input

#: The red block of ``cluttered`` (scene file): colour, default position, a free spot.
RED = np.array([0.85, 0.1, 0.1]) * 255
RED_HOME = (0.78, 0.36)
RED_MOVED = (0.50, 0.30)
BLOCK_PIXELS_MIN = 50  # a 5 cm block is ~12 x 12 px at 400 x 300, less its grasp marker


def legws(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> Result:
    capsys.readouterr()
    code = run([str(a) for a in argv])
    out = capsys.readouterr()
    return Result(code, out.out, out.err)


def render(
    capsys: pytest.CaptureFixture[str], path: Path, *argv: str | Path
) -> tuple[Result, np.ndarray]:
    result = legws(capsys, "render", "-o", path, *argv)
    assert result.code == 0, result
    assert result.err == ""
    with Image.open(path) as im:
        assert im.format == "PNG"
        image = np.asarray(im.convert("RGB"))
    return result, image


def assert_not_blank(image: np.ndarray) -> None:
    assert image.std() > 20.0
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50


def red_pixels_near(image: np.ndarray, x: float, y: float, half: int = 12) -> int:
    """Pixels within 40 (RGB distance) of the red block's colour around table point x, y."""
    height, width = image.shape[:2]
    r, c = (round(v) for v in top_pixel(load_scene("cluttered"), width, height, x, y))
    patch = image[max(r - half, 0) : r + half + 1, max(c - half, 0) : c + half + 1]
    return int((np.linalg.norm(patch.astype(float) - RED, axis=-1) < 40).sum())


def test_breakfast_easy_top_and_perspective(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "pictures" / "nested" / "top.png"  # folders are created
    result, image = render(capsys, out, "--scene", "breakfast_easy")
    assert image.shape == (600, 800, 3)  # default size
    assert_not_blank(image)
    assert str(out) in result.out
    assert sorted(p.name for p in out.parent.iterdir()) == ["top.png"]  # no temp file left

    persp = tmp_path / "persp.png"
    args = ("--scene", "breakfast_easy", "--view", "perspective", "--width", "320")
    _, image = render(capsys, persp, *args, "--height", "240")
    assert image.shape == (240, 320, 3)
    assert_not_blank(image)


def test_cluttered_top_view_shows_the_red_block_where_the_layout_puts_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    size = ("--width", "400", "--height", "300")
    _, default = render(capsys, tmp_path / "default.png", "--scene", "cluttered", *size)
    assert default.shape == (300, 400, 3)
    assert_not_blank(default)
    assert red_pixels_near(default, *RED_HOME) > BLOCK_PIXELS_MIN
    assert red_pixels_near(default, *RED_MOVED) < 5

    layout = tmp_path / "moved.json"
    layout.write_text(json.dumps({"red_block": {"x": RED_MOVED[0], "y": RED_MOVED[1]}}))
    args = ("--scene", "cluttered", "--layout", layout, *size)
    _, moved = render(capsys, tmp_path / "moved.png", *args)
    assert red_pixels_near(moved, *RED_HOME) < 5
    assert red_pixels_near(moved, *RED_MOVED) > BLOCK_PIXELS_MIN
    assert np.abs(moved.astype(int) - default.astype(int)).sum(axis=-1).astype(bool).sum() > 100


def test_png_is_replaced_whole(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.png"
    out.write_bytes(b"old")
    size = ("--width", "64", "--height", "48")
    _, image = render(capsys, out, "--scene", "cluttered", "--view", "perspective", *size)
    assert image.shape == (48, 64, 3)
    assert [p.name for p in tmp_path.iterdir()] == ["x.png"]


def test_unknown_scene_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.png"
    assert_bad_input(legws(capsys, "render", "--scene", "nope", "-o", out), "unknown scene", "nope")
    assert not out.exists()


def test_bad_layout_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    layout = tmp_path / "bad.json"
    layout.write_text(json.dumps({"ghost": {"x": 0.5, "y": 0.0}}))
    out = tmp_path / "x.png"
    args = ("render", "--scene", "cluttered", "--layout", layout, "-o", out)
    assert_bad_input(legws(capsys, *args), "bad.json", "ghost")
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--scene", "cluttered"], "-o"),
        (["--scene", "cluttered", "-o", "x.png", "--view", "side"], "side"),
        (["--scene", "cluttered", "-o", "x.png", "--width", "0"], "--width"),
    ],
)
def test_usage_errors_are_one_line(
    argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert_bad_input(legws(capsys, "render", *argv), needle)


def test_no_gl_backend_is_one_line_naming_the_packages(tmp_path: Path) -> None:
    env = {**os.environ, "MUJOCO_GL": "no-such-backend"}
    proc = subprocess.run(
        [str(LEGWS), "render", "--scene", "cluttered", "-o", str(tmp_path / "x.png")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )
    line = assert_bad_input(Result(proc.returncode, proc.stdout, proc.stderr), "OpenGL")
    assert "libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libosmesa6" in line
    assert not (tmp_path / "x.png").exists()


def test_assets_status(capsys: pytest.CaptureFixture[str]) -> None:
    result = legws(capsys, "assets", "status")
    assert result.code == 0, result
    folders = [Path(line) for line in result.out.splitlines()]
    assert [f.name for f in folders] == list(arm_names())  # one folder per registered arm
    assert all((f / "robot.xml").is_file() for f in folders)


def test_assets_status_when_missing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("LEGWS_ASSETS", str(tmp_path / "empty"))
    assert_bad_input(legws(capsys, "assets", "status"), "not fetched", "assets fetch")


def test_assets_fetch_is_a_no_op_when_cached(capsys: pytest.CaptureFixture[str]) -> None:
    result = legws(capsys, "assets", "fetch")
    assert result.code == 0, result
    assert all((Path(line) / "robot.xml").is_file() for line in result.out.splitlines())
    assert result.err == ""


def test_assets_reachability_prints_the_cached_map(capsys: pytest.CaptureFixture[str]) -> None:
    result = legws(capsys, "assets", "reachability")
    assert result.code == 0, result
    paths = [Path(line) for line in result.out.splitlines()]
    assert len(set(paths)) == len(arm_names())  # one map per arm
    assert all(p.suffix == ".npz" and p.is_file() for p in paths)
