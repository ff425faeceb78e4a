"""``legws track``'s loop: frames from a camera (or the stand-in's rendered camera) in, the
objects' poses out on ``legws/<robot>/objects``.

Each frame stands alone (:class:`~legws_daemon.tracking.tracker.Tracker`): a message carries
only the objects measured in that frame, stamped with the frame's capture time. An object
missing from :data:`UNSEEN_AFTER` frames in a row is listed ``unseen`` (a single missed
frame is not news: it is simply not reported). A frame that cannot be read publishes
nothing, so a drop-out never passes an old pose off as fresh; the daemon turns objects it
has not heard of for a second unseen by itself.

Sources:

* :class:`CameraSource` — a UVC camera through OpenCV (``--camera N``), with the
  intrinsics of a calibration file (``legws track calibrate``).
* :class:`SimSource` — the MuJoCo stand-in's camera (``--source sim:SCENE[:LAYOUT]``)
  over the layout the daemon runs (:class:`~legws_daemon.tracking.follow.DaemonLayout`),
  or the scene file's; a layout file's objects and ``--move`` shifts over it, rendered
  again whenever any of them changes: move an object by editing the file.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import SCHEMA_VERSION, ObjectsMessage, dump
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.joystick.publisher import publisher_config
from legws_daemon.scene.layout_file import load_layout
from legws_daemon.scene.scene import Layout, ObjectPose, Scene
from legws_daemon.tracking.camera import Intrinsics
from legws_daemon.tracking.follow import DaemonLayout
from legws_daemon.tracking.tracker import Tracker, TrackFrame
from legws_daemon.transport.session import keys, open_session

#: An object missing from this many frames in a row is reported unseen.
UNSEEN_AFTER = 3
#: How long opening a camera may take to deliver its first frame, s.
FIRST_FRAME_TIMEOUT = 2.0
#: The same warning text at most this often on standard error, s.
WARNING_INTERVAL = 10.0
#: Highest tracking rate, Hz.
MAX_RATE = 60.0


class FrameSource(Protocol):
    """Where frames come from."""

    intrinsics: Intrinsics
    name: str

    def read(self) -> np.ndarray | None:
        """The next frame (BGR ``uint8``), or ``None`` when none could be read."""

    def waiting(self) -> str | None:
        """Why :meth:`read` has nothing to show yet (not a failed read), or ``None``."""

    def close(self) -> None: ...


def open_camera(index: int) -> Any:
    """UVC camera ``index`` through OpenCV's ``VideoCapture``, opened, with OpenCV's own
    warnings held back (they would print several lines where one error line is due).

    Raises:
        InputError: it cannot be opened (no such device, or another program uses it).
    """
    import cv2

    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    timeout_ms = int(FIRST_FRAME_TIMEOUT * 1000)
    try:
        cap = cv2.VideoCapture(
            index,
            cv2.CAP_ANY,
            [
                cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
                timeout_ms,
                cv2.CAP_PROP_READ_TIMEOUT_MSEC,
                timeout_ms,
            ],
        )
    finally:
        cv2.utils.logging.setLogLevel(level)
    if not cap.isOpened():
        device = f"/dev/video{index}"
        why = (
            f"no device {device}"
            if sys.platform == "linux" and not os.path.exists(device)
            else f"{device}: no such camera, another program is using it, or it is not "
            "readable (check `ls -l /dev/video*` and the video group)"
        )
        raise InputError(f"cannot open the camera: {why}", source=f"camera {index}")
    return cap


class CameraSource:
    """A UVC camera through OpenCV (:func:`open_camera`; V4L2 on Linux).

    Args:
        index: the camera's number (``/dev/video<index>``).
        intrinsics: its calibration; scaled when the camera delivers another resolution of
            the same picture (:func:`~legws_daemon.tracking.calibration.scaled_intrinsics`).

    Raises:
        InputError: the camera cannot be opened, or gives no frame within
            :data:`FIRST_FRAME_TIMEOUT` seconds, or a picture the calibration does not fit.
    """

    def __init__(self, index: int, intrinsics: Intrinsics, calibration: str = "calibration"):
        import cv2

        from legws_daemon.tracking.calibration import scaled_intrinsics

        self.name = f"camera{index}"
        self._cap = open_camera(index)
        self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, intrinsics.width)
        self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, intrinsics.height)
        first = self._first_frame()
        if first is None:
            self._cap.release()
            raise InputError(
                f"the camera gave no picture within {FIRST_FRAME_TIMEOUT:g} s",
                source=f"camera {index}",
            )
        height, width = first.shape[:2]
        self.intrinsics = scaled_intrinsics(intrinsics, width, height, source=calibration)

    def _first_frame(self) -> np.ndarray | None:
        end = time.monotonic() + FIRST_FRAME_TIMEOUT
        while time.monotonic() < end:
            frame = self.read()
            if frame is not None:
                return frame
            time.sleep(0.05)
        return None

    def read(self) -> np.ndarray | None:
        ok, frame = self._cap.read()
        if not ok or frame is None or frame.ndim not in (2, 3) or frame.size == 0:
            return None
        return np.asarray(frame, dtype=np.uint8)

    def waiting(self) -> str | None:
        return None  # a camera shows what stands there

    def close(self) -> None:
        self._cap.release()


@dataclass(frozen=True)
class SimSpec:
    """``sim:SCENE[:LAYOUT]``: the stand-in's camera over a scene, objects where a layout
    file says (``None``: the scene file's poses)."""

    scene: str
    layout: Path | None


def parse_sim_source(text: str) -> SimSpec:
    """``sim:tea`` or ``sim:tea:out/placed.json``; an error naming what is expected."""
    kind, _, rest = text.partition(":")
    scene, _, layout = rest.partition(":")
    if kind != "sim" or not scene:
        raise InputError(
            f"expected sim:SCENE or sim:SCENE:LAYOUT_FILE, got {text!r}", field="--source"
        )
    return SimSpec(scene, Path(layout) if layout else None)


#: A shift of an object from where it would stand: ``(dx, dy, dyaw)``, m, m, rad.
Move = tuple[float, float, float]
#: The largest shift ``--move`` takes, m (beyond any table).
MAX_MOVE = 10.0


def parse_move(text: str, scene: Scene) -> tuple[str, Move]:
    """``--move OBJ=DX,DY[,DYAW]``: metres along the base frame's x (away from the robot)
    and y (its left), and degrees anticlockwise seen from above; an error naming what is
    expected."""
    name, eq, rest = text.partition("=")
    parts = rest.split(",")
    try:
        if not eq or len(parts) not in (2, 3):
            raise ValueError
        values = [float(v) for v in parts] + ([0.0] if len(parts) == 2 else [])
    except ValueError:
        raise InputError(
            f"expected OBJ=DX,DY[,DYAW] (m, m, degrees), got {text!r}", field="--move"
        ) from None
    dx, dy, dyaw = values
    if not all(math.isfinite(v) for v in values) or max(abs(dx), abs(dy)) > MAX_MOVE:
        raise InputError(
            f"a shift of at most {MAX_MOVE:g} m and finite numbers, got {text!r}",
            field="--move",
        )
    if name not in scene.objects:
        raise InputError(
            f"unknown object '{name}'; scene '{scene.name}' has: {', '.join(scene.objects)}",
            field="--move",
        )
    return name, (dx, dy, math.radians(dyaw))


class SimSource:
    """The MuJoCo stand-in's camera over ``scene`` (:meth:`layout` says what it shows).

    Args:
        layout: a layout file whose objects stand where it says, over the base layout;
            read again whenever it changes (its modification time or size) and the picture
            rendered again; a bad version is one warning and the last good one stays. A
            layout may put an object off the table (out of view).
        follow: the layout the daemon runs, as the base (``None``: the scene file's
            poses); until it is known, or while it does not fit the scene, nothing is
            rendered (:meth:`waiting` says why).
        moves: object → its shift from where the base and the file put it (``--move``).
        say: a line for people when the daemon's layout changes.
    """

    def __init__(
        self,
        scene: Scene,
        layout: Path | None,
        width: int,
        height: int,
        warn: Callable[[str], None],
        *,
        follow: DaemonLayout | None = None,
        moves: Mapping[str, Move] | None = None,
        say: Callable[[str], None] | None = None,
    ) -> None:
        from legws_daemon.tracking.sim_camera import SimCamera

        self.name = f"sim:{scene.name}"
        self._scene = scene
        self._path = layout
        self._warn = warn
        self._say = say
        self._follow = follow
        self._moves = dict(moves or {})
        unknown = [n for n in self._moves if n not in scene.objects]
        if unknown:
            raise InputError(f"unknown object '{unknown[0]}' in scene '{scene.name}'")
        self._stamp: tuple[int, int] | None = None
        self._file: Layout = (self._read_layout() or {}) if layout is not None else {}
        self._camera = SimCamera(scene, None, width, height)
        self._image: np.ndarray | None = None
        self.intrinsics = self._camera.intrinsics

    def layout(self) -> dict[str, ObjectPose]:
        """What the camera shows: every object where the daemon's layout (or the scene
        file) puts it, the layout file's where it says, each ``moves`` shift added."""
        base = self._follow.layout if self._follow is not None else None
        poses = {**self._scene.poses(), **(base or {}), **self._file}
        for name, (dx, dy, dyaw) in self._moves.items():
            p = poses[name]
            poses[name] = ObjectPose(p.x + dx, p.y + dy, p.yaw + dyaw)
        return poses

    def _read_layout(self) -> Layout | None:
        """The layout file if it changed since last read (``None``: unchanged)."""
        assert self._path is not None
        try:
            st = self._path.stat()
        except OSError as err:
            raise InputError(
                f"cannot read the layout: {err.strerror}", source=str(self._path)
            ) from None
        stamp = (st.st_mtime_ns, st.st_size)
        if stamp == self._stamp:
            return None
        self._stamp = stamp
        return load_layout(self._path, self._scene)

    def read(self) -> np.ndarray | None:
        """The camera's picture: rendered again when the layout changed (a render takes
        ~70 ms on a software renderer), else the last one (nothing moved: a real camera
        would see the same); ``None`` while the daemon's layout is not known
        (:meth:`waiting`)."""
        changed = self._image is None
        if self._path is not None:
            try:
                layout = self._read_layout()
            except InputError as err:
                self._warn(str(err))
                layout = None
            if layout is not None:  # the objects it leaves out stand on the base layout
                self._file, changed = layout, True
        follow = self._follow
        if follow is not None:
            if follow.update():
                changed = True
                if follow.layout is not None and self._say is not None:
                    self._say(
                        f"rendering the layout the daemon runs (stage {follow.stage}, "
                        f"decision {follow.decision})"
                    )
            if follow.layout is None:
                self._image = None
                return None
        if changed:
            self._camera.set_layout(self.layout())
            self._image = self._camera.render()
        return self._image

    def waiting(self) -> str | None:
        """Why there is no picture: the daemon's layout is not known or does not fit."""
        if self._follow is None or self._follow.layout is not None:
            return None
        return self._follow.problem

    def close(self) -> None:
        self._camera.close()


@dataclass
class TrackStats:
    """What a run did: frames read, dropped (unreadable) and tracked, messages sent, and
    the times the source had nothing to show (``waited``: the sim camera without the
    daemon's layout)."""

    frames: int = 0
    dropped: int = 0
    published: int = 0
    waited: int = 0
    started: float = field(default_factory=time.monotonic)

    def rate(self) -> float:
        elapsed = time.monotonic() - self.started
        return self.frames / elapsed if elapsed > 0 else 0.0


class Absence:
    """Counts each tracked object's missed frames in a row; names those missing from
    :data:`UNSEEN_AFTER` or more."""

    def __init__(self) -> None:
        self._missed: dict[str, int] = {}

    def update(self, frame: TrackFrame) -> list[str]:
        for name in frame.poses:
            self._missed[name] = 0
        for name in frame.unseen:
            self._missed[name] = self._missed.get(name, 0) + 1
        return [n for n, k in self._missed.items() if k >= UNSEEN_AFTER]


class Warnings:
    """One-line warnings to ``write``, the same text at most every :data:`WARNING_INTERVAL`
    seconds."""

    def __init__(self, write: Callable[[str], None]) -> None:
        self._last: dict[str, float] = {}
        self._write = write

    def __call__(self, text: str) -> None:
        now = time.monotonic()
        if now - self._last.get(text, -np.inf) >= WARNING_INTERVAL:
            self._last[text] = now
            self._write(text)


class ObjectsPublisher:
    """A zenoh session publishing on ``legws/<robot>/objects`` (connects to the daemon)."""

    def __init__(self, profile: ProfileSpec, zenoh_config: Path | None, source: str) -> None:
        self.config = publisher_config(profile, zenoh_config)
        self.key = keys(profile.robot)["objects"]
        self.source = source
        self.seq = 0
        self._publisher: Any = None
        self._session: Any = None
        self._stack = ExitStack()

    def __enter__(self) -> ObjectsPublisher:
        with ExitStack() as stack:
            self._session = stack.enter_context(open_session(self.config))
            self._publisher = self._session.declare_publisher(self.key)
            self._stack = stack.pop_all()
        return self

    def __exit__(self, *exc: object) -> None:
        self._publisher = self._session = None
        self._stack.close()

    def subscribe(self, key: str, receive: Callable[[bytes], None]) -> None:
        """Hear ``key`` on the same session (``receive`` runs on zenoh's thread) until the
        publisher closes (e.g. the daemon's status, :class:`DaemonLayout`)."""
        assert self._session is not None
        sub = self._session.declare_subscriber(key, lambda s: receive(s.payload.to_bytes()))
        self._stack.callback(sub.undeclare)

    def message(self, frame: TrackFrame, unseen: list[str], stamp: float) -> bytes:
        """The validated payload of one frame."""
        data = {
            "schema": SCHEMA_VERSION,
            "seq": self.seq,
            "stamp": stamp,
            "source": self.source,
            "objects": {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in frame.poses.items()},
            "unseen": unseen,
        }
        self.seq += 1
        return dump(ObjectsMessage.model_validate(data))

    def put(self, payload: bytes) -> None:
        assert self._publisher is not None
        self._publisher.put(payload)


def track(
    source: FrameSource,
    tracker: Tracker,
    send: Callable[[TrackFrame, list[str], float], None],
    *,
    rate: float,
    stop: threading.Event,
    duration: float | None = None,
    warn: Callable[[str], None],
    on_frame: Callable[[TrackFrame, TrackStats], None] | None = None,
) -> TrackStats:
    """Read, track and send frames at ``rate`` Hz (or as fast as frames come, if slower)
    until ``stop`` is set or ``duration`` seconds passed."""
    if not 0 < rate <= MAX_RATE:
        raise InputError(f"rate must be in (0, {MAX_RATE:g}] Hz, got {rate}", field="--rate")
    stats = TrackStats()
    absence = Absence()
    period = 1.0 / rate
    end = None if duration is None else time.monotonic() + duration
    next_at = time.monotonic()
    while not stop.is_set() and (end is None or time.monotonic() < end):
        image = source.read()
        stamp = time.time()
        why = source.waiting() if image is None else None
        if why is not None:  # nothing to show yet, not a failed read
            stats.waited += 1
            warn(f"{source.name}: {why}; nothing published")
        elif image is None:
            stats.frames += 1
            stats.dropped += 1
            warn(f"{source.name}: a frame could not be read; nothing published for it")
        else:
            stats.frames += 1
            frame = tracker.process(image)
            for text in frame.warnings:
                warn(text)
            send(frame, absence.update(frame), stamp)
            stats.published += 1
            if on_frame is not None:
                on_frame(frame, stats)
        next_at += period
        delay = next_at - time.monotonic()
        if delay > 0:
            stop.wait(delay)
        else:
            next_at = time.monotonic()  # behind: no burst to catch up
    return stats
