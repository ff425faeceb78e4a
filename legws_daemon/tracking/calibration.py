"""A camera's intrinsics from views of a ChArUco board (``legws track calibrate``), and the
calibration file that keeps them.

The board is a chessboard whose white squares hold ArUco markers: the markers name each
chessboard corner, so a view that shows only part of the board still yields corners with
known board coordinates, and the chessboard corners refine to a fraction of a pixel. Its
markers come from :data:`BOARD_DICTIONARY` (``5X5_100``), not from the scenes' usual
``4X4_50``: a board in view never reads as table or object markers.

:func:`calibrate` detects the board in each view (:func:`detect_board`), keeps the views
that show enough corners not on one line, and fits OpenCV's pinhole camera with lens
distortion ``k1, k2, p1, p2`` (``k3`` is held at 0: a webcam's lens needs no sixth-order
term, and a dozen views cannot pin it down). The result, a :class:`Calibration`, is
written as JSON by :func:`save_calibration` and read back, fully validated, by
:func:`load_calibration`; :func:`scaled_intrinsics` adapts it to a camera that delivers
another resolution of the same picture.
"""

from __future__ import annotations

import io
import json
import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Annotated, Any, Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictInt, field_validator, model_validator

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path, write_atomic
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.scene_file import MARKER_DICTIONARIES
from legws_daemon.formats.validation import (
    Finite,
    did_you_mean,
    field_error,
    read_json_with_lines,
    validate,
)
from legws_daemon.tracking.camera import MAX_ASPECT, MAX_FOCAL, MIN_FOCAL, Intrinsics
from legws_daemon.tracking.markers import dictionary

#: The board's marker dictionary: not the scenes' ``4X4_50``, so that the board's markers
#: are never taken for the scene's (the detector of a 4x4 dictionary does not read 5x5).
BOARD_DICTIONARY = "5X5_100"
#: Fewest usable views :func:`calibrate` accepts: fewer leave the focal length and the
#: principal point poorly determined (OpenCV's samples use 10-20).
MIN_VIEWS = 8
#: Fewest chessboard corners a usable view shows (and not all on one line).
MIN_CORNERS = 6
#: Least mean shift of the corners, as a fraction of the picture's diagonal, between a new
#: view from a camera and each earlier one (24 pixels at 640x480).
MIN_SHIFT = 0.03
#: Largest magnitude of the radial coefficients ``k1, k2, k3`` a file may hold: real lenses,
#: fisheyes aside, stay below 1; beyond 10 the numbers describe no lens.
MAX_RADIAL = 10.0
#: Largest magnitude of the tangential coefficients ``p1, p2`` (real lenses: below 0.01).
MAX_TANGENTIAL = 1.0
#: Relative difference of aspect ratios below which another resolution is taken for the
#: same picture scaled (1280x720 and 1920x1080 differ by 0; 640x480 and 1280x720 by 25 %).
ASPECT_TOLERANCE = 0.005
#: What the calibration file's ``kind`` says.
FILE_KIND = "legws camera calibration"
#: A4 paper, portrait, mm.
A4_MM = (210.0, 297.0)
#: Blank paper kept around the board on a printed page, mm (printers do not print to the
#: edge, and the detector wants a white margin around the outer markers).
PAGE_MARGIN_MM = 12.0
MM_PER_INCH = 25.4


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares_x`` by ``squares_y`` chessboard squares of side
    ``square`` (m), markers of side ``marker`` (m) from ``dictionary`` in the white ones.

    The default, 7 x 5 squares of 30 mm with 22 mm markers, fits on A4 paper.
    """

    squares_x: int = 7
    squares_y: int = 5
    square: float = 0.030
    marker: float = 0.022
    dictionary: str = BOARD_DICTIONARY

    def __post_init__(self) -> None:
        if not (3 <= self.squares_x <= 40 and 3 <= self.squares_y <= 40):
            raise InputError(
                f"the board needs 3 to 40 squares each way, got {self.squares_x}x{self.squares_y}"
            )
        if not (math.isfinite(self.square) and 0.001 <= self.square <= 1.0):
            raise InputError(
                f"the board's squares must be 1 to 1000 mm, got {self.square * 1e3:g} mm"
            )
        if not (math.isfinite(self.marker) and 0.5 * self.square <= self.marker < self.square):
            raise InputError(
                f"the board's markers must be at least half a square and smaller than it "
                f"({self.square * 1e3:g} mm), got {self.marker * 1e3:g} mm"
            )
        available = MARKER_DICTIONARIES.get(self.dictionary)
        if available is None:
            raise InputError(
                f"unknown marker dictionary '{self.dictionary}'; known: "
                + ", ".join(MARKER_DICTIONARIES)
            )
        if self.markers > available:
            raise InputError(
                f"a {self.squares_x}x{self.squares_y} board holds {self.markers} markers, "
                f"more than the {available} of dictionary {self.dictionary}"
            )

    @property
    def markers(self) -> int:
        """How many markers the board holds (one in every white square)."""
        return self.squares_x * self.squares_y // 2

    @property
    def corners(self) -> int:
        """How many inner chessboard corners the board has (the points calibrated on)."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def size_mm(self) -> tuple[float, float]:
        """Width and height of the board, mm."""
        return self.squares_x * self.square * 1e3, self.squares_y * self.square * 1e3

    def describe(self) -> str:
        """One line to print on the board and in reports."""
        w, h = self.size_mm
        return (
            f"ChArUco board {self.squares_x} x {self.squares_y} squares of "
            f"{self.square * 1e3:g} mm, markers {self.marker * 1e3:g} mm, "
            f"dictionary {self.dictionary}; {w:g} x {h:g} mm"
        )

    def to_data(self) -> dict[str, Any]:
        """The ``board`` object of the calibration file."""
        return {
            "dictionary": self.dictionary,
            "squares_x": self.squares_x,
            "squares_y": self.squares_y,
            "square_m": self.square,
            "marker_m": self.marker,
        }


