"""Camera calibration with a ChArUco board: known intrinsics recovered from synthetic views,
too few views refused, the calibration file written, read back and refused when bad, and
intrinsics scaled to another resolution."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from PIL import Image

from legws_daemon.errors import InputError
from legws_daemon.tracking.calibration import (
    DEFAULT_BOARD,
    MIN_VIEWS,
    BoardSpec,
    Detection,
    board_image,
    board_png,
    calibrate,
    charuco_board,
    detect_board,
    differs,
    load_calibration,
    save_calibration,
    scaled_intrinsics,
)
from legws_daemon.tracking.camera import Intrinsics

#: The synthetic camera: 640x480, a little off-centre, non-square pixels, barrel distortion.
WIDTH, HEIGHT = 640, 480
K_TRUE = np.array([[610.0, 0.0, 322.0], [0.0, 605.0, 236.0], [0.0, 0.0, 1.0]])
D_TRUE = np.array([-0.12, 0.08, 0.001, -0.0015, 0.0])
#: Pictures are drawn at this many times the resolution, then averaged down (anti-aliasing).
SUPERSAMPLE = 2
#: Pixels per square of the board picture that is projected.
PPS = 80


@cache
def _rays() -> np.ndarray:
    """The normalised ray ``(x, y, 1)`` seen by each (supersampled) pixel of the distorted
    synthetic camera: each pixel looks through the lens, distortion removed exactly."""
    s = SUPERSAMPLE
    k = K_TRUE.copy()
    k[:2, :2] *= s
    k[:2, 2] = (K_TRUE[:2, 2] + 0.5) * s - 0.5
    u, v = np.meshgrid(np.arange(WIDTH * s, dtype=np.float64), np.arange(HEIGHT * s))
    pixels = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2).astype(np.float64)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    xy = cv2.undistortPoints(pixels, k, D_TRUE, None, None, None, criteria)
    xy = xy.reshape(HEIGHT * s, WIDTH * s, 2)
    return np.concatenate([xy, np.ones((HEIGHT * s, WIDTH * s, 1))], axis=-1)


def render_view(rvec: np.ndarray, tvec: np.ndarray, spec: BoardSpec = DEFAULT_BOARD) -> np.ndarray:
    """The synthetic camera's grey picture of the board centred at ``tvec`` (camera frame,
    m), turned by ``rvec``, in front of a grey background, with a little noise."""
    rot, _ = cv2.Rodrigues(rvec)
    w, h = spec.squares_x * spec.square, spec.squares_y * spec.square
    # board point (bx, by, 1) -> camera point, the board plane's homography
    g = np.column_stack([rot[:, 0], rot[:, 1], tvec - rot[:, 0] * w / 2 - rot[:, 1] * h / 2])
    b = _rays() @ np.linalg.inv(g).T
    bx, by = b[..., 0] / b[..., 2], b[..., 1] / b[..., 2]
    # board_image: pixel u's centre shows (u + 0.5) / PPS - 0.5 squares
    mx = ((bx / spec.square + 0.5) * PPS - 0.5).astype(np.float32)
    my = ((by / spec.square + 0.5) * PPS - 0.5).astype(np.float32)
    mx[b[..., 2] <= 0] = -1e6  # behind the camera
    board = board_image(spec, PPS).astype(np.float32)
    big = cv2.remap(board, mx, my, cv2.INTER_LINEAR, borderValue=110.0)
    small = cv2.resize(big, (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA)
    noise = np.random.default_rng(int(abs(tvec[0]) * 1e6)).normal(0, 2, small.shape)
    return np.asarray(np.clip(small + noise, 0, 255), dtype=np.uint8)


@cache
def _views(count: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        tilt = np.radians([rng.uniform(-35, 35), rng.uniform(-35, 35), rng.uniform(-25, 25)])
        where = np.array(
            [rng.uniform(-0.05, 0.05), rng.uniform(-0.04, 0.04), rng.uniform(0.3, 0.45)]
        )
        out.append(render_view(tilt, where))
    return tuple(out)


def synthetic_views(count: int = 12, seed: int = 1) -> list[np.ndarray]:
    """``count`` pictures of the default board at random poses (tilted up to 35 degrees,
    30-45 cm away, anywhere in the picture) by the synthetic camera."""
    return list(_views(count, seed))


def _relative(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def test_recovers_known_intrinsics() -> None:
    cal = calibrate(synthetic_views())
    k = cal.intrinsics.matrix
    for got, true in ((k[0, 0], 610.0), (k[1, 1], 605.0), (k[0, 2], 322.0), (k[1, 2], 236.0)):
        assert _relative(got, true) < 0.01, (got, true)
    assert cal.rms_px < 0.5
    assert cal.views == 12
    assert len(cal.view_errors_px) == 12
    assert max(cal.view_errors_px) < 0.5
    assert abs(cal.intrinsics.distortion[0] - D_TRUE[0]) < 0.03
    assert cal.intrinsics.distortion[4] == 0.0  # k3 held at 0
    assert (cal.intrinsics.width, cal.intrinsics.height) == (WIDTH, HEIGHT)
    assert cal.board == DEFAULT_BOARD


def test_too_few_usable_views_says_how_many() -> None:
    blank = np.full((HEIGHT, WIDTH), 110, dtype=np.uint8)
    views = [*synthetic_views()[:5], blank, blank]
    with pytest.raises(InputError) as info:
        calibrate(views, source="shots")
    message = str(info.value)
    assert message.startswith("shots: only 5 of 7 views")
    assert f"need at least {MIN_VIEWS}" in message
    assert "\n" not in message


def test_views_of_different_sizes_are_refused() -> None:
    views = [*synthetic_views()[:8], np.zeros((240, 320), dtype=np.uint8)]
    with pytest.raises(InputError, match=r"picture 8 is 320x240, picture 0 is 640x480"):
        calibrate(views)


def test_detection_of_a_partly_hidden_board() -> None:
    view = synthetic_views()[0].copy()
    whole = detect_board(view)
    assert whole.count == DEFAULT_BOARD.corners == 24
    assert whole.usable
    np.testing.assert_allclose(whole.object_points[:, 2], 0.0)
    view[:, : WIDTH * 3 // 5] = 110  # most of the board out of sight
    part = detect_board(view)
    assert 0 < part.count < whole.count or not part.usable
    assert detect_board(np.full((HEIGHT, WIDTH), 110, dtype=np.uint8)).count == 0


def test_a_view_must_differ_from_the_earlier_ones() -> None:
    first = detect_board(synthetic_views()[0])
    again = Detection(first.ids, first.image_points + 2.0, first.object_points, usable=True)
    moved = Detection(first.ids, first.image_points + 60.0, first.object_points, usable=True)
    assert differs(first, [], WIDTH, HEIGHT)
    assert not differs(again, [first], WIDTH, HEIGHT)
    assert differs(moved, [first], WIDTH, HEIGHT)
    assert not differs(moved, [first, again, moved], WIDTH, HEIGHT)


def test_the_board_avoids_the_scene_markers_dictionary() -> None:
    assert DEFAULT_BOARD.dictionary == "5X5_100"
    scene_detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    )
    for picture in (board_image(DEFAULT_BOARD, 60), *synthetic_views()[:3]):
        _, ids, _ = scene_detector.detectMarkers(picture)
        assert ids is None or len(ids) == 0


def test_board_png_is_true_scale() -> None:
    img = Image.open(io.BytesIO(board_png(DEFAULT_BOARD)))
    dpi = img.info["dpi"][0]
    pixels_per_square = round(30 / 25.4 * 300)
    assert pixels_per_square / dpi * 25.4 == pytest.approx(30.0, abs=0.01)
    found = detect_board(np.asarray(img.convert("L")))
    assert found.count == 24


@pytest.mark.parametrize(
    ("spec", "needle"),
    [
        (lambda: BoardSpec(2, 5), "3 to 40 squares"),
        (lambda: BoardSpec(square=0.03, marker=0.03), "smaller than it"),
        (lambda: BoardSpec(dictionary="7X7_1"), "unknown marker dictionary"),
        (lambda: BoardSpec(15, 15, dictionary="4X4_50"), "more than the 50"),
    ],
)
def test_bad_boards_are_refused(spec: Callable[[], BoardSpec], needle: str) -> None:
    with pytest.raises(InputError, match=needle):
        spec()


# --- the calibration file ------------------------------------------------------------------


@pytest.fixture(scope="module")
def calibration_data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    path = tmp_path_factory.mktemp("cal") / "calib.json"
    save_calibration(calibrate(synthetic_views()), path)
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def test_round_trip(tmp_path: Path) -> None:
    cal = calibrate(synthetic_views())
    path = save_calibration(cal, tmp_path / "calib.json")
    assert [p.name for p in tmp_path.iterdir()] == ["calib.json"]  # no temporary left
    data = json.loads(path.read_text())
    assert set(data) == {
        "schema", "kind", "width", "height", "matrix", "distortion", "rms_px", "views",
        "view_errors_px", "board", "created",
    }  # fmt: skip
    assert data["schema"] == 1
    assert data["kind"] == "legws camera calibration"
    assert data["board"] == {
        "dictionary": "5X5_100", "squares_x": 7, "squares_y": 5, "square_m": 0.03,
        "marker_m": 0.022,
    }  # fmt: skip
    back = load_calibration(path)
    np.testing.assert_array_equal(back.intrinsics.matrix, cal.intrinsics.matrix)
    np.testing.assert_array_equal(back.intrinsics.distortion, cal.intrinsics.distortion)
    assert (back.rms_px, back.views, back.view_errors_px, back.board, back.created) == (
        cal.rms_px,
        cal.views,
        cal.view_errors_px,
        cal.board,
        cal.created,
    )
    assert (back.intrinsics.width, back.intrinsics.height) == (WIDTH, HEIGHT)


def _set(data: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    out: dict[str, Any] = json.loads(json.dumps(data))
    target: Any = out
    for key in path[:-1]:
        target = target[key]
    if value is _DELETE:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return out


_DELETE = object()

BAD_FILES = [
    (("matrix",), _DELETE, "matrix", "Field required"),
    (("matrix",), [[600, 0, 320], [0, 600, 240]], "matrix", "3x3 matrix"),
    (("matrix",), 600, "matrix", "valid tuple"),
    (("matrix", 0), [600, 0], "matrix[0]", "a row of 3 numbers, got 2"),
    (("matrix", 0, 0), float("nan"), "matrix[0][0]", "finite"),
    (("matrix", 0, 0), 0.0, "matrix[0][0]", "fx must be 0.02 to 100 times"),
    (("matrix", 1, 1), -600.0, "matrix[1][1]", "fy must be 0.02 to 100 times"),
    # accepted once (a tracker then died in OpenCV): 1e-300 px is no lens, nor is 1e9
    (("matrix", 0, 0), 1e-300, "matrix[0][0]", "(12.8 to 64000 px), got 1e-300"),
    (("matrix", 1, 1), 1e9, "matrix[1][1]", "(12.8 to 64000 px), got 1e+09"),
    (("matrix", 1, 1), 100.0, "matrix[1][1]", "fx / fy must be within 4 of 1"),
    (("matrix", 0, 1), 0.5, "matrix[0][1]", "must be 0"),
    (("matrix", 2, 2), 2.0, "matrix[2][2]", "must be 1"),
    (("matrix", 0, 2), 700.0, "matrix[0][2]", "cx must lie in the picture"),
    (("matrix", 1, 2), -3.0, "matrix[1][2]", "cy must lie in the picture"),
    (("matrix", 0, 0), "600", "matrix[0][0]", "valid number"),
    (("width",), 0, "width", "greater than or equal to 1"),
    (("height",), 480.0, "height", "valid integer"),
    (("distortion",), [0.1, 0.0, 0.0, 0.0], "distortion", "expected 5 numbers"),
    (("distortion", 0), 50.0, "distortion[0]", "describes no lens"),
    (("distortion", 2), 3.0, "distortion[2]", "describes no lens"),
    (("distortion", 1), float("inf"), "distortion[1]", "finite"),
    (("rms_px",), -1.0, "rms_px", "greater than or equal to 0"),
    (("views",), 3, "view_errors_px", "expected 3 numbers"),
    (("schema",), 2, "schema", "schema 1"),
    (("kind",), "legws layout", "kind", "legws camera calibration"),
    (("created",), "yesterday", "created", "ISO 8601"),
    (("created",), "2025-01-31T12:00:00", "created", "time zone"),
    (("board", "marker_m"), 0.04, "board.marker_m", "smaller than a square"),
    (("board", "dictionary"), "9X9_1", "board.dictionary", "unknown marker dictionary"),
    (("board", "squares_x"), 2, "board.squares_x", "greater than or equal to 3"),
    (("lens",), "wide", "lens", "Extra inputs"),
]


@pytest.mark.parametrize(
    ("where", "value", "field", "needle"), BAD_FILES, ids=[b[2] + ":" + b[3] for b in BAD_FILES]
)
def test_bad_calibration_file_is_one_line_naming_the_field(
    tmp_path: Path,
    calibration_data: dict[str, Any],
    where: tuple[Any, ...],
    value: Any,
    field: str,
    needle: str,
) -> None:
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(_set(calibration_data, where, value), allow_nan=True))
    with pytest.raises(InputError) as info:
        load_calibration(path)
    message = str(info.value)
    # one line of JSON: every field on line 1; a missing top-level key has no line
    at = str(path) if value is _DELETE and len(where) == 1 else f"{path}:1"
    assert message.startswith(f"{at}: {field}: "), message
    assert needle in message
    assert "\n" not in message


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("{not json", "invalid JSON at line 1"),
        ("[1, 2]", "valid dictionary"),
        ('{"schema": 1, "schema": 1}', "appears twice"),
        ("", "invalid JSON"),
    ],
)
def test_unreadable_calibration_file(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "calib.json"
    path.write_text(text)
    with pytest.raises(InputError, match=needle) as info:
        load_calibration(path)
    assert str(info.value).startswith(str(path))


def test_missing_calibration_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        load_calibration(tmp_path / "nope.json")


# --- another resolution ----------------------------------------------------------------------


def test_scaled_intrinsics_project_like_a_resized_picture() -> None:
    intr = Intrinsics(K_TRUE, D_TRUE, WIDTH, HEIGHT)
    assert scaled_intrinsics(intr, WIDTH, HEIGHT) is intr
    big = scaled_intrinsics(intr, 1280, 960)
    assert big.matrix[0, 0] == pytest.approx(1220.0)
    assert big.matrix[0, 2] == pytest.approx((322.0 + 0.5) * 2 - 0.5)
    np.testing.assert_array_equal(big.distortion, intr.distortion)
    points = np.array([[0.1, -0.05, 0.5], [-0.2, 0.1, 0.6], [0.0, 0.0, 1.0]])
    small_px, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), intr.matrix, intr.distortion)
    big_px, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), big.matrix, big.distortion)
    np.testing.assert_allclose(big_px, (small_px + 0.5) * 2 - 0.5, atol=1e-9)


def test_another_aspect_ratio_is_refused_naming_both_sizes() -> None:
    intr = Intrinsics(K_TRUE, D_TRUE, WIDTH, HEIGHT)
    with pytest.raises(InputError) as info:
        scaled_intrinsics(intr, 1280, 720, source="calib.json")
    message = str(info.value)
    assert message.startswith("calib.json: calibrated at 640x480")
    assert "1280x720" in message


def test_the_board_frame_matches_the_board_picture() -> None:
    """A corner's board coordinates and where it lies in :func:`board_image` agree (the
    synthetic views depend on it)."""
    img = board_image(DEFAULT_BOARD, PPS)
    found = detect_board(img)
    expected = (found.object_points[:, :2] / DEFAULT_BOARD.square + 0.5) * PPS - 0.5
    np.testing.assert_allclose(found.image_points, expected, atol=1.0)
    assert len(charuco_board(DEFAULT_BOARD).getIds()) == DEFAULT_BOARD.markers


def test_a_picture_is_measured_from_its_header_before_it_is_decoded() -> None:
    from legws_daemon.tracking.calibration import MAX_PICTURE_PIXELS, check_picture_size
    from tests.reliability.classes import png_header_only

    assert check_picture_size(png_header_only(640, 480), "a.png") == (640, 480)
    assert MAX_PICTURE_PIXELS < 10000 * 6000  # over ours, under PIL's own bound
    with pytest.raises(InputError, match=r"^b.png: 10000 x 6000 pixels is more than the 50 mi"):
        check_picture_size(png_header_only(10000, 6000), "b.png")
    with pytest.raises(InputError, match=r"^c.png: not a picture OpenCV can read"):
        check_picture_size(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40, "c.png")
