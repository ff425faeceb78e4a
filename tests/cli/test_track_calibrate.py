"""``legws track calibrate``: from photographs, from a (fake) camera, the printed board at
true scale, and one-line errors for an unreadable camera and bad input."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pdfplumber
import pytest

from legws_daemon.cli import track_calibrate
from legws_daemon.tracking.calibration import detect_board, load_calibration
from tests.cli.helpers import Result, assert_bad_input
from tests.reliability.classes import png_header_only
from tests.tracking.test_calibration import synthetic_views

MM_PER_POINT = 25.4 / 72


@pytest.fixture
def pictures(tmp_path: Path) -> Path:
    folder = tmp_path / "shots"
    folder.mkdir()
    for i, view in enumerate(synthetic_views()):
        cv2.imwrite(str(folder / f"view{i:02d}.png"), view)
    return folder


def _one_line_error(result: Result, *needles: str) -> None:
    """Exit 2 with one error line; stdout may hold the progress made before the error
    (the pictures read, the views taken)."""
    assert_bad_input(Result(result.code, "", result.err), *needles)
    assert "Traceback" not in result.out


def _fx_fy_cx_cy(path: Path) -> tuple[float, float, float, float]:
    k = load_calibration(path).intrinsics.matrix
    return float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])


def _close(got: Sequence[float], true: Sequence[float] = (610.0, 605.0, 322.0, 236.0)) -> bool:
    return all(abs(g - t) / t < 0.01 for g, t in zip(got, true, strict=True))


def test_images(cli: Callable[..., Result], pictures: Path, tmp_path: Path) -> None:
    out = tmp_path / "calib.json"
    result = cli("track", "calibrate", "--images", f"{pictures}/*.png", "--out", out)
    assert result.code == 0, result.err
    assert result.err == ""
    lines = result.out.splitlines()
    assert sum("of 24 corners" in line for line in lines) == 12
    assert "calibrated 640x480 from 12 of 12 views: RMS reprojection error" in result.out
    assert "fx " in result.out
    assert "worst view: " in result.out
    assert lines[-1] == f"wrote {out}"
    assert _close(_fx_fy_cx_cy(out))
    assert load_calibration(out).rms_px < 0.5


def test_images_from_a_folder_with_pictures_left_out(
    cli: Callable[..., Result], pictures: Path, tmp_path: Path
) -> None:
    cv2.imwrite(str(pictures / "blank.png"), np.full((480, 640), 110, dtype=np.uint8))
    out = tmp_path / "calib.json"
    result = cli("track", "calibrate", "--images", pictures, "--out", out)
    assert result.code == 0, result.err
    assert f"{pictures / 'blank.png'}: 0 of 24 corners, left out" in result.out
    assert "from 12 of 13 views" in result.out


@pytest.mark.parametrize(
    ("setup", "args", "needles"),
    [
        (None, ("--images", "{tmp}/none/*.png"), ("--images: no pictures match",)),
        (None, ("--images", "{tmp}/missing.png"), ("missing.png: no such file",)),
        ("text", ("--images", "{tmp}/bad.png"), ("bad.png: not a picture OpenCV can read",)),
        # a 32000 x 32000 PNG header (it decodes to 1 GiB): refused from its header
        (
            "huge",
            ("--images", "{tmp}/huge.png"),
            ("huge.png: 1,024,000,000 pixels is more than the 50 million", "nothing was decoded"),
        ),
        ("few", ("--images", "{tmp}/few/*.png"), ("--images: only 3 of 3 views", "at least 8")),
        ("sizes", ("--images", "{tmp}/sizes/*.png"), ("b.png: is 320x240", "640x480")),
        (None, ("--camera", "99"), ("camera 99: cannot open the camera",)),
        (None, (), ("exactly one of --images, --camera and --print-board",)),
        (None, ("--camera", "0", "--print-board", "{tmp}/b.pdf"), ("exactly one of",)),
        (None, ("--print-board", "{tmp}/board.svg"), ("board.svg", ".pdf or a .png")),
        (None, ("--print-board", "{tmp}/no/board.pdf"), ("its folder",)),
        (None, ("--print-board", "{tmp}/b.pdf", "--board", "12x9"), ("does not fit on A4",)),
        (None, ("--print-board", "{tmp}/b.pdf", "--board", "seven"), ("COLUMNSxROWS",)),
        (None, ("--print-board", "{tmp}/b.pdf", "--marker-mm", "40"), ("smaller than it",)),
    ],
)
def test_bad_input_is_one_line(
    cli: Callable[..., Result],
    tmp_path: Path,
    setup: str | None,
    args: tuple[str, ...],
    needles: tuple[str, ...],
) -> None:
    if setup == "text":
        (tmp_path / "bad.png").write_text("not a picture")
    elif setup == "huge":
        (tmp_path / "huge.png").write_bytes(png_header_only(32000, 32000))
    elif setup == "few":
        (tmp_path / "few").mkdir()
        for i, view in enumerate(synthetic_views()[:3]):
            cv2.imwrite(str(tmp_path / "few" / f"{i}.png"), view)
    elif setup == "sizes":
        (tmp_path / "sizes").mkdir()
        cv2.imwrite(str(tmp_path / "sizes" / "a.png"), synthetic_views()[0])
        cv2.imwrite(str(tmp_path / "sizes" / "b.png"), np.zeros((240, 320), dtype=np.uint8))
    argv = [a.format(tmp=tmp_path) for a in args]
    if "--images" in argv or "--camera" in argv:
        argv += ["--out", str(tmp_path / "calib.json")]
    result = cli("track", "calibrate", *argv)
    _one_line_error(result, *needles)
    assert not (tmp_path / "calib.json").exists()


def test_out_is_required_and_checked_before_any_work(
    cli: Callable[..., Result], tmp_path: Path
) -> None:
    assert_bad_input(cli("track", "calibrate", "--camera", "99"), "--out")
    result = cli("track", "calibrate", "--camera", "99", "--out", tmp_path)
    assert_bad_input(result, "--out", "is a directory")


# --- a camera ------------------------------------------------------------------------------


class FakeCamera:
    """``cv2.VideoCapture`` of a camera that shows ``frames``, then raises ``then`` (a
    Ctrl-C) or delivers nothing more."""

    def __init__(self, frames: Sequence[np.ndarray], then: type[BaseException] | None) -> None:
        self._frames: Iterator[np.ndarray] = iter(frames)
        self._then = then
        self.released = False

    def isOpened(self) -> bool:  # noqa: N802 (OpenCV's name)
        return True

    def read(self) -> tuple[bool, np.ndarray | None]:
        frame = next(self._frames, None)
        if frame is None and self._then is not None:
            raise self._then
        return (frame is not None), frame

    def release(self) -> None:
        self.released = True


@pytest.fixture
def camera(monkeypatch: pytest.MonkeyPatch) -> Callable[..., FakeCamera]:
    """Install a fake camera; views taken without waiting, a silent camera noticed fast."""
    monkeypatch.setattr(track_calibrate, "VIEW_INTERVAL_S", 0.0)
    monkeypatch.setattr(track_calibrate, "FRAME_TIMEOUT_S", 0.05)

    def install(frames: Sequence[np.ndarray], then: type[BaseException] | None) -> FakeCamera:
        fake = FakeCamera(frames, then)

        def open_capture(index: int, *_: Any) -> FakeCamera:
            assert index == 3
            return fake

        monkeypatch.setattr(cv2, "VideoCapture", open_capture)
        return fake

    return install


def _colour(views: Sequence[np.ndarray], repeat: int) -> list[np.ndarray]:
    # a camera delivers BGR; each view held for a few frames (only its first one is new)
    return [cv2.cvtColor(v, cv2.COLOR_GRAY2BGR) for v in views for _ in range(repeat)]


def test_camera_takes_distinct_views_up_to_views(
    cli: Callable[..., Result], camera: Callable[..., FakeCamera], tmp_path: Path
) -> None:
    fake = camera(_colour(synthetic_views(), 3), None)
    out = tmp_path / "calib.json"
    result = cli("track", "calibrate", "--camera", "3", "--views", "9", "--out", out)
    assert result.code == 0, result.err
    assert "camera 3: 640x480" in result.out
    assert [line for line in result.out.splitlines() if line.startswith("view ")] == [
        f"view {i}/9: 24 of 24 corners" for i in range(1, 10)
    ]
    assert "from 9 of 9 views" in result.out
    assert fake.released
    assert _close(_fx_fy_cx_cy(out))


def test_camera_ctrl_c_finishes_with_enough_views(
    cli: Callable[..., Result], camera: Callable[..., FakeCamera], tmp_path: Path
) -> None:
    camera(_colour(synthetic_views(), 2), KeyboardInterrupt)
    out = tmp_path / "calib.json"
    result = cli("track", "calibrate", "--camera", "3", "--views", "30", "--out", out)
    assert result.code == 0, result.err
    taken = int(re.findall(r"^stopped with (\d+) views$", result.out, re.MULTILINE)[0])
    assert 8 <= taken <= 12  # the views too close to an earlier one are not taken
    assert f"from {taken} of {taken} views" in result.out
    assert _close(_fx_fy_cx_cy(out))


def test_camera_ctrl_c_with_too_few_views(
    cli: Callable[..., Result], camera: Callable[..., FakeCamera], tmp_path: Path
) -> None:
    camera(_colour(synthetic_views()[:3], 1), KeyboardInterrupt)
    out = tmp_path / "calib.json"
    result = cli("track", "calibrate", "--camera", "3", "--out", out)
    _one_line_error(result, "camera 3: only ", "need at least 8")
    assert re.search(r"only ([123]) of \1 views", result.err)
    assert not out.exists()


def test_camera_that_delivers_nothing(
    cli: Callable[..., Result], camera: Callable[..., FakeCamera], tmp_path: Path
) -> None:
    fake = camera([], None)
    result = cli("track", "calibrate", "--camera", "3", "--out", tmp_path / "c.json")
    assert_bad_input(result, "camera 3: the camera delivered no picture for 0.05 s")
    assert fake.released


# --- the board to print ----------------------------------------------------------------------


def test_print_board_pdf_is_true_scale(cli: Callable[..., Result], tmp_path: Path) -> None:
    pdf, png = tmp_path / "board.pdf", tmp_path / "board.png"
    result = cli("track", "calibrate", "--print-board", pdf, "--print-board", png)
    assert result.code == 0, result.err
    assert f"wrote {pdf}: ChArUco board 7 x 5 squares of 30 mm" in result.out
    with pdfplumber.open(pdf) as doc:
        assert len(doc.pages) == 1
        page = doc.pages[0]
        # A4 landscape
        assert page.width * MM_PER_POINT == pytest.approx(297, abs=0.5)
        assert page.height * MM_PER_POINT == pytest.approx(210, abs=0.5)
        sizes = [
            (r["width"] * MM_PER_POINT, r["height"] * MM_PER_POINT)
            for r in page.rects
            if 20 < r["width"] * MM_PER_POINT < 40 and 20 < r["height"] * MM_PER_POINT < 40
        ]  # the page's white background and the markers' rows of cells left out
        assert len(sizes) == 18  # the black squares of a 7 x 5 board
        for w, h in sizes:
            assert w == pytest.approx(30.0, abs=0.2)
            assert h == pytest.approx(30.0, abs=0.2)
        text = page.extract_text()
        assert "7 x 5 squares of 30 mm, markers 22 mm, dictionary 5X5_100" in text
        assert "210 mm wide" in text
        picture = np.asarray(page.to_image(resolution=150).original.convert("L"))
    found = detect_board(picture)
    assert found.count == 24  # the vector drawing is the board OpenCV knows
    printed = np.asarray(cv2.imread(str(png), cv2.IMREAD_GRAYSCALE))
    assert detect_board(printed).count == 24