#: The board :func:`calibrate` expects unless told otherwise.
DEFAULT_BOARD = BoardSpec()


@cache
def charuco_board(spec: BoardSpec) -> cv2.aruco.CharucoBoard:
    """OpenCV's board of ``spec`` (board frame: origin at the top-left outer corner, x to
    the right, y down the printed board, metres)."""
    return cv2.aruco.CharucoBoard(
        (spec.squares_x, spec.squares_y), spec.square, spec.marker, dictionary(spec.dictionary)
    )


@cache
def _detector(spec: BoardSpec) -> cv2.aruco.CharucoDetector:
    return cv2.aruco.CharucoDetector(charuco_board(spec))


def board_image(spec: BoardSpec = DEFAULT_BOARD, pixels_per_square: int = 100) -> np.ndarray:
    """The board's picture, ``uint8`` grey, black on white, ``pixels_per_square`` pixels
    per square, with a white margin of ``m = pixels_per_square // 2`` pixels around it.

    The centre of pixel ``(u, v)`` shows the board point
    ``((u + 0.5 - m) / pixels_per_square, (v + 0.5 - m) / pixels_per_square)`` squares
    from the board's top-left corner.
    """
    if pixels_per_square < 10:
        raise InputError(
            f"a board picture needs at least 10 pixels per square: {pixels_per_square}"
        )
    margin = pixels_per_square // 2
    size = (spec.squares_x * pixels_per_square, spec.squares_y * pixels_per_square)
    img = charuco_board(spec).generateImage(size, marginSize=0, borderBits=1)
    return np.pad(np.asarray(img, dtype=np.uint8), margin, constant_values=255)


# --- detection and calibration ----------------------------------------------------------


@dataclass(frozen=True)
class Detection:
    """The board's chessboard corners found in one view.

    Attributes:
        ids: ``(N,)`` the corners' ids (row-major over the inner corners).
        image_points: ``(N, 2)`` where they are in the picture, pixels.
        object_points: ``(N, 3)`` where they are on the board, m (z = 0).
        usable: at least :data:`MIN_CORNERS` corners, not all on one line.
    """

    ids: np.ndarray
    image_points: FloatArray
    object_points: FloatArray
    usable: bool

    @property
    def count(self) -> int:
        return len(self.ids)


def _grey(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    if image.ndim == 3 and image.shape[2] == 4:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY))
    raise InputError(f"expected a grey, BGR or BGRA picture, got an array of shape {image.shape}")


