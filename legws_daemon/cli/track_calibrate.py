"""``legws track calibrate``: a camera's intrinsics from views of a printed ChArUco board.

Three uses, one at a time:

* ``--print-board board.pdf`` (or ``.png``): the board to print, at true scale;
* ``--images 'DIR/*.png' --out calib.json``: calibrate from photographs of it;
* ``--camera N --out calib.json``: calibrate live from a UVC camera, taking a view about
  every :data:`VIEW_INTERVAL_S` seconds while the board is in view and has moved since
  the views already taken; it stops at ``--views`` views, or at Ctrl-C with what it has.

OpenCV loads only when the command runs: ``legws --help`` and the other commands do not
pay for it.
"""

from __future__ import annotations

import glob
import os
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import click

from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path
from legws_daemon.formats.printable import echo

if TYPE_CHECKING:
    import cv2
    import numpy as np

    from legws_daemon.tracking.calibration import BoardSpec, Calibration, Detection

#: Least time between two views taken from a camera, s: the user moves the board between.
VIEW_INTERVAL_S = 0.7
#: Longest wait for a camera's frame, s, before it is called unreadable.
FRAME_TIMEOUT_S = 2.0
#: Picture files a folder given to ``--images`` is searched for.
PICTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _board_size(_ctx: click.Context, _param: click.Parameter, value: str) -> tuple[int, int]:
    cols, sep, rows = value.lower().partition("x")
    if not (sep and cols.isdigit() and rows.isdigit()):
        raise click.BadParameter(f"expected COLUMNSxROWS of squares, e.g. 7x5, got {value!r}")
    return int(cols), int(rows)


@click.command("calibrate")
@click.option(
    "--images",
    "patterns",
    multiple=True,
    help="Photographs of the board: a glob pattern (quote it), a file or a folder. Repeatable.",
)
@click.option(
    "--camera", type=click.IntRange(0, 1023), help="Calibrate live from camera N (a UVC index)."
)
@click.option(
    "--views",
    type=click.IntRange(8, 200),
    default=15,
    show_default=True,
    help="With --camera: views to take before calibrating.",
)
@click.option(
    "--out",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Calibration file (JSON) to write.",
)
@click.option(
    "--print-board",
    "board_files",
    multiple=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="Write the board to print: a .pdf (A4, true scale) and/or a .png (300 dpi).",
)
@click.option(
    "--board",
    "board_size",
    default="7x5",
    show_default=True,
    callback=_board_size,
    help="Squares of the board, COLUMNSxROWS.",
)
@click.option(
    "--square-mm",
    type=click.FloatRange(1, 1000),
    default=30.0,
    show_default=True,
    help="Side of a square, mm, as printed.",
)
@click.option(
    "--marker-mm",
    type=click.FloatRange(0.5, 1000),
    default=22.0,
    show_default=True,
    help="Side of a marker, mm, as printed.",
)
def calibrate_cmd(
    patterns: tuple[str, ...],
    camera: int | None,
    views: int,
    out: Path | None,
    board_files: tuple[Path, ...],
    board_size: tuple[int, int],
    square_mm: float,
    marker_mm: float,
) -> None:
    """Calibrate a camera's intrinsics with a printed ChArUco board.

    First print the board (--print-board board.pdf, at 100 %, and measure a square), then
    photograph it from 10-20 angles and distances (--images) or hold it in front of the
    camera (--camera). Prints the reprojection error (RMS, pixels; below 0.5 is good) and
    the camera matrix, and writes the calibration file that `legws track` reads.
    """
    from legws_daemon.tracking.calibration import BoardSpec

    uses = sum((bool(patterns), camera is not None, bool(board_files)))
    if uses != 1:
        raise InputError("give exactly one of --images, --camera and --print-board")
    spec = BoardSpec(board_size[0], board_size[1], square_mm / 1e3, marker_mm / 1e3)
    if board_files:
        _print_boards(board_files, spec)
        return
    if out is None:
        raise InputError("--out: name the calibration file to write")
    output_path(out)  # a folder or device there: one line before any work
    if camera is not None:
        detections, (width, height), names = _capture(camera, views, spec)
        source = f"camera {camera}"
    else:
        detections, (width, height), names = _from_files(_pictures(patterns), spec)
        source = "--images"
    from legws_daemon.tracking.calibration import calibrate_detections, save_calibration

    cal = calibrate_detections(detections, width, height, spec, source=source)
    save_calibration(cal, out)
    used = [n for n, d in zip(names, detections, strict=True) if d.usable]
    _report(cal, len(detections), used, out)


def _print_boards(paths: Sequence[Path], spec: BoardSpec) -> None:
    from legws_daemon.tracking.calibration import write_board

    for path in paths:
        write_board(path, spec)
        echo(f"wrote {path}: {spec.describe()}")
    echo(
        f"print at 100 % (not 'fit to page') and measure: a square must be "
        f"{spec.square * 1e3:g} mm; if not, pass the measured size as --square-mm and "
        "--marker-mm when calibrating"
    )


