"""A trial's per-tick frames: where the end effector was, what the stick sent, the mode.

One row per control tick of the trial, written as Parquet (pyarrow) beside the trial table
(``PXX/frames/step-NNN.parquet``, the trial table's ``frames`` column):

- ``tick`` (int64): the tick from the trial's start, 0, 1, ...;
- ``t`` (float64, s): ``tick`` times the control period;
- ``ee`` (3 float64, m): the end effector's position at the tick's start;
- ``axes`` (3 float64, each in [-1, 1]): the joystick deflection that reached the
  controller at that tick; a tick without input (the deadman released) is zeros;
- ``mode`` (string): the controller's mode after the tick (what the daemon records).

The simulator records them while a trial runs (:class:`FrameRecorder`); a real participant's
trial recording (``.rrd``) gives the same file (:func:`frames_from_recording`). Reading one
back (:func:`read_frames`) validates it: every error is one :class:`InputError` naming the
file, the field and what was expected.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.errors import InputError
from legws_daemon.formats.files import regular_file, write_atomic

#: The frames file of a step, relative to the participant's folder.
FRAMES_PATH = "frames/step-{index:03d}.parquet"
#: Longest mode name read.
MAX_MODE = 64
#: A deflection may exceed 1 by this much (a unit vector's rounding).
AXES_TOLERANCE = 1e-9

_UNITS = {"tick": "", "t": "s", "ee": "m", "axes": "", "mode": ""}
_MEANINGS = {
    "tick": "the tick from the trial's start",
    "t": "seconds from the trial's start",
    "ee": "the end effector's position at the tick's start (x, y, z)",
    "axes": "the joystick deflection that reached the controller, in [-1, 1] (none: 0)",
    "mode": "the controller's mode after the tick",
}


@dataclass(frozen=True, slots=True)
class Frames:
    """A trial's frames, one row per tick (the module's columns)."""

    tick: IntArray  # (K,)
    t: FloatArray  # (K,) s
    ee: FloatArray  # (K, 3) m
    axes: FloatArray  # (K, 3)
    mode: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.tick.shape[0])


def frames_path(index: int) -> str:
    """The frames file of the step ``index``, relative to the participant's folder."""
    return FRAMES_PATH.format(index=index)


def make_frames(ticks: Any, ee: Any, axes: Any, modes: Any, dt: float) -> Frames:
    """Frames of these ticks (``t`` is ``tick * dt``; ``NaN`` axes, a tick without input,
    become zeros)."""
    tick = np.asarray(ticks, dtype=np.int64).reshape(-1)
    deflection = np.nan_to_num(np.asarray(axes, dtype=np.float64).reshape(-1, 3), nan=0.0)
    return Frames(
        tick,
        tick.astype(np.float64) * dt,
        np.asarray(ee, dtype=np.float64).reshape(-1, 3),
        deflection,
        tuple(str(m) for m in modes),
    )


class FrameRecorder:
    """Collects a trial's frames tick by tick (the ``on_tick`` of
    :meth:`~legws_daemon.sim.protocol.Evaluator.pick`)."""

    def __init__(self) -> None:
        self.ticks: list[int] = []
        self.ee: list[FloatArray] = []
        self.axes: list[FloatArray] = []
        self.modes: list[str] = []

    def __call__(self, tick: int, ee: FloatArray, axes: FloatArray, mode: str) -> None:
        self.ticks.append(tick)
        self.ee.append(np.array(ee, dtype=np.float64))
        self.axes.append(np.array(axes, dtype=np.float64))
        self.modes.append(mode)

    def frames(self, dt: float) -> Frames:
        return make_frames(self.ticks, self.ee, self.axes, self.modes, dt)


def _schema() -> Any:
    import pyarrow as pa  # type: ignore[import-untyped]

    vector = pa.list_(pa.float64(), 3)
    types = {"tick": pa.int64(), "t": pa.float64(), "ee": vector, "axes": vector,
             "mode": pa.string()}  # fmt: skip
    return pa.schema(
        [pa.field(name, kind, nullable=False,
                  metadata={"unit": _UNITS[name], "meaning": _MEANINGS[name]})
         for name, kind in types.items()]
    )  # fmt: skip


def frames_table(frames: Frames) -> Any:
    """The frames as a pyarrow table of the module's schema."""
    import pyarrow as pa

    schema = _schema()
    vector = schema.field("ee").type

    def vectors(a: FloatArray) -> Any:
        return pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1), pa.float64()), 3)

    columns = [
        pa.array(frames.tick, pa.int64()),
        pa.array(frames.t, pa.float64()),
        vectors(frames.ee).cast(vector),
        vectors(frames.axes).cast(vector),
        pa.array(list(frames.mode), pa.string()),
    ]
    return pa.Table.from_arrays(columns, schema=schema)