def detect_board(image: np.ndarray, spec: BoardSpec = DEFAULT_BOARD) -> Detection:
    """The chessboard corners of the board ``spec`` in ``image`` (grey, BGR or BGRA)."""
    corners, ids, _, _ = _detector(spec).detectBoard(_grey(image))
    if ids is None or corners is None or len(ids) == 0:
        none = np.zeros((0, 3))
        return Detection(np.zeros(0, dtype=np.int32), none[:, :2], none, usable=False)
    board = charuco_board(spec)
    # the corners go in as one array (OpenCV's stubs ask for a sequence of arrays: that
    # would be a marker board's per-marker corners, another code path)
    obj, img = board.matchImagePoints(corners, ids)  # type: ignore[call-overload]
    ids = np.asarray(ids, dtype=np.int32).reshape(-1)
    usable = len(ids) >= MIN_CORNERS and not board.checkCharucoCornersCollinear(ids)
    return Detection(
        ids,
        np.asarray(img, dtype=np.float64).reshape(-1, 2),
        np.asarray(obj, dtype=np.float64).reshape(-1, 3),
        usable=bool(usable),
    )


def differs(candidate: Detection, previous: Sequence[Detection], width: int, height: int) -> bool:
    """Whether a view adds to ``previous`` ones: its corners lie, on average, at least
    :data:`MIN_SHIFT` of the picture's diagonal away from where the same corners lay in
    every earlier view (the board moved, turned or tilted; a board held still, give or
    take a trembling hand, adds nothing)."""
    threshold = MIN_SHIFT * math.hypot(width, height)
    for view in previous:
        common, here, there = np.intersect1d(candidate.ids, view.ids, return_indices=True)
        if len(common) == 0:
            continue
        shift = np.linalg.norm(candidate.image_points[here] - view.image_points[there], axis=1)
        if float(np.mean(shift)) < threshold:
            return False
    return True


@dataclass(frozen=True)
class Calibration:
    """A camera's calibration.

    Attributes:
        intrinsics: the camera matrix, distortion and the picture size calibrated at.
        rms_px: root-mean-square reprojection error over all corners of all views, pixels.
        views: how many views were used.
        view_errors_px: each used view's RMS reprojection error, pixels, in order.
        board: the board calibrated with.
        created: when, ISO 8601 with time zone.
    """

    intrinsics: Intrinsics
    rms_px: float
    views: int
    view_errors_px: tuple[float, ...]
    board: BoardSpec
    created: str


def calibrate(
    images: Sequence[np.ndarray], spec: BoardSpec = DEFAULT_BOARD, *, source: str = "calibration"
) -> Calibration:
    """Calibrate a camera from pictures of the board ``spec`` (all of one size).

    Raises:
        InputError: pictures of different sizes, or fewer than :data:`MIN_VIEWS` usable
            views (the message says how many were usable), or a fit that fails.
    """
    if not images:
        raise InputError("no pictures to calibrate from", source=source)
    height, width = images[0].shape[:2]
    for i, img in enumerate(images):
        if img.shape[:2] != (height, width):
            raise InputError(
                f"picture {i} is {img.shape[1]}x{img.shape[0]}, picture 0 is {width}x{height}; "
                "all views must come from the camera at one resolution",
                source=source,
            )
    return calibrate_detections(
        [detect_board(img, spec) for img in images], width, height, spec, source=source
    )