def _pictures(patterns: Sequence[str]) -> list[Path]:
    """The picture files named by ``--images``: glob patterns, files or folders."""
    found: list[Path] = []
    for pattern in patterns:
        if os.path.isdir(pattern):
            matches = sorted(
                p for p in Path(pattern).iterdir() if p.suffix.lower() in PICTURE_SUFFIXES
            )
        elif glob.has_magic(pattern):
            matches = [Path(p) for p in sorted(glob.glob(pattern))]
        else:
            matches = [Path(pattern)]
        if not matches:
            raise InputError(f"no pictures match {pattern!r}", source="--images")
        found += [p for p in matches if p not in found]
    return found


def _read_picture(path: Path) -> np.ndarray:
    import cv2
    import numpy as np

    from legws_daemon.formats.files import read_limited
    from legws_daemon.tracking.calibration import check_picture_size

    data = read_limited(path, "picture")
    check_picture_size(data, str(path))  # from its header: a small file may decode to GiB
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError("not a picture OpenCV can read (PNG, JPEG, BMP, TIFF)", source=str(path))
    return np.asarray(image)


def _from_files(
    paths: Sequence[Path], spec: BoardSpec
) -> tuple[list[Detection], tuple[int, int], list[str]]:
    """The board found in each picture, the pictures' common size, their names."""
    from legws_daemon.tracking.calibration import detect_board

    detections: list[Detection] = []
    size: tuple[int, int] | None = None
    for path in paths:
        image = _read_picture(path)
        here = (image.shape[1], image.shape[0])
        if size is None:
            size = here
        elif here != size:
            raise InputError(
                f"is {here[0]}x{here[1]}, the pictures before it {size[0]}x{size[1]}; all "
                "must come from the camera at one resolution",
                source=str(path),
            )
        found = detect_board(image, spec)
        note = "" if found.usable else ", left out"
        echo(f"{path}: {found.count} of {spec.corners} corners{note}")
        detections.append(found)
    assert size is not None  # _pictures never returns an empty list
    return detections, size, [str(p) for p in paths]


def _frames(cap: cv2.VideoCapture, index: int) -> Iterator[np.ndarray]:
    """The camera's frames as they come; an error when none comes for
    :data:`FRAME_TIMEOUT_S` seconds."""
    deadline = time.monotonic() + FRAME_TIMEOUT_S
    while True:
        ok, frame = cap.read()
        if ok and frame is not None:
            deadline = time.monotonic() + FRAME_TIMEOUT_S
            yield frame
        elif time.monotonic() > deadline:
            raise InputError(
                f"the camera delivered no picture for {FRAME_TIMEOUT_S:g} s",
                source=f"camera {index}",
            )


def _capture(
    index: int, wanted: int, spec: BoardSpec
) -> tuple[list[Detection], tuple[int, int], list[str]]:
    """Views of the board from camera ``index``: up to ``wanted``, or fewer at Ctrl-C."""
    from legws_daemon.tracking.calibration import MIN_VIEWS, detect_board, differs
    from legws_daemon.tracking.stream import open_camera

    cap = open_camera(index)
    taken: list[Detection] = []
    size = (0, 0)
    try:
        frames = _frames(cap, index)
        first = next(frames)
        size = (first.shape[1], first.shape[0])
        echo(
            f"camera {index}: {size[0]}x{size[1]}; show the board at different angles and "
            f"distances, tilted, in every part of the picture; Ctrl-C stops "
            f"(at least {MIN_VIEWS} views)"
        )
        last = -VIEW_INTERVAL_S
        for frame in frames:
            now = time.monotonic()
            if now - last < VIEW_INTERVAL_S:
                continue
            found = detect_board(frame, spec)
            if found.usable and differs(found, taken, *size):
                taken.append(found)
                last = now
                echo(f"view {len(taken)}/{wanted}: {found.count} of {spec.corners} corners")
                if len(taken) >= wanted:
                    break
    except KeyboardInterrupt:
        echo(f"stopped with {len(taken)} views")
    finally:
        cap.release()
    return taken, size, [f"view {i + 1}" for i in range(len(taken))]


def _report(cal: Calibration, offered: int, used: Sequence[str], out: Path) -> None:
    k = cal.intrinsics.matrix
    d = cal.intrinsics.distortion
    width, height = cal.intrinsics.width, cal.intrinsics.height
    echo(
        f"calibrated {width}x{height} from {cal.views} of {offered} views: "
        f"RMS reprojection error {cal.rms_px:.3f} px"
    )
    echo(f"fx {k[0, 0]:.2f}  fy {k[1, 1]:.2f}  cx {k[0, 2]:.2f}  cy {k[1, 2]:.2f} px")
    echo(f"distortion k1 {d[0]:.4f}  k2 {d[1]:.4f}  p1 {d[2]:.5f}  p2 {d[3]:.5f}  k3 {d[4]:.4f}")
    worst = max(range(len(used)), key=lambda i: cal.view_errors_px[i])
    echo(f"worst view: {used[worst]} ({cal.view_errors_px[worst]:.3f} px)")
    if cal.rms_px > 1.0:
        echo(
            "an RMS above 1 px suggests a bent board, blurred views or the wrong board size: "
            "retake the worst views"
        )
    echo(f"wrote {out}")