def write_frames(path: Path, frames: Frames) -> Path:
    """Write ``frames`` to ``path`` (Parquet, atomically); returns ``path``."""
    import pyarrow as pa
    import pyarrow.parquet as pq  # type: ignore[import-untyped]

    buf = pa.BufferOutputStream()
    pq.write_table(frames_table(frames), buf)
    return write_atomic(path, buf.getvalue().to_pybytes())


def _error(path: Path, name: str, message: str) -> InputError:
    return InputError(message, source=str(path), field=name)


def _column(path: Path, table: Any, name: str, what: str, ok: Any, expected: str) -> Any:
    """The column ``name`` of ``table``, its type checked by ``ok``, without nulls."""
    index = table.schema.get_field_index(name)
    if index < 0:
        raise _error(path, name, f"expected a column '{name}' ({what}), found none")
    column = table.column(index)
    if not ok(column.type):
        raise _error(path, name, f"expected {what} ({expected}), got {column.type}")
    if column.null_count:
        raise _error(path, name, f"expected {what} in every row, {column.null_count} empty")
    return column


def _is_vector(kind: Any) -> bool:
    import pyarrow as pa

    return bool(
        pa.types.is_fixed_size_list(kind)
        and kind.list_size == 3
        and kind.value_type == pa.float64()
    )


def _vectors(path: Path, table: Any, name: str, what: str) -> FloatArray:
    column = _column(path, table, name, what, _is_vector, "3 float64 a row")
    flat = column.combine_chunks().flatten().to_numpy(zero_copy_only=False)
    out = np.asarray(flat, dtype=np.float64).reshape(-1, 3)
    bad = ~np.all(np.isfinite(out), axis=1)
    if np.any(bad):
        raise _error(
            path, name, f"expected finite {what}, row {int(np.flatnonzero(bad)[0])} is not"
        )
    return out


def _scalars(path: Path, table: Any, name: str, what: str, kind: Any) -> Any:
    column = _column(path, table, name, what, lambda t: t == kind, str(kind))
    return column.to_numpy()


def read_frames(path: Path) -> Frames:
    """The frames in ``path``, validated (the module's columns and types; ticks increasing,
    ``t`` finite and increasing, axes in [-1, 1], mode names of at most :data:`MAX_MODE`
    characters)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    regular_file(path, "study table")
    try:
        table = pq.read_table(path)
    except Exception as err:  # pyarrow's errors have no common base beyond ArrowException
        raise InputError(f"not a readable Parquet table: {err}", source=str(path)) from None
    tick = np.asarray(_scalars(path, table, "tick", "the tick", pa.int64()), dtype=np.int64)
    t = np.asarray(_scalars(path, table, "t", "seconds", pa.float64()), dtype=np.float64)
    ee = _vectors(path, table, "ee", "3 positions, m")
    axes = _vectors(path, table, "axes", "3 deflections")
    names = _column(path, table, "mode", "the mode's name", pa.types.is_string, "string")
    mode = tuple(str(m) for m in names.to_pylist())
    _check(path, tick, t, axes, mode)
    return Frames(tick, t, ee, axes, mode)


def _check(
    path: Path, tick: IntArray, t: FloatArray, axes: FloatArray, mode: tuple[str, ...]
) -> None:
    if tick.size and (tick[0] < 0 or np.any(np.diff(tick) <= 0)):
        raise _error(path, "tick", "expected ticks from 0 up, increasing")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise _error(path, "t", "expected finite seconds, increasing")
    over = np.any(np.abs(axes) > 1.0 + AXES_TOLERANCE, axis=1)
    if np.any(over):
        row = int(np.flatnonzero(over)[0])
        raise _error(path, "axes", f"expected deflections in [-1, 1], row {row} is not")
    long = [m for m in mode if not m or len(m) > MAX_MODE]
    if long:
        raise _error(path, "mode", f"expected a mode's name of 1..{MAX_MODE} characters")


def frames_from_recording(rrd_path: Path, dt: float) -> Frames:
    """The frames of a trial's recording (``.rrd``): every tick with the EE, the deflection
    and the mode (:func:`~legws_daemon.telemetry.recording.read_teleoperation`), ticks
    counted from the recording's first; a tick logged in two stages keeps the later."""
    from legws_daemon.telemetry.recording import read_teleoperation

    tele = read_teleoperation(rrd_path)
    if tele.ticks.size == 0:
        raise InputError(
            "expected ticks with the EE position, the deflection and the mode, found none",
            source=str(rrd_path),
            field="ee",
        )
    # the last row of each tick (rows are ordered by tick, then stage)
    last = np.flatnonzero(np.append(np.diff(tele.ticks) != 0, True))
    ticks = tele.ticks[last] - tele.ticks[0]
    modes = [tele.modes[i] for i in last.tolist()]
    return make_frames(ticks, tele.positions[last], tele.deflections[last], modes, dt)
