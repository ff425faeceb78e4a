"""Rerun telemetry of the daemon: one :class:`RerunLog` per run, called once per control tick.

Entity layout (timelines ``tick``, a sequence, and ``time``, a duration in seconds):

* ``world/table``, ``world/planned/<obj>`` (wireframe boxes), ``world/grasps/<goal>`` (frame
  and an arrow along the approach axis): static, replaced by each :meth:`RerunLog.log_setup`.
* ``world/robot/<link>`` (the link's pose per tick) with ``world/robot/<link>/mesh`` (the
  Sawyer's own meshes, static, :mod:`.robot_drawing`) and the gripper's fingers at their
  opening; ``world/ee`` (EE frame, plus the exact float64 pose as ``legws.EePose``),
  ``world/ee_trail``, ``world/objects/<obj>`` (the object's shape and colour; a candidate
  of the current stage labelled with its name and, while inferring, its probability, the
  others unlabelled), ``world/committed`` (an outline around
  the committed object), ``world/joystick``, ``world/command``, ``world/placement`` (with a
  tracker: arrows from each misplaced object to where it should stand),
  ``world/calibration/target`` (``legws operator calibrate``: the target shown, a point
  labelled ``target 3 of 20``; cleared between targets).
* Plots, each in its own view: ``plots/posterior/<goal>`` with ``plots/threshold`` and
  ``plots/commits`` (a marker at each commit); ``plots/slack``; ``plots/timing/tick_ms``,
  ``plots/timing/budget_ms`` and ``plots/timing/overruns``.
* ``status`` (a panel: mode, operator, phase, fault, stage; with a tracker, the placement:
  certified or not, J and K, each object not in place with its correction; while
  calibrating, the target and how far it is; with an operator file, whose model the
  certificates are for and what the live watch says), ``log``
  (commits, cancels, faults; every row tagged with its stage), ``status/mode``.
* ``meta/robot``, ``meta/params`` (the Params JSON as given) and ``meta/goals`` (one JSON
  document per stage, i.e. per decision: the goal-set file of
  :mod:`legws_daemon.formats.goalset` plus the stage's name and index, ``candidates``,
  ``inference`` (false for a single candidate, whose document has no goal set), scene,
  robot, threshold and goal -> object map), static: the viewer shows the latest.
  ``meta/stages``: the same documents on the timelines, so
  :mod:`legws_daemon.telemetry.recording` reads every stage back (a finished file keeps only
  the newest static value).
* A posterior curve ends (a NaN) where its goal stops being inferred: inference stopped,
  the goal no longer a candidate, or a new stage set up; it never runs across a stage
  where its object is no candidate.

A ``save:`` file is written without rerun's footer (its manifest would grow in memory for
the whole session) and finished at :meth:`RerunLog.close` (:mod:`.rrd_file`).

The EE trail is ``world/ee_trail``, not ``world/ee/trail``: a child of ``world/ee`` would be
moved by the EE's own transform.

Cost: the hot per-tick components are built straight from numpy as Arrow arrays with the
descriptors of the rerun archetypes (taken once from templates), which is 2-4x cheaper
than the archetype constructors; unchanged link frames, object boxes and labels are not
re-sent. Rerun's batcher writes on its own thread, so no call waits for I/O.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import shutil
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray, yaw_quat
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_path
from legws_daemon.formats.goalset import ParamsSchema, goalset_to_data, params_from_schema
from legws_daemon.formats.log_lines import How, parse_commit
from legws_daemon.formats.log_lines import commit_text as commit_text
from legws_daemon.formats.printable import MESSAGE_LIMIT, safe_text, without_terminal_sequences
from legws_daemon.formats.validation import parse_json, validate
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.telemetry import rrd_file
from legws_daemon.telemetry.robot_drawing import RobotDrawing
from legws_daemon.telemetry.snapshot import TickSnapshot

if TYPE_CHECKING:  # MuJoCo (under robot.visual) loads only where the meshes are made
    from legws_daemon.robot.visual import RobotVisual
    from legws_daemon.telemetry import web_viewer

_LOG = logging.getLogger(__name__)

#: Version of the ``meta/goals`` documents.
TELEMETRY_FORMAT = 1
EE_PATH = "world/ee"
GOALS_DOC = "meta/goals"
#: The same documents on the timelines, one per set-up: the history of the stages. (The
#: static ``meta/goals`` is what the viewer shows; rerun keeps only the newest static value
#: of an entity when it compacts a file, as :mod:`.rrd_file` does at close.)
STAGES_DOC = "meta/stages"
PARAMS_DOC = "meta/params"
TEXT_LOG = "log"
#: Dynamic archetype of the exact EE pose logged at ``world/ee`` (float64, for replay).
EE_ARCHETYPE = "legws.EePose"
#: Dynamic archetype of the stage index attached to every ``log`` row.
STAGE_ARCHETYPE = "legws.Stage"
TARGET_FORMS = "save:PATH, spawn, connect, connect:URL, web or web:[HOST:]PORT"
#: Where a spawned native viewer listens (rerun's default).
SPAWN_URL = "rerun+http://127.0.0.1:9876/proxy"

_COMMITTED = 0xFFB000FF
_PLANNED = 0xFFFFFF50  # faint outlines
_OVERRUN = 0xE03030FF
_PALETTE = (0x1F77B4FF, 0xFF7F0EFF, 0x2CA02CFF, 0xD62728FF, 0x9467BDFF, 0x8C564BFF,
            0xE377C2FF, 0x17BECFFF, 0xBCBD22FF, 0x7F7F7FFF)  # fmt: skip
#: A label's probability is rounded to this many steps, so it is re-sent only on a visible change.
_LABEL_STEPS = 50
_UNKNOWN_HALF_SIZE = (0.025, 0.025, 0.025)
#: The threshold and budget lines are constants: one point every this many ticks draws them.
_THRESHOLD_EVERY = 10
STATUS_DOC = "status"
#: Arrows from misplaced objects to their planned poses (a tracker's report).
PLACEMENT_PATH = "world/placement"
#: Their colour: orange.
_MISPLACED = (255, 140, 0)
#: The calibration target shown (``legws operator calibrate``), and its colour: magenta.
CALIBRATION_TARGET_PATH = "world/calibration/target"
_CALIBRATION = (230, 40, 200)
#: Where the posterior of a goal is plotted: this prefix and the escaped goal name.
POSTERIOR_PREFIX = "plots/posterior/"
COMMITS_PLOT = "plots/commits"
TIMING = "plots/timing"
#: Seconds :meth:`RerunLog.close` waits for a sink that already failed a check.
FAILED_CLOSE_TIMEOUT = 0.5
#: A ``save:`` file gets what was logged in chunks of this many seconds (rerun's default is
#: 0.2 s, for live viewers). The file is written without rerun's footer, whose manifest of
#: every chunk would stay in memory until the end (:mod:`.rrd_file`; the footer is added at
#: close), so this only trades the file's size against what a crash loses: at 0.2 s a
#: 10-minute recording was 3x larger than at 5 s. A crash loses at most this.
SAVE_FLUSH_SECONDS = 1.0
#: Below this many free bytes on a ``save:`` file's file system, :meth:`RerunLog.check`
#: reports the disk as (nearly) full.
LOW_SPACE = 256 * 1024
#: A ``save:`` file that has not grown for this long while data was logged has stalled, s.
STALL_SECONDS = 15.0


def parse_target(text: str) -> tuple[str, str | None]:
    """Parse ``--rerun``: ``save:PATH``, ``spawn``, ``connect``, ``connect:URL``, ``web`` or
    ``web:[HOST:]PORT`` (:func:`~.web_viewer.parse_web_target` checks the address).

    Returns:
        ``(kind, argument)``; the argument is ``None`` for ``spawn``, a bare ``connect``
        (rerun's default address) and a bare ``web`` (127.0.0.1:9090).
    """
    kind, sep, arg = text.partition(":")
    if kind == "spawn" and not sep:
        return "spawn", None
    if kind in ("connect", "web") and (not sep or arg):
        if kind == "web":
            from legws_daemon.telemetry.web_viewer import parse_web_target  # imports this

            parse_web_target(arg or None)
        return kind, arg or None
    if kind == "save" and arg:
        return "save", arg
    raise InputError(f"expected {TARGET_FORMS}, got {text!r}", field="--rerun")


def parse_targets(texts: str | Sequence[str]) -> list[tuple[str, str | None]]:
    """One or more ``--rerun`` targets (:func:`parse_target`), each kind at most once."""
    items = [texts] if isinstance(texts, str) else list(texts)
    if not items:
        raise InputError(f"expected one of {TARGET_FORMS}, got none", field="--rerun")
    parsed = [parse_target(t) for t in items]
    kinds = [k for k, _ in parsed]
    for kind in kinds:
        if kinds.count(kind) > 1:
            raise InputError(f"{kind} given {kinds.count(kind)} times; at most once",
                             field="--rerun")  # fmt: skip
    return parsed


#: Seconds a plot shows before and after the time cursor: its curves are drawn up to the
#: cursor, the legend stands in the room after it (at 800x500 a legend over the curves
#: hid most of the posterior).
PLOT_WINDOW = (36.0, 24.0)


def _cursor(seconds: float) -> rrb.TimeRangeBoundary:
    return rrb.TimeRangeBoundary.cursor_relative(seconds=seconds)


def _plot(name: str, contents: str | list[str], **kwargs: Any) -> rrb.TimeSeriesView:
    """A plot of the last :data:`PLOT_WINDOW` seconds up to the cursor on the ``time``
    timeline, with its legend at the top right, after the cursor."""
    before, after = PLOT_WINDOW
    return rrb.TimeSeriesView(
        name=name,
        origin="/plots",
        contents=contents,
        axis_x=rrb.TimeAxis(view_range=rrb.TimeRange(start=_cursor(-before), end=_cursor(after))),
        time_ranges=rrb.VisibleTimeRange("time", start=_cursor(-before), end=_cursor(0.0)),
        plot_legend=rrb.PlotLegend(corner="RightTop"),
        **kwargs,
    )


def default_blueprint() -> rrb.Blueprint:
    """The operator's layout: the 3D world over the text log on the left; the status panel
    and three plots on the right — the posterior (0 to 1, with the threshold and the
    commits), the certificate's slack, and the tick timing against its budget, each the
    last :data:`PLOT_WINDOW` seconds up to the time cursor with its legend after it. The
    side panels start collapsed (the views get the room); the time panel stays."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(name="world", origin="/world", contents="/world/**"),
                rrb.TextLogView(name="log", origin="/", contents=["/log", "/status/**"]),
                row_shares=[3, 1],
            ),
            rrb.Vertical(
                rrb.TextDocumentView(name="status", origin="/status", contents="/status"),
                _plot(
                    "posterior",
                    [f"/{POSTERIOR_PREFIX}**", "/plots/threshold", f"/{COMMITS_PLOT}"],
                    axis_y=rrb.ScalarAxis(range=(0.0, 1.0), zoom_lock=True),
                ),
                _plot("slack", "/plots/slack"),
                _plot("timing (ms)", f"/{TIMING}/**"),
                row_shares=[1, 4, 1.5, 1.5],
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", play_state="following"),
    )


# --- Arrow batches without the archetype converters -------------------------------------------


@dataclass(frozen=True, slots=True)
class _Raw:
    """A ready Arrow array as a rerun component batch."""

    array: Any

    def as_arrow_array(self) -> Any:
        return self.array


class _Fast:
    """Builds described component batches from numpy, with descriptors and Arrow types taken
    from template archetypes (so they always match the installed rerun)."""

    def __init__(self, *templates: rr.AsComponents) -> None:
        self._spec: dict[str, tuple[rr.ComponentDescriptor, Any]] = {}
        self._constants: dict[tuple[str, Any], rr.DescribedComponentBatch] = {}
        for template in templates:
            for batch in template.as_component_batches():
                descriptor = batch.component_descriptor()
                self._spec[str(descriptor)] = (descriptor, batch.as_arrow_array().type)

    def _batch(self, name: str, array: Any) -> rr.DescribedComponentBatch:
        return rr.DescribedComponentBatch(_Raw(array), self._spec[name][0])

    def fixed(self, name: str, values: ArrayLike) -> rr.DescribedComponentBatch:
        """Fixed-size float32 lists (vectors, quaternions, column-major matrices)."""
        return self.wrap(name, pa.array(np.asarray(values, dtype=np.float32).ravel()))

    def wrap(self, name: str, flat: Any) -> rr.DescribedComponentBatch:
        """Fixed-size lists over a flat float32 Arrow array (or a zero-copy slice of one)."""
        return self._batch(name, pa.FixedSizeListArray.from_arrays(flat, type=self._spec[name][1]))

    def strips(self, name: str, points: ArrayLike) -> rr.DescribedComponentBatch:
        """One line strip through ``(N, 3)`` points."""
        kind = self._spec[name][1]
        pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        inner = pa.FixedSizeListArray.from_arrays(pa.array(pts.ravel()), type=kind.value_type)
        offsets = pa.array(np.array([0, len(pts)], dtype=np.int32))
        return self._batch(name, pa.ListArray.from_arrays(offsets, inner, type=kind))

    def plain(self, name: str, values: Iterable[Any]) -> rr.DescribedComponentBatch:
        """Scalars, colours (``0xRRGGBBAA``), strings or integers of the component's type."""
        return self._batch(name, pa.array(list(values), type=self._spec[name][1]))

    def constant(self, name: str, value: Any) -> rr.DescribedComponentBatch:
        """A one-element :meth:`plain` batch, built once per value."""
        key = (name, value)
        batch = self._constants.get(key)
        if batch is None:
            batch = self._constants[key] = self.plain(name, [value])
        return batch


@cache
def _fast() -> _Fast:
    eye = np.eye(3)
    return _Fast(
        rr.Transform3D(translation=[0, 0, 0], mat3x3=eye),
        rr.Transform3D(quaternion=rr.Quaternion(xyzw=[0, 0, 0, 1])),
        rr.Scalars(0.0),
        rr.Arrows3D(origins=[[0, 0, 0]], vectors=[[0, 0, 1]], colors=[[1, 2, 3]]),
        rr.LineStrips3D([[[0, 0, 0], [1, 1, 1]]]),
        rr.Boxes3D(
            centers=[[0, 0, 0]],
            half_sizes=[[1, 1, 1]],
            quaternions=[rr.Quaternion(xyzw=[0, 0, 0, 1])],
            colors=[[1, 2, 3]],
            labels=["x"],
            fill_mode="solid",
        ),
        rr.DynamicArchetype(
            EE_ARCHETYPE,
            components={
                "position": [0.0] * 3,
                "quaternion": [0.0] * 4,
                "t": 0.0,
                "stage": 0,
                "deflection": [0.0] * 3,
                "mode": "teleop",
            },
        ),
        rr.DynamicArchetype(STAGE_ARCHETYPE, components={"stage": 0}),
    )


# --- small pure helpers --------------------------------------------------------------------------


def _part(name: str) -> str:
    return rr.escape_entity_path_part(name)


def _xyzw(q_wxyz: ArrayLike) -> FloatArray:
    q = np.asarray(q_wxyz, dtype=np.float64)
    return np.array([q[1], q[2], q[3], q[0]])


def _half_size(scene: Scene, name: str) -> tuple[float, float, float]:
    obj = scene.object(name)
    sx, sy, sz = extents(obj.shape, tuple(obj.size))
    return (sx / 2, sy / 2, sz / 2)


def _rgba(rgb: ArrayLike, alpha: int = 255) -> int:
    r, g, b = (round(float(c)) for c in np.clip(np.asarray(rgb, dtype=np.float64), 0, 255))
    return (r << 24) | (g << 16) | (b << 8) | alpha


def _md(text: str | None) -> str:
    """A value in a line of Markdown: one terminal-safe line, its markup characters escaped."""
    line = safe_text(" ".join(str(text).split()))
    return "".join("\\" + c if c in "\\`*_[]<>#|~" else c for c in line)


def _probe(path: Path) -> Path:
    """Check that a ``save:`` file can be created and written (one byte, which rerun's
    writer then replaces); one-line :class:`InputError` otherwise. Returns the file written:
    ``path``, or the target of a symbolic link (written and finished in its own folder; the
    link stays a link)."""
    if not path.parent.is_dir():
        what = "is not a folder" if path.parent.exists() else "does not exist"
        raise InputError(f"folder {path.parent} {what}", field="--rerun")
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected a file path", field="--rerun")
    try:
        path = output_path(path)  # a device, FIFO or socket there is refused, never written to
    except InputError as err:
        raise InputError(str(err), field="--rerun") from None
    try:
        with path.open("wb") as out:
            out.write(b"\0")
            out.flush()
            os.fsync(out.fileno())
    except OSError as err:
        detail = err.strerror or str(err)
        raise InputError(f"cannot write {path}: {detail}", field="--rerun") from None
    return path


#: Fewer free bytes than this on a file system: it is full.
_FULL = 4096


def _free_bytes(path: Path) -> int | None:
    """Bytes free to this process on the file system of ``path``'s folder (``None``:
    unknown, or a file system without blocks such as ``/proc``)."""
    try:
        st = os.statvfs(path.parent)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize if st.f_blocks > 0 else None


def viewer_executable() -> Path:
    """The Rerun viewer to spawn: the one installed next to this Python (the venv's, found
    even when the venv is not on PATH), else ``rerun`` on PATH.

    Raises:
        InputError: when neither exists (one line: what to install, or what to use instead).
    """
    here = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    if here.is_file() and os.access(here, os.X_OK):
        return here
    found = shutil.which("rerun")
    if found:
        return Path(found)
    raise InputError(
        f"no Rerun viewer: neither {here} nor `rerun` on PATH; install it with "
        f"`{sys.executable} -m pip install rerun-sdk`, or log with --rerun save:PATH",
        field="--rerun",
    )


def _disk_note(path: Path) -> str:
    """``"; no space left on the device"`` when the file system of ``path`` is full."""
    free = _free_bytes(path)
    return "; no space left on the device" if free is not None and free < _FULL else ""


def parse_params_json(params_json: str) -> Params:
    """The :class:`Params` of a JSON object of its fields (as ``Params.as_dict()`` gives),
    parsed as any JSON text legws reads (:func:`~legws_daemon.formats.validation.parse_json`:
    a key given twice, a control character, too deep a nesting are refused)."""
    if not isinstance(params_json, str):
        raise InputError(
            f"expected a JSON object, got {type(params_json).__name__}", field="params_json"
        )
    data = parse_json(params_json, "params_json", None)
    return params_from_schema(validate(ParamsSchema, data, "params_json"), "params_json")


def _check_settings(length: int, every: int, scale: float, link_every: int) -> None:
    checks = [
        ("trail_length", length, isinstance(length, int) and length >= 2, "an integer >= 2"),
        ("trail_every", every, isinstance(every, int) and every >= 1, "an integer >= 1"),
        ("command_scale", scale, isinstance(scale, int | float) and scale > 0, "a number > 0"),
        ("link_frames_every", link_every, isinstance(link_every, int) and link_every >= 0,
         "an integer >= 0"),
    ]  # fmt: skip
    for name, value, ok, expected in checks:
        if not ok:
            raise InputError(f"expected {expected}, got {value!r}", field=name)


@dataclass(frozen=True, slots=True)
class _Shape:
    """How an object is drawn: its scene shape, size (as the scene gives it) and colour."""

    kind: str  # box | cylinder | sphere
    size: tuple[float, ...]
    color: int
    half_size: tuple[float, float, float]  # of its bounding box

    def archetype(self, position: FloatArray, q_wxyz: FloatArray, label: str) -> Any:
        quat = rr.Quaternion(xyzw=_xyzw(q_wxyz))
        # an empty list clears the label an earlier row gave
        common: dict[str, Any] = {"centers": [position], "colors": [self.color],
                                  "labels": [label] if label else [],
                                  "fill_mode": "solid"}  # fmt: skip
        if self.kind == "cylinder":
            radius, height = self.size[0], self.size[1]
            return rr.Cylinders3D(lengths=[height], radii=[radius], quaternions=[quat], **common)
        if self.kind == "sphere":
            r = self.size[0]
            return rr.Ellipsoids3D(half_sizes=[[r, r, r]], **common)
        return rr.Boxes3D(half_sizes=[self.half_size], quaternions=[quat], **common)


def _shape_of(scene: Scene, name: str) -> _Shape:
    obj = scene.object(name)
    colour = _rgba(np.asarray(obj.color, dtype=np.float64) * 255)
    return _Shape(obj.shape, tuple(float(x) for x in obj.size), colour, _half_size(scene, name))


_UNKNOWN = _Shape("box", tuple(2 * h for h in _UNKNOWN_HALF_SIZE), 0x909090FF, _UNKNOWN_HALF_SIZE)


@dataclass(slots=True)
class _ObjectState:
    """What was last sent for one object (to skip unchanged rows)."""

    shape: _Shape
    sent: bytes = b""  # pose and label as last sent


@dataclass(slots=True)
class _Trail:
    """Ring buffer of recent EE positions; the strip is re-sent every ``every`` new points."""

    capacity: int
    every: int
    points: FloatArray = field(init=False)
    count: int = 0
    pending: int = 0

    def __post_init__(self) -> None:
        self.points = np.zeros((self.capacity, 3))

    def add(self, position: FloatArray, min_step: float = 1e-3) -> bool:
        """Add a point (if it moved ``min_step``); True when the strip is due to be re-sent."""
        if self.count:
            last = self.points[(self.count - 1) % self.capacity]
            if float(np.sum((position - last) ** 2)) < min_step**2:
                return False
        self.points[self.count % self.capacity] = position
        self.count += 1
        self.pending += 1
        return self.count >= 2 and self.pending >= self.every

    def ordered(self) -> FloatArray:
        self.pending = 0
        if self.count <= self.capacity:
            return self.points[: self.count]
        start = self.count % self.capacity
        return np.concatenate((self.points[start:], self.points[:start]))

    def clear(self) -> None:
        self.count = self.pending = 0


def _pass_on(text: str) -> None:
    """Lines another writer left on standard error, each terminal-safe (rerun's own lines
    carry its colours unless NO_COLOR, and names or addresses the user gave)."""
    for line in text.splitlines():
        line = without_terminal_sequences(line)  # colours (a NO_COLOR the user set empty)
        if line.strip():
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.write(safe_text(line, MESSAGE_LIMIT) + "\n")
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.flush()


class RerunLog:
    """Telemetry of one daemon run to a rerun recording (file, spawned viewer or server).

    Args:
        target: ``save:PATH`` (the parent folder must exist), ``spawn`` (starts a viewer)
            or ``connect:URL`` (a running viewer or server; if it cannot be reached, rerun
            waits 5 s here, then buffers).
        robot: robot name, logged at ``meta/robot``.
        application_id: rerun application id.
        recording_id: rerun recording id (default: a new one).
        trail_length: number of EE positions in ``world/ee_trail``.
        trail_every: re-send the trail every this many new trail points.
        command_scale: seconds; the command arrow is the EE velocity times this.
        link_frames_every: send the links' poses every this many ticks (0: at the first
            tick only). Each moving link costs about as much as a posterior plot point.
        tick_period: the control period, s: drawn as the budget line of the timing plot,
            and a tick longer than it is an overrun.

    Per-tick calls never raise: a failure is counted in :attr:`dropped` and logged (once,
    then every 1000th time) on the ``logging`` logger of this module. Not thread-safe: call
    :meth:`log_tick` from one thread; :meth:`close` from the thread that owns the run (it
    may take seconds: it finishes a ``save:`` file).

    Failures of the file: a ``save:`` path is probed at start (a byte is written and
    synced, then rerun's writer replaces the file), so a path that cannot be written — no
    such folder, a folder, ``/proc``, ``/dev/full`` — is an :class:`InputError`. Later
    (rerun's file writer stops at the first failed write, e.g. when the disk fills up) the
    logging calls still do not raise: :meth:`check` says that the recording no longer
    takes data. A ``save:`` file is written in chunks of :data:`SAVE_FLUSH_SECONDS`,
    without a footer until :meth:`close`.
    """

    def __init__(
        self,
        target: str | Sequence[str],
        *,
        robot: str,
        application_id: str = "legws",
        recording_id: str | None = None,
        trail_length: int = 200,
        trail_every: int = 5,
        command_scale: float = 2.0,
        link_frames_every: int = 1,
        tick_period: float | None = None,
    ) -> None:
        targets = parse_targets(target)
        _check_settings(trail_length, trail_every, command_scale, link_frames_every)
        if tick_period is not None and not (
            isinstance(tick_period, int | float) and math.isfinite(tick_period) and tick_period > 0
        ):
            raise InputError(f"expected a number > 0, got {tick_period!r}", field="tick_period")
        save_arg = dict(targets).get("save")
        save_path = _probe(Path(save_arg)) if save_arg is not None else None
        self.robot = robot
        self.dropped = 0
        self.last_error: str | None = None
        self._checked_drops = 0
        self._sink_failed = False
        self._logged = 0  # calls that logged data, for the stall check
        self._file_state: tuple[int, int, int, float] | None = None  # inode, size, logged, when
        self._save_path = save_path
        self._closed = False
        #: ``save:`` only: whether :meth:`close` added the footer (``None`` before it ran).
        self.finished: bool | None = None
        self._now: tuple[int, float] = (0, 0.0)  # the latest (tick, time) logged
        live = any(kind != "save" for kind, _ in targets)  # a viewer waits on the chunks
        batching = None if live else rr.ChunkBatcherConfig(flush_tick=SAVE_FLUSH_SECONDS)
        self._stream = rr.RecordingStream(
            application_id, recording_id=recording_id, batcher_config=batching
        )
        #: the web viewer of a ``web`` target (its page: ``web.target.page_url``)
        self.web: web_viewer.WebViewer | None = None
        try:
            self._open_sinks(targets)
        except BaseException:
            if self.web is not None:
                self.web.close()
            raise
        self._fast = _fast()
        self._trail = _Trail(trail_length, trail_every)
        self._command_scale = command_scale
        self._robot = RobotDrawing(self._stream.log, self._fast, None, link_frames_every)
        self._budget_ms = None if tick_period is None else float(tick_period) * 1e3
        self._stage = -1
        self._static: dict[str, str] = {}
        self._goal_object: dict[str, str] = {}
        self._object_goals: dict[str, list[str]] = {}
        self._objects: dict[str, _ObjectState] = {}
        self._shapes: dict[str, _Shape] = {}
        self._committed_outline: bytes | None = None
        self._status: tuple[str | None, ...] | None = None
        self._corrections = b""
        self._calibration: tuple[tuple[float, float, float], str] | None = None
        self._stage_name: str | None = None
        self._goal_colours: dict[str, int] = {}
        self._open_series: set[str] = set()  # plots with a line in progress
        self._pending_clears: list[str] = []
        self._paths: dict[str, str] = {}
        self._p_thresh: float | None = None
        self._threshold_due = False
        self._mode: str | None = None
        self._joystick_shown = False
        self._ee_axes_sent = False
        self._stream.send_recording_name(f"legws {robot}")
        self._stream.log("meta/robot", rr.TextDocument(robot), static=True)
        self._stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def _open_sinks(self, targets: list[tuple[str, str | None]]) -> None:
        sinks: list[Any] = []
        for kind, arg in targets:
            if kind == "save":
                path = self._save_path
                assert path is not None
                # no footer while logging: its manifest would grow in memory all session
                sinks.append(rr.FileSink(path, write_footer=False))
            elif kind == "spawn":
                viewer = viewer_executable()
                try:
                    rr.spawn(executable_path=str(viewer), connect=False)
                except (OSError, RuntimeError) as exc:
                    detail = " ".join(str(exc).split())
                    raise InputError(f"cannot start the Rerun viewer {viewer}: {detail}",
                                     field="--rerun") from None  # fmt: skip
                sinks.append(rr.GrpcSink(SPAWN_URL))
            elif kind == "web":
                from legws_daemon.telemetry.web_viewer import WebViewer, parse_web_target

                self.web = WebViewer.start(parse_web_target(arg))
                sinks.append(rr.GrpcSink(self.web.target.grpc_url))
            else:
                sinks.append(rr.GrpcSink(arg) if arg else rr.GrpcSink())
        try:
            self._stream.set_sinks(*sinks, default_blueprint=default_blueprint())
        except (OSError, RuntimeError, ValueError) as exc:
            detail = " ".join(str(exc).split())
            if self._save_path is not None:
                detail += _disk_note(self._save_path)
                raise InputError(f"cannot write {self._save_path}: {detail}",
                                 field="--rerun") from None  # fmt: skip
            raise InputError(f"cannot open the Rerun sinks: {detail}", field="--rerun") from None

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> RerunLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- setup (static) ------------------------------------------------------------------------

    def log_setup(
        self,
        *,
        scene: Scene,
        goals: GoalSet | Sequence[str],
        goal_objects: dict[str, str],
        planned: dict[str, ObjectPose],
        p_thresh: float,
        params_json: str,
        stage: str | None = None,
    ) -> None:
        """Log a stage (one decision): table, planned layout, grasps, goal set, params,
        threshold.

        ``goals`` is the candidates' goal set, or, for a decision without inference (a
        single candidate), the candidates' names: the stage is recorded all the same (its
        EE samples and log lines carry its own index), without grasps or posterior.

        Replaces the static data of the previous stage; objects of the previous scene that
        this one lacks are cleared at the next tick. Every plot line in progress ends here
        (a NaN at the latest tick): no curve runs on from one decision into the next.

        Raises:
            InputError: unknown goal or object names, a threshold outside (0, 1), or a
                ``params_json`` that is not a valid Params object.
        """
        if isinstance(goals, str):
            raise InputError(f"expected candidate names, got {goals!r}", field="goals")
        names = goals.names if isinstance(goals, GoalSet) else tuple(goals)
        self._check_setup(scene, names, goal_objects, planned, p_thresh)
        if self._closed:
            return
        doc = self._stage_doc(scene, goals, goal_objects, planned, p_thresh, params_json, stage)
        self._stage += 1
        self._stage_name = stage
        doc["stage_index"] = self._stage
        static: dict[str, str] = {}
        self._log_table(scene, static)
        self._log_planned(scene, planned, static)
        if isinstance(goals, GoalSet):
            self._log_grasps(goals, static)
        self._log_series(names if isinstance(goals, GoalSet) else (), static)
        self._clear_static(static)
        text = json.dumps(doc, indent=1, allow_nan=False)
        self._stream.log(GOALS_DOC, rr.TextDocument(text), static=True)
        self._set_time(*self._now)  # the set-up belongs to the latest tick (0 at start)
        self._end_lines(self._open_series)
        self._open_series = set()
        self._stream.log(STAGES_DOC, rr.TextDocument(text))
        self._stream.log(PARAMS_DOC, rr.TextDocument(params_json), static=True)
        self._reset_stage(scene, names, goal_objects, p_thresh)
        self._logged += 1

    @staticmethod
    def _check_setup(
        scene: Scene,
        names: Sequence[str],
        goal_objects: Mapping[str, str],
        planned: Mapping[str, ObjectPose],
        p_thresh: float,
    ) -> None:
        if not names or not all(isinstance(n, str) and n for n in names):
            raise InputError(f"expected candidate names, got {list(names)!r}", field="goals")
        for goal, obj in goal_objects.items():
            if goal not in names:
                raise InputError(f"unknown goal '{goal}'; known: {', '.join(names)}", field="goal")
            scene.object(obj)
        for obj in planned:
            scene.object(obj)
        if not (isinstance(p_thresh, int | float) and 0.0 < p_thresh < 1.0):
            raise InputError(f"expected a number in (0, 1), got {p_thresh!r}", field="p_thresh")

    def _stage_doc(
        self,
        scene: Scene,
        goals: GoalSet | Sequence[str],
        goal_objects: Mapping[str, str],
        planned: Mapping[str, ObjectPose],
        p_thresh: float,
        params_json: str,
        stage: str | None,
    ) -> dict[str, Any]:
        params = parse_params_json(params_json)
        if isinstance(goals, GoalSet):
            doc = goalset_to_data(goals, params)
            doc.update(candidates=list(goals.names), inference=True)
        else:  # no goal set: a decision without inference
            doc = {"params": params.as_dict(), "candidates": list(goals), "inference": False}
        doc.update(
            legws_telemetry=TELEMETRY_FORMAT,
            stage=stage,
            robot=self.robot,
            scene=scene.name,
            p_thresh=float(p_thresh),
            goal_objects=dict(goal_objects),
            planned={n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in planned.items()},
        )
        return doc

    def _log_table(self, scene: Scene, static: dict[str, str]) -> None:
        ws = scene.workspace
        box = rr.Boxes3D(
            centers=[[ws.table_center[0], ws.table_center[1], ws.table_height - 0.02]],
            half_sizes=[[ws.table_size[0] / 2, ws.table_size[1] / 2, 0.02]],
            colors=[[209, 189, 153]],
            fill_mode="solid",
        )
        self._stream.log("world/table", box, static=True)
        static["world/table"] = "box"

    def _log_planned(
        self, scene: Scene, planned: Mapping[str, ObjectPose], static: dict[str, str]
    ) -> None:
        for name, pose in planned.items():
            path = f"world/planned/{_part(name)}"
            box = rr.Boxes3D(
                centers=[[pose.x, pose.y, scene.z_center(name)]],
                half_sizes=[_half_size(scene, name)],
                quaternions=[rr.Quaternion(xyzw=_xyzw(yaw_quat(pose.yaw)))],
                colors=[_PLANNED],
                fill_mode="majorwireframe",
            )
            self._stream.log(path, box, static=True)
            static[path] = "box"

    def _log_grasps(self, goals: GoalSet, static: dict[str, str]) -> None:
        for i, name in enumerate(goals.names):
            path = f"world/grasps/{_part(name)}"
            frame = rr.Transform3D(
                translation=goals.positions[i],
                quaternion=rr.Quaternion(xyzw=_xyzw(goals.quaternions[i])),
            )
            approach = rr.Arrows3D(
                origins=[[0.0, 0.0, -0.06]],
                vectors=[[0.0, 0.0, 0.06]],
                colors=[_PALETTE[i % len(_PALETTE)]],
                radii=[0.002],
            )
            self._stream.log(path, frame, approach, static=True)
            static[path] = "grasp"

    def _log_series(self, names: Sequence[str], static: dict[str, str]) -> None:
        # a goal keeps its colour for the whole session (its earlier curves stay in the
        # plot), so the styles of earlier stages' goals are not cleared
        for name in names:
            if name in self._goal_colours:
                continue
            colour = _PALETTE[len(self._goal_colours) % len(_PALETTE)]
            self._goal_colours[name] = colour
            style = rr.SeriesLines(colors=[colour], names=[name], widths=2)
            self._stream.log(self._posterior_path(name), style, static=True)
        styles: dict[str, rr.SeriesLines | rr.SeriesPoints] = {
            "plots/threshold": rr.SeriesLines(colors=[0xBBBBBBFF], names=["threshold"], widths=1),
            COMMITS_PLOT: rr.SeriesPoints(
                colors=[_COMMITTED], names=["commit"], markers=["diamond"], marker_sizes=[6]
            ),
            "plots/slack": rr.SeriesLines(colors=[0x4FC3F7FF], names=["slack J"], widths=2),
            f"{TIMING}/tick_ms": rr.SeriesLines(colors=[0x9CCC65FF], names=["tick"], widths=1),
            f"{TIMING}/budget_ms": rr.SeriesLines(colors=[0xBBBBBBFF], names=["budget"], widths=1),
            f"{TIMING}/overruns": rr.SeriesPoints(
                colors=[_OVERRUN], names=["overrun"], markers=["cross"], marker_sizes=[5]
            ),
        }
        for path, series in styles.items():
            self._stream.log(path, series, static=True)
            static[path] = "points" if isinstance(series, rr.SeriesPoints) else "series"

    def _clear_static(self, static: dict[str, str]) -> None:
        """Overwrite the static data of entities the new stage no longer has."""
        for path, kind in self._static.items():
            if path in static:
                continue
            if kind == "box":
                self._stream.log(path, rr.Boxes3D.cleared(), static=True)
            elif kind == "grasp":
                cleared = (rr.Transform3D.cleared(), rr.Arrows3D.cleared())
                self._stream.log(path, *cleared, static=True)
            elif kind == "points":
                self._stream.log(path, rr.SeriesPoints.cleared(), static=True)
            else:
                self._stream.log(path, rr.SeriesLines.cleared(), static=True)
        self._static = static

    def _reset_stage(
        self,
        scene: Scene,
        names: Sequence[str],
        goal_objects: Mapping[str, str],
        p_thresh: float,
    ) -> None:
        shapes = {name: _shape_of(scene, name) for name in scene.objects}
        # objects gone, or drawn as another shape now (the old archetype would stay)
        self._pending_clears.extend(
            f"world/objects/{_part(n)}"
            for n, state in self._objects.items()
            if shapes.get(n, _UNKNOWN).kind != state.shape.kind or n not in shapes
        )
        self._shapes = shapes
        self._objects = {}
        self._goal_object = {g: goal_objects[g] for g in names if g in goal_objects}
        self._object_goals = {}
        for goal, obj in self._goal_object.items():
            self._object_goals.setdefault(obj, []).append(goal)
        self._p_thresh = float(p_thresh)
        self._threshold_due = True
        self._trail.clear()

    def _posterior_path(self, goal: str) -> str:
        path = self._paths.get(goal)
        if path is None:
            path = self._paths[goal] = POSTERIOR_PREFIX + _part(goal)
        return path

    # --- per tick ------------------------------------------------------------------------------

    def log_tick(self, snap: TickSnapshot) -> None:
        """Log one control tick (see the module docstring for the entities, and
        :class:`~legws_daemon.telemetry.snapshot.TickSnapshot` for the fields). Never
        raises."""
        if self._closed:
            return
        posterior = snap.posterior or None  # an empty posterior (no goals in the stage): none
        tick, t, mode = snap.tick, snap.t, snap.mode
        try:
            self._set_time(tick, t)
            for path in self._pending_clears:
                self._stream.log(path, rr.Clear(recursive=False))
            self._pending_clears.clear()
            self._robot.log_poses(tick, snap.link_positions, snap.link_rotations)
            if snap.gripper_half_gap is not None:
                self._robot.log_fingers(float(snap.gripper_half_gap))
            ee = self._log_ee(t, snap.ee_position, snap.ee_quaternion, snap.joystick, mode)
            self._log_objects(snap.objects, posterior, snap.committed)
            self._log_arrows(ee, snap.joystick, snap.command)
            self._log_plots(tick, posterior, snap.slack, snap.tick_seconds)
            if mode != self._mode:
                self._stream.log("status/mode", rr.TextLog(f"mode {mode}", level="INFO"))
                self._mode = mode
            lines = (*(snap.placement or ()), *self._calibration_lines(snap.calibration, ee),
                     *(snap.operator_model or ()))  # fmt: skip
            fields = (mode, snap.operator, snap.phase, snap.fault, snap.stage)
            self._log_status(fields, snap.committed, lines)
            self._log_corrections(snap.corrections or {})
            self._log_calibration(snap.calibration)
            self._logged += 1
        except Exception as exc:  # telemetry must never stop the control loop
            self._drop("tick", exc)

    def log_robot(self, visual: RobotVisual) -> None:
        """Draw the arm with its own meshes from now on (static; call once, before the
        ticks: the first tick then shows the whole arm). Never raises."""
        if self._closed:
            return
        try:
            self._robot = RobotDrawing(self._stream.log, self._fast, visual, self._robot.every)
            self._robot.log_static()
            self._logged += 1
        except Exception as exc:  # telemetry must never stop the control loop
            self._drop("robot", exc)

    def _log_status(
        self,
        fields: tuple[str | None, ...],
        committed: str | None,
        placement: tuple[str, ...] | None = None,
    ) -> None:
        """The status panel, re-sent when a field changes."""
        mode, operator, phase, fault, stage = fields
        stage = stage or self._stage_name
        key = (mode, operator, phase, fault, stage, committed, *(placement or ()))
        if key == self._status:
            return
        self._status = key
        fault_text = f"**fault** :warning: {_md(fault)}" if fault else "**fault** none"
        doc = "  \n".join(
            [
                f"**mode** {_md(mode)} · **phase** {_md(phase or '-')} · "
                f"**stage** {_md(stage or '-')}",
                f"**committed** {_md(committed or '-')} · {fault_text}",
                f"**operator** {_md(operator or 'none')}",
                *(_md(line) for line in placement or ()),
            ]
        )
        self._stream.log(STATUS_DOC, rr.TextDocument(doc, media_type=rr.MediaType.MARKDOWN))

    @staticmethod
    def _calibration_lines(
        calibration: tuple[tuple[float, float, float], str] | None, ee: FloatArray
    ) -> tuple[str, ...]:
        """The status line of the calibration target (its distance to the centimetre, so
        the panel is re-sent about every 0.2 s while the EE moves)."""
        if calibration is None:
            return ()
        target, label = calibration
        cm = 100 * float(np.linalg.norm(np.asarray(target, dtype=np.float64) - ee))
        return (f"calibration: {label}, {cm:.0f} cm to go",)

    def _log_calibration(self, calibration: tuple[tuple[float, float, float], str] | None) -> None:
        """The calibration target shown (re-sent when it changes; cleared when none is)."""
        if calibration == self._calibration:
            return
        self._calibration = calibration
        if calibration is None:
            self._stream.log(CALIBRATION_TARGET_PATH, rr.Clear(recursive=False))
            return
        target, label = calibration
        self._stream.log(
            CALIBRATION_TARGET_PATH,
            rr.Points3D(
                [list(target)], labels=[label], colors=[_CALIBRATION], radii=0.015,
                show_labels=True,
            ),
        )  # fmt: skip

    def _log_corrections(self, corrections: Mapping[str, tuple[FloatArray, FloatArray]]) -> None:
        """Arrows from where each misplaced object stands to where it should (re-sent when
        they change; cleared when all are in place)."""
        names = sorted(corrections)
        key = b"".join(
            n.encode() + np.asarray(corrections[n], dtype=np.float64).tobytes() for n in names
        )
        if key == self._corrections:
            return
        self._corrections = key
        if not names:
            self._stream.log(PLACEMENT_PATH, rr.Clear(recursive=False))
            return
        start = np.array([corrections[n][0] for n in names], dtype=np.float64)
        end = np.array([corrections[n][1] for n in names], dtype=np.float64)
        self._stream.log(
            PLACEMENT_PATH,
            rr.Arrows3D(
                origins=start, vectors=end - start, labels=names, colors=[_MISPLACED], radii=0.004
            ),
        )

    def _drop(self, what: str, exc: Exception) -> None:
        self.dropped += 1
        self.last_error = f"{what}: {type(exc).__name__}: {exc}"
        if self.dropped == 1 or self.dropped % 1000 == 0:
            _LOG.warning("rerun telemetry: %s not logged (%d so far): %s", what, self.dropped, exc)

    def _set_time(self, tick: int, t: float) -> None:
        self._now = (tick, t)
        self._stream.set_time("tick", sequence=tick)
        self._stream.set_time("time", duration=t)

    def _log_ee(
        self,
        t: float,
        position: FloatArray,
        quaternion: FloatArray,
        joystick: FloatArray | None = None,
        mode: str = "",
    ) -> FloatArray:
        """The EE pose of the tick, with the deflection that reached the controller (empty
        when none: deadman) and the mode: what ``legws operator trace`` reads back."""
        p = np.array(position, dtype=np.float64).reshape(3)
        q = np.array(quaternion, dtype=np.float64).reshape(4)
        u = [] if joystick is None else np.asarray(joystick, dtype=np.float64).ravel()[:3].tolist()
        fast = self._fast
        pose = [
            fast.fixed("Transform3D:translation", p),
            fast.fixed("Transform3D:quaternion", _xyzw(q)),
            fast.plain(f"{EE_ARCHETYPE}:position", p.tolist()),
            fast.plain(f"{EE_ARCHETYPE}:quaternion", q.tolist()),
            fast.plain(f"{EE_ARCHETYPE}:t", [float(t)]),
            fast.plain(f"{EE_ARCHETYPE}:stage", [self._stage]),
            fast.plain(f"{EE_ARCHETYPE}:deflection", u),
            fast.plain(f"{EE_ARCHETYPE}:mode", [mode]),
        ]
        if not self._ee_axes_sent:
            self._stream.log(EE_PATH, rr.TransformAxes3D(0.08), static=True)
            self._ee_axes_sent = True
        self._stream.log(EE_PATH, pose)
        if self._trail.add(p):
            strip = [fast.strips("LineStrips3D:strips", self._trail.ordered())]
            self._stream.log("world/ee_trail", strip)
        return p

    def _log_objects(
        self,
        objects: Mapping[str, tuple[FloatArray, FloatArray]],
        posterior: Mapping[str, float] | None,
        committed: str | None,
    ) -> None:
        committed_object = self._goal_object.get(committed) if committed else None
        outline: tuple[FloatArray, FloatArray, _Shape] | None = None
        for name, (position, quaternion) in objects.items():
            state = self._objects.get(name)
            if state is None:
                state = self._objects[name] = _ObjectState(self._shapes.get(name, _UNKNOWN))
            p = np.asarray(position, dtype=np.float64).reshape(3)
            q = np.asarray(quaternion, dtype=np.float64).reshape(4)
            label = self._object_label(name, posterior)
            sent = p.tobytes() + q.tobytes() + label.encode()
            if sent != state.sent:
                state.sent = sent
                self._stream.log(f"world/objects/{_part(name)}", state.shape.archetype(p, q, label))
            if name == committed_object:
                outline = (p, q, state.shape)
        self._log_outline(outline)

    def _log_outline(self, outline: tuple[FloatArray, FloatArray, _Shape] | None) -> None:
        """An amber outline around the committed object (cleared without a commit)."""
        if outline is None:
            if self._committed_outline is not None:
                self._stream.log("world/committed", rr.Clear(recursive=False))
                self._committed_outline = None
            return
        p, q, shape = outline
        key = p.tobytes() + q.tobytes()
        if key == self._committed_outline:
            return
        self._committed_outline = key
        box = rr.Boxes3D(
            centers=[p],
            half_sizes=[[h + 0.012 for h in shape.half_size]],
            quaternions=[rr.Quaternion(xyzw=_xyzw(q))],
            colors=[_COMMITTED],
            radii=[0.003],
            fill_mode="majorwireframe",
        )
        self._stream.log("world/committed", box)

    def _object_label(self, name: str, posterior: Mapping[str, float] | None) -> str:
        """A candidate's name, then its probability (in :data:`_LABEL_STEPS` steps, so the
        label is re-sent only when it visibly changes) while inferring. Once a stage is set
        up, other objects (done with, or for a later decision) have none: a brick sorted
        into a bin would write its name over the bin's."""
        goals = self._object_goals.get(name)
        if not goals:
            return name if self._stage < 0 else ""
        if posterior is None:
            return name
        p = min(max(sum(float(posterior.get(g, 0.0)) for g in goals), 0.0), 1.0)
        return f"{name} {round(p * _LABEL_STEPS) / _LABEL_STEPS:.2f}"

    def _log_arrows(self, ee: FloatArray, joystick: FloatArray | None, command: FloatArray) -> None:
        fast = self._fast
        origin = fast.fixed("Arrows3D:origins", ee)
        if joystick is None:
            if self._joystick_shown:
                self._stream.log("world/joystick", rr.Clear(recursive=False))
                self._joystick_shown = False
        else:
            stick = np.asarray(joystick, dtype=np.float64).ravel()[:3] * 0.1
            arrow = [
                origin,
                fast.fixed("Arrows3D:vectors", stick),
                fast.constant("Arrows3D:colors", 0x3080FFFF),
            ]
            self._stream.log("world/joystick", arrow)
            self._joystick_shown = True
        velocity = np.asarray(command, dtype=np.float64).ravel()[:3] * self._command_scale
        arrow = [
            origin,
            fast.fixed("Arrows3D:vectors", velocity),
            fast.constant("Arrows3D:colors", 0xFF5020FF),
        ]
        self._stream.log("world/command", arrow)

    def _log_plots(
        self,
        tick: int,
        posterior: Mapping[str, float] | None,
        slack: float | None,
        tick_s: float | None,
    ) -> None:
        fast = self._fast
        drawn = set()
        for goal, p in (posterior or {}).items():
            path = self._posterior_path(goal)
            self._stream.log(path, [fast.plain("Scalars:scalars", [p])])
            drawn.add(path)
        if posterior is None:  # inference stopped: a NaN ends each line (none across the gap)
            self._end_lines(self._open_series)
            self._open_series = set()
        else:
            # a goal no longer inferred (not a candidate now) ends its line; the slack
            # comes every few ticks: its line goes on between its points
            gone = {p for p in self._open_series if p.startswith(POSTERIOR_PREFIX)} - drawn
            self._end_lines(gone)
            self._open_series -= gone
            self._open_series |= drawn
            if slack is not None:
                self._open_series.add("plots/slack")
        if self._p_thresh is not None and (self._threshold_due or tick % _THRESHOLD_EVERY == 0):
            value = [fast.constant("Scalars:scalars", self._p_thresh)]
            self._stream.log("plots/threshold", value)
            self._threshold_due = False
        if slack is not None:
            self._stream.log("plots/slack", [fast.plain("Scalars:scalars", [slack])])
        if tick_s is None:
            return
        ms = tick_s * 1e3
        self._stream.log(f"{TIMING}/tick_ms", [fast.plain("Scalars:scalars", [ms])])
        budget = self._budget_ms
        if budget is not None:
            if tick % _THRESHOLD_EVERY == 0:
                self._stream.log(f"{TIMING}/budget_ms", [fast.constant("Scalars:scalars", budget)])
            if ms > budget:
                self._stream.log(f"{TIMING}/overruns", [fast.plain("Scalars:scalars", [ms])])

    def _end_lines(self, paths: Iterable[str]) -> None:
        """A NaN at the current time on each plot of ``paths``: its line ends there."""
        for path in sorted(paths):
            self._stream.log(path, [self._fast.constant("Scalars:scalars", math.nan)])

    # --- events and lifecycle ------------------------------------------------------------------

    def log_text(self, tick: int, t: float, level: str, text: str) -> None:
        """A line of the text log (``INFO``, ``WARN``, ``ERROR``); tagged with the stage. The
        text is made terminal-safe (``legws replay`` prints it; a goal name or a joystick's
        source in it may hold escapes)."""
        if self._closed:
            return
        try:
            text = safe_text(text, MESSAGE_LIMIT)
            lvl = level.upper()
            lvl = "WARN" if lvl == "WARNING" else lvl
            self._set_time(tick, t)
            stage = [self._fast.plain(f"{STAGE_ARCHETYPE}:stage", [self._stage])]
            self._stream.log(TEXT_LOG, rr.TextLog(text, level=lvl), stage)
            commit = parse_commit(text)
            if commit is not None:
                self._stream.log(COMMITS_PLOT, [self._fast.plain("Scalars:scalars", [commit.p])])
            self._logged += 1
        except Exception as exc:  # telemetry must never stop the control loop
            self._drop("text", exc)

    def log_commit(self, tick: int, t: float, goal: str, p: float, how: How = "inferred") -> None:
        """Log a commit in the format :func:`commit_text` (read back by ``legws replay``)."""
        self.log_text(tick, t, "INFO", commit_text(goal, p, how=how))

    def check(self) -> str | None:
        """Whether the recording still takes data (cheap; any thread).

        Looks at the log calls that failed since the previous check and, for a ``save:``
        file, at the file itself: still there, its disk not full (:data:`LOW_SPACE`), and
        growing while data is logged (rerun's writer stops at its first failed write, and
        says so only on its own stderr). It does not flush: a flush into a writer that
        has just failed can leave rerun unable to close the file or to exit (rerun 0.41).

        Returns:
            ``None`` when all is well, else the problem in one line.
        """
        if self._closed:
            return None
        problems = []
        if self.dropped > self._checked_drops:
            failed = self.dropped - self._checked_drops
            problems.append(f"{failed} log call(s) failed, last: {self.last_error}")
            self._checked_drops = self.dropped
        if self._save_path is not None:
            problem = self._file_problem(self._save_path)
            self._sink_failed = problem is not None
            if problem is not None:
                problems.append(f"recording to {self._save_path}: {problem}")
                self.last_error = problems[-1]
        return "; ".join(problems) or None

    def _file_problem(self, path: Path) -> str | None:
        now = time.monotonic()
        try:
            st = os.stat(path)
        except OSError as err:
            return f"the file is gone ({err.strerror})"
        previous = self._file_state
        if previous is not None and st.st_ino != previous[0]:
            return "the file was replaced"
        free = _free_bytes(path)
        if free is not None and free < LOW_SPACE:
            if free < _FULL:
                return "no space left on the device"
            return f"the disk is nearly full ({free // 1024} KiB left)"
        if previous is None or st.st_size != previous[1] or self._logged == previous[2]:
            self._file_state = (st.st_ino, st.st_size, self._logged, now)
            return None
        if now - previous[3] > STALL_SECONDS:
            return f"the file has not grown for {now - previous[3]:.0f} s while data was logged"
        return None

    def flush(self, timeout: float = 5.0) -> None:
        """Wait (at most ``timeout`` seconds) until everything logged has reached the sink."""
        if self._closed:
            return
        try:
            self._stream.flush(timeout_sec=timeout)
        except Exception as exc:  # a slow viewer must not crash the daemon
            self._drop("flush", exc)

    def close(self, timeout: float = 5.0, *, finish_file: bool = True) -> None:
        """Flush (at most ``timeout`` s) and disconnect; a ``save:`` file is then finished
        (its footer added, :func:`.rrd_file.finish`) unless ``finish_file`` is false.

        Idempotent. With a ``connect:`` target whose server cannot be reached, rerun also
        waits up to 5 s for a last connection attempt before dropping the data. When the
        file cannot be finished, the raw file stays (a valid stream without the manifest),
        :attr:`finished` is false and :attr:`last_error` says why.
        """
        if self._closed:
            return
        self._closed = True  # first: a signal arriving during close must not re-enter it
        if self._sink_failed:
            timeout = min(timeout, FAILED_CLOSE_TIMEOUT)
        # rerun's own lines (a viewer it cannot reach: its last attempts and what it drops)
        # are written from Rust straight to file descriptor 2: caught here, passed on safe
        with rrd_file.quiet_stderr() as said:
            try:
                self._stream.flush(timeout_sec=timeout)
            except Exception as exc:  # closing is best effort: still disconnect
                self._drop("close", exc)
            try:
                self._stream.disconnect()
            except Exception as exc:
                self._drop("close", exc)
                disconnected = False
            else:
                disconnected = True
            finally:
                if self.web is not None:
                    self.web.close()
        _pass_on(said.text)
        if not disconnected:
            return
        if self._save_path is not None and finish_file:
            started = time.monotonic()
            try:
                raw = self._save_path.stat().st_size
            except OSError:
                raw = 0
            problem = rrd_file.finish(self._save_path)
            if problem is not None:
                self.finished = False
                self.last_error = f"{problem}; finish it with: legws recording finish FILE"
                _LOG.warning("telemetry: %s", self.last_error)
            else:
                self.finished = True
                _LOG.info(
                    "recording %s finished in %.2f s (%.1f MiB raw -> %.1f MiB)",
                    self._save_path,
                    time.monotonic() - started,
                    raw / 2**20,
                    self._save_path.stat().st_size / 2**20,
                )