def calibrate_detections(
    detections: Sequence[Detection],
    width: int,
    height: int,
    spec: BoardSpec = DEFAULT_BOARD,
    *,
    source: str = "calibration",
) -> Calibration:
    """Calibrate from the board's corners found in views of ``width`` x ``height`` pixels;
    the views that are not :attr:`Detection.usable` are left out.

    Raises:
        InputError: fewer than :data:`MIN_VIEWS` usable views, or a fit that does not give
            a plausible camera.
    """
    used = [d for d in detections if d.usable]
    if len(used) < MIN_VIEWS:
        raise InputError(
            f"only {len(used)} of {len(detections)} views show the board with at least "
            f"{MIN_CORNERS} corners; need at least {MIN_VIEWS}: show the whole board, from "
            "several angles and distances, in focus",
            source=source,
        )
    obj = [d.object_points.astype(np.float32) for d in used]
    img = [d.image_points.astype(np.float32).reshape(-1, 1, 2) for d in used]
    try:
        rms, k, dist, _, _, _, _, per_view = cv2.calibrateCameraExtended(
            obj, img, (width, height), np.eye(3), np.zeros(5), flags=cv2.CALIB_FIX_K3
        )
    except cv2.error as err:
        detail = " ".join(str(err).split())
        raise InputError(f"the calibration failed: {detail}", source=source) from None
    data = {
        "schema": 1,
        "kind": FILE_KIND,
        "width": width,
        "height": height,
        "matrix": np.asarray(k, dtype=np.float64).tolist(),
        "distortion": np.asarray(dist, dtype=np.float64).reshape(-1)[:5].tolist(),
        "rms_px": float(rms),
        "views": len(used),
        "view_errors_px": np.asarray(per_view, dtype=np.float64).reshape(-1).tolist(),
        "board": spec.to_data(),
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    try:
        return calibration_from_data(data, source)
    except InputError as err:
        raise InputError(
            f"the fit gave no plausible camera ({err}); take views with the board tilted "
            "towards and away from the camera, filling the picture's corners too",
            source=source,
        ) from None


# --- the calibration file ---------------------------------------------------------------

_Count = Annotated[StrictInt, Field(ge=1, le=100_000)]
_Row = tuple[Finite, Finite, Finite]


class _BoardModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    dictionary: str
    squares_x: Annotated[StrictInt, Field(ge=3, le=40)]
    squares_y: Annotated[StrictInt, Field(ge=3, le=40)]
    square_m: Annotated[Finite, Field(ge=0.001, le=1.0)]
    marker_m: Annotated[Finite, Field(gt=0, le=1.0)]


class _CalibrationModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    schema_: StrictInt = Field(alias="schema")
    kind: Literal["legws camera calibration"]
    width: _Count
    height: _Count
    matrix: tuple[_Row, _Row, _Row]
    distortion: tuple[Finite, Finite, Finite, Finite, Finite]
    rms_px: Annotated[Finite, Field(ge=0)]
    views: _Count
    view_errors_px: list[Annotated[Finite, Field(ge=0)]]
    board: _BoardModel
    created: Annotated[str, Field(max_length=64)]

    @field_validator("matrix", mode="before")
    @classmethod
    def _three_by_three(cls, value: Any) -> Any:
        # pydantic would call a short row's missing number "Field required"
        if isinstance(value, list):
            if len(value) != 3:
                raise ValueError(
                    f"expected a 3x3 matrix, 3 rows of 3 numbers; this one has {len(value)}"
                )
            for i, row in enumerate(value):
                if isinstance(row, list) and len(row) != 3:
                    raise field_error((i,), f"expected a row of 3 numbers, got {len(row)}")
        return value

    @field_validator("distortion", mode="before")
    @classmethod
    def _five_coefficients(cls, value: Any) -> Any:
        if isinstance(value, list) and len(value) != 5:
            raise ValueError(f"expected 5 numbers k1, k2, p1, p2, k3; {len(value)} given")
        return value

    @field_validator("schema_")
    @classmethod
    def _known_schema(cls, schema: int) -> int:
        if schema != 1:
            raise ValueError("this legws reads calibration files of schema 1 only")
        return schema

    @field_validator("created")
    @classmethod
    def _iso_time(cls, text: str) -> str:
        try:
            when = datetime.fromisoformat(text)
        except ValueError:
            raise ValueError("expected an ISO 8601 time, e.g. 2025-01-31T12:00:00+00:00") from None
        if when.tzinfo is None:
            raise ValueError("the time needs a time zone, e.g. +00:00")
        return text

    @model_validator(mode="after")
    def _plausible(self) -> _CalibrationModel:
        m = self.matrix
        size = max(self.width, self.height)
        for loc, value in (((0, 0), "fx"), ((1, 1), "fy")):
            f = m[loc[0]][loc[1]]
            if not MIN_FOCAL * size <= f <= MAX_FOCAL * size:
                raise field_error(
                    ("matrix", *loc),
                    f"the focal length {value} must be {MIN_FOCAL:g} to {MAX_FOCAL:g} times the "
                    f"picture's larger side ({MIN_FOCAL * size:g} to {MAX_FOCAL * size:g} px), "
                    f"got {f:g}",
                )
        if not 1 / MAX_ASPECT <= m[0][0] / m[1][1] <= MAX_ASPECT:
            raise field_error(
                ("matrix", 1, 1),
                f"fx / fy must be within {MAX_ASPECT:g} of 1 (square-ish pixels), got "
                f"{m[0][0] / m[1][1]:g}",
            )
        for loc in ((0, 1), (1, 0), (2, 0), (2, 1)):
            if m[loc[0]][loc[1]] != 0:
                raise field_error(
                    ("matrix", *loc),
                    "must be 0: OpenCV's camera matrix is [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]",
                )
        if m[2][2] != 1:
            raise field_error(("matrix", 2, 2), f"must be 1, got {m[2][2]:g}")
        for loc, name, size in (((0, 2), "cx", self.width), ((1, 2), "cy", self.height)):
            c = m[loc[0]][loc[1]]
            if not 0 <= c <= size:
                raise field_error(
                    ("matrix", *loc),
                    f"the principal point's {name} must lie in the picture (0 to {size}), "
                    f"got {c:g}",
                )
        for i, name in enumerate(("k1", "k2", "p1", "p2", "k3")):
            limit = MAX_TANGENTIAL if name.startswith("p") else MAX_RADIAL
            if abs(self.distortion[i]) > limit:
                raise field_error(
                    ("distortion", i),
                    f"{name} = {self.distortion[i]:g} describes no lens (|{name}| must be at "
                    f"most {limit:g})",
                )
        if len(self.view_errors_px) != self.views:
            raise field_error(
                ("view_errors_px",),
                f"expected {self.views} numbers (one per view), got {len(self.view_errors_px)}",
            )
        b = self.board
        if b.dictionary not in MARKER_DICTIONARIES:
            guess = did_you_mean(b.dictionary, MARKER_DICTIONARIES)
            hint = f"; did you mean '{guess}'?" if guess is not None else ";"
            raise field_error(
                ("board", "dictionary"),
                f"unknown marker dictionary {b.dictionary!r}{hint} known: "
                + ", ".join(MARKER_DICTIONARIES),
            )
        if b.marker_m >= b.square_m:
            raise field_error(("board", "marker_m"), "a marker must be smaller than a square")
        return self


def calibration_from_data(data: Any, source: str, where: SourceText | None = None) -> Calibration:
    """A :class:`Calibration` from the parsed JSON of a calibration file (``where``: its
    text, for the line of each error).

    Raises:
        InputError: naming ``source``, the line (from ``where``) and the field of every
            error of the file's fields, or of the first check across fields that fails.
    """
    doc = validate(_CalibrationModel, data, source, where)
    b = doc.board
    try:
        board = BoardSpec(b.squares_x, b.squares_y, b.square_m, b.marker_m, b.dictionary)
    except InputError as err:
        at = where.at(source, ("board",)) if where is not None else source
        raise InputError(str(err), source=at, field="board") from None
    intrinsics = Intrinsics(np.array(doc.matrix), np.array(doc.distortion), doc.width, doc.height)
    return Calibration(
        intrinsics,
        doc.rms_px,
        doc.views,
        tuple(doc.view_errors_px),
        board,
        doc.created,
    )


def calibration_to_data(cal: Calibration) -> dict[str, Any]:
    """The JSON object of the calibration file."""
    intr = cal.intrinsics
    return {
        "schema": 1,
        "kind": FILE_KIND,
        "width": intr.width,
        "height": intr.height,
        "matrix": np.asarray(intr.matrix, dtype=np.float64).tolist(),
        "distortion": np.asarray(intr.distortion, dtype=np.float64).tolist(),
        "rms_px": cal.rms_px,
        "views": cal.views,
        "view_errors_px": list(cal.view_errors_px),
        "board": cal.board.to_data(),
        "created": cal.created,
    }


def save_calibration(cal: Calibration, path: Path) -> Path:
    """Write the calibration file atomically (a reader never sees half of it)."""
    text = json.dumps(calibration_to_data(cal), indent=2, allow_nan=False) + "\n"
    return write_atomic(path, text.encode("utf-8"))


#: Largest picture decoded, pixels (8K UHD is 33 MP): a 1 MB PNG can say 32000 x 32000.
MAX_PICTURE_PIXELS = 50_000_000


def check_picture_size(data: bytes, source: str) -> tuple[int, int]:
    """A picture file's width and height from its header, before anything decodes it.

    Raises:
        InputError: not a picture the header of which PIL reads (PNG, JPEG, BMP, TIFF, …),
            or more than :data:`MAX_PICTURE_PIXELS` pixels.
    """
    from PIL import Image, UnidentifiedImageError

    too_big = (f"is more than the {MAX_PICTURE_PIXELS / 1e6:g} million pixels a calibration "
               "picture may have (nothing was decoded)")  # fmt: skip
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as picture:  # reads the header only
                width, height = picture.size
    except Image.DecompressionBombError as err:  # PIL's own bound, far above ours
        said = re.search(r"\((\d+) pixels\)", str(err))
        pixels = f"{int(said[1]):,} pixels" if said else "its size"
        raise InputError(f"{pixels} {too_big}", source=source) from None
    except (UnidentifiedImageError, OSError, ValueError):
        raise InputError(
            "not a picture OpenCV can read (PNG, JPEG, BMP, TIFF)", source=source
        ) from None
    if width * height > MAX_PICTURE_PIXELS:
        raise InputError(f"{width} x {height} pixels {too_big}", source=source)
    return width, height


def load_calibration(path: Path) -> Calibration:
    """Read a calibration file; each error is a line naming the file, the line and the
    field (every error of the fields)."""
    data, where = read_json_with_lines(path, "camera calibration")
    return calibration_from_data(data, str(path), where)


def scaled_intrinsics(
    intrinsics: Intrinsics, width: int, height: int, *, source: str = "calibration"
) -> Intrinsics:
    """``intrinsics`` for the same camera delivering ``width`` x ``height`` pixels.

    A camera that delivers another resolution of the same picture (same aspect ratio,
    within :data:`ASPECT_TOLERANCE`) scales it: the focal lengths and the principal point
    scale with the pixel size (pixel centres kept: ``c' = (c + 0.5) s - 0.5``); the
    distortion, in normalised coordinates, stays. Another aspect ratio means a cropped
    picture, whose principal point cannot be known: an error naming both sizes.
    """
    w0, h0 = intrinsics.width, intrinsics.height
    if (width, height) == (w0, h0):
        return intrinsics
    if width < 1 or height < 1:
        raise InputError(f"a picture size must be positive, got {width}x{height}", source=source)
    if abs((width / height) / (w0 / h0) - 1) > ASPECT_TOLERANCE:
        raise InputError(
            f"calibrated at {w0}x{h0} but the camera delivers {width}x{height}, another "
            f"aspect ratio (a cropped picture); calibrate again at {width}x{height}",
            source=source,
        )
    sx, sy = width / w0, height / h0
    k = np.array(intrinsics.matrix, dtype=np.float64)
    k[0, 0] *= sx
    k[1, 1] *= sy
    k[0, 2] = (k[0, 2] + 0.5) * sx - 0.5
    k[1, 2] = (k[1, 2] + 0.5) * sy - 0.5
    return Intrinsics(k, intrinsics.distortion.copy(), width, height)


# --- the printed board ------------------------------------------------------------------


def _black_squares(spec: BoardSpec) -> list[tuple[int, int]]:
    """The ``(column, row)`` of the board's black squares, read off OpenCV's picture (which
    squares are black depends on the pattern OpenCV draws)."""
    pps = 40
    img = charuco_board(spec).generateImage(
        (spec.squares_x * pps, spec.squares_y * pps), marginSize=0, borderBits=1
    )
    # a point in the white border every marker keeps inside its square
    inset = max(1, int(pps * (1 - spec.marker / spec.square) / 4))
    return [
        (c, r)
        for r in range(spec.squares_y)
        for c in range(spec.squares_x)
        if img[r * pps + inset, c * pps + inset] < 128
    ]


def _black_rects(spec: BoardSpec) -> list[tuple[float, float, float, float]]:
    """The board as black rectangles ``(x, y, w, h)`` in mm, board frame (y down): its
    black squares and each marker's black cells, merged along rows."""
    sq = spec.square * 1e3
    rects = [(c * sq, r * sq, sq, sq) for c, r in _black_squares(spec)]
    board = charuco_board(spec)
    cells = int(board.getDictionary().markerSize) + 2
    cell = spec.marker * 1e3 / cells
    for marker_id, corners in zip(board.getIds(), board.getObjPoints(), strict=True):
        x0, y0 = (float(v) * 1e3 for v in np.asarray(corners).reshape(-1, 3)[0][:2])
        bits = cv2.aruco.generateImageMarker(board.getDictionary(), int(marker_id), cells)
        for row in range(cells):
            col = 0
            while col < cells:
                if bits[row, col] >= 128:
                    col += 1
                    continue
                end = col
                while end < cells and bits[row, end] < 128:
                    end += 1
                rects.append((x0 + col * cell, y0 + row * cell, (end - col) * cell, cell))
                col = end
    return rects


def _page_mm(spec: BoardSpec) -> tuple[float, float]:
    """The A4 page (portrait or landscape) the board fits on with its margins and caption."""
    w, h = spec.size_mm
    need_w, need_h = w + 2 * PAGE_MARGIN_MM, h + 2 * PAGE_MARGIN_MM + 15.0
    for page in (A4_MM, A4_MM[::-1]):
        if need_w <= page[0] and need_h <= page[1]:
            return page
    raise InputError(
        f"a {w:g} x {h:g} mm board does not fit on A4 paper at true scale; use fewer or "
        "smaller squares, or print the PNG at its true size"
    )


def board_pdf(spec: BoardSpec = DEFAULT_BOARD) -> bytes:
    """A one-page A4 PDF of the board at true scale, drawn in vectors, with its dimensions
    written under it (print at 100 %, then measure)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    page_w, page_h = _page_mm(spec)
    w, h = spec.size_mm
    x0 = (page_w - w) / 2
    y0 = PAGE_MARGIN_MM + 10.0
    fig = Figure(figsize=(page_w / MM_PER_INCH, page_h / MM_PER_INCH))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0, page_w)
    ax.set_ylim(page_h, 0)  # mm from the top-left corner of the page, y down
    ax.set_axis_off()
    for x, y, rw, rh in _black_rects(spec):
        ax.add_patch(
            Rectangle((x0 + x, y0 + y), rw, rh, facecolor="black", edgecolor="none", linewidth=0)
        )
    ax.text(page_w / 2, PAGE_MARGIN_MM + 3, spec.describe(), ha="center", va="center", fontsize=8)
    check = (
        f"print at 100 % (no 'fit to page'), then measure: one square {spec.square * 1e3:g} mm, "
        f"the board {w:g} mm wide. Keep it flat (glue it to a rigid board)."
    )
    ax.text(page_w / 2, y0 + h + 7, check, ha="center", va="center", fontsize=7)
    buf = io.BytesIO()
    fig.savefig(buf, format="pdf", metadata={"Title": spec.describe(), "Creator": "legws"})
    return buf.getvalue()


def board_png(spec: BoardSpec = DEFAULT_BOARD, dpi: float = 300.0) -> bytes:
    """A PNG of the board at about ``dpi``, with its dimensions written under it.

    The squares are a whole number of pixels; the resolution stored in the PNG is the
    one that makes them exactly ``spec.square`` (e.g. 354 pixels per 30 mm: 299.7 dpi),
    so a printer honouring it prints the board at true scale.
    """
    from PIL import Image

    pps = round(spec.square * 1e3 / MM_PER_INCH * dpi)
    img = board_image(spec, pps)
    caption = np.full((pps // 2, img.shape[1]), 255, dtype=np.uint8)
    scale = pps / 200
    for i, text in enumerate((spec.describe(), "print at 100 %, then measure one square")):
        cv2.putText(
            caption,
            text,
            (pps // 2, int((i + 1) * pps / 5)),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            0,
            max(1, round(2 * scale)),
            cv2.LINE_AA,
        )
    true_dpi = pps / (spec.square * 1e3) * MM_PER_INCH
    buf = io.BytesIO()
    Image.fromarray(np.vstack([img, caption])).save(buf, format="PNG", dpi=(true_dpi, true_dpi))
    return buf.getvalue()


def write_board(path: Path, spec: BoardSpec = DEFAULT_BOARD) -> Path:
    """Write the printable board to ``path``: a PDF (A4, true scale) or a 300 dpi PNG,
    chosen by the file's suffix."""
    suffix = Path(path).suffix.lower()
    if suffix not in (".pdf", ".png"):
        raise InputError("the board is written as a .pdf or a .png file", source=str(path))
    output_path(path)  # a folder or device there: one line before drawing
    return write_atomic(path, board_pdf(spec) if suffix == ".pdf" else board_png(spec))
