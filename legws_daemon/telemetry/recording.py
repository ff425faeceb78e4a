"""Reading a daemon recording (``.rrd`` written by :class:`~.rerun_log.RerunLog`) headless.

Uses :class:`rerun.chunk.RrdReader`: no viewer, no server. A recording is input like any
other file: before this process decodes any of it, its framing is checked and a ``rerun``
child process decodes all of it (:func:`~.rrd_file.check_readable`: rerun's reader aborts
the process on some damaged payloads), and rerun's own log lines are kept off the terminal
(:func:`~.rrd_file.quiet_stderr`). Every document and column read is validated
(:mod:`legws_daemon.formats.recording_doc`): a column of another Arrow type, a position of
another number of floats, a value out of its range, a stage document that is not the goal
set's schema. Every error (missing file, not an ``.rrd``, damaged, no legws telemetry in
it, a field out of range) is one :class:`InputError` naming the file and the field.

Stages: each :meth:`RerunLog.log_setup` call writes one ``meta/goals`` document with its
``stage_index`` (0, 1, ...), static (the viewer shows the latest) and on the timelines as
``meta/stages`` (every stage; a finished file keeps only the newest static one).
Every EE sample and text-log row carries the index of the stage it was logged in (``-1``
before the first set-up). The readers take an optional ``stage``: ``None`` means the last
stage for :func:`read_goals` and :func:`read_params` (what the viewer shows) and every
stage for :func:`read_ee_path` and :func:`read_text_log`; an ``int`` is a stage index
(negative from the end); a ``str`` is a stage's name if only one stage has it, else
``NAME#K``, the K-th stage of that name (:func:`select_index`).

The posterior plots ``plots/posterior/<goal>`` carry no stage index: a tick belongs to
the stage whose EE samples span it (from the stage's first EE tick to the next stage's
first EE tick), which :func:`read_posterior` uses to give each stage its own values.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr
from rerun.chunk import RrdReader

from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.files import regular_file
from legws_daemon.formats.goalset import goalset_from_data, params_from_schema
from legws_daemon.formats.log_lines import How
from legws_daemon.formats.log_lines import parse_commit as parse_commit
from legws_daemon.formats.recording_doc import (
    MAX_ROW,
    MAX_STAGE,
    MAX_TICK,
    StageDoc,
    commit_row,
    one_line,
    parse_stage_doc,
)
from legws_daemon.formats.scene_file import CELL_XY, CELL_Z
from legws_daemon.formats.validation import (
    MAX_COORDINATE,
    MAX_QUATERNION_NORM,
    printable,
    unsafe_character,
)
from legws_daemon.telemetry import rrd_file
from legws_daemon.telemetry.rerun_log import (
    EE_ARCHETYPE,
    EE_PATH,
    GOALS_DOC,
    POSTERIOR_PREFIX,
    STAGE_ARCHETYPE,
    STAGES_DOC,
    TELEMETRY_FORMAT,
    TEXT_LOG,
)

StageKey = int | str | None


@dataclass(frozen=True, slots=True)
class Stage:
    """One ``log_setup`` of a recording: one decision.

    Attributes:
        index: stage index (0 for the first set-up).
        name: the stage name given to ``log_setup`` (may be ``None``).
        goals: the stage's goal set; ``None`` for a decision without inference (a single
            candidate).
        params: the stage's parameters.
        p_thresh: the threshold the daemon plotted.
        scene: scene name.
        robot: robot name.
        goal_objects: goal name -> object name.
        candidates: the candidates' names (the goal set's, or the single one's).
    """

    index: int
    name: str | None
    goals: GoalSet | None
    params: Params
    p_thresh: float
    scene: str | None
    robot: str | None
    goal_objects: dict[str, str]
    candidates: tuple[str, ...] = ()

    @property
    def inference(self) -> bool:
        """Whether the daemon inferred in this stage (it has a goal set)."""
        return self.goals is not None


class EePath(NamedTuple):
    """The recorded end-effector path, ordered by (stage, tick)."""

    ticks: IntArray
    times: FloatArray
    positions: FloatArray
    quaternions: FloatArray


class Posterior(NamedTuple):
    """The posterior the daemon plotted, one row per tick that has a value of any goal.

    Attributes:
        goals: the goal names, one column each.
        ticks: ``(K,)`` ticks, increasing.
        times: ``(K,)`` seconds on the ``time`` timeline.
        values: ``(K, len(goals))``; ``NaN`` where a goal has no value at that tick.
    """

    goals: tuple[str, ...]
    ticks: IntArray
    times: FloatArray
    values: FloatArray

    def row_at(self, tick: int) -> int | None:
        """The row of the latest tick ``<= tick`` (``None`` when every row is later)."""
        i = int(np.searchsorted(self.ticks, tick, side="right")) - 1
        return i if i >= 0 else None

    def as_dict(self, row: int) -> dict[str, float | None]:
        """Goal name -> value of one row (``None`` for a goal without a value there)."""
        return {
            g: None if np.isnan(v) else float(v)
            for g, v in zip(self.goals, self.values[row].tolist(), strict=True)
        }


class RecordedCommit(NamedTuple):
    """A commit line of the text log (:mod:`legws_daemon.formats.log_lines`).

    Attributes:
        tick: the tick of the line.
        seconds: its time on the ``time`` timeline (``None`` when it has none).
        goal: the committed goal.
        p: the probability the daemon wrote.
        how: ``inferred``, ``confirmed`` (the operator pressed confirm) or ``single``.
    """

    tick: int
    seconds: float | None
    goal: str
    p: float
    how: How


_FLOAT = pa.float64()
_INT = pa.int64()
_TEXT = pa.string()
_ITEM_NAMES = {_FLOAT: "float64", _INT: "int64", _TEXT: "string"}
#: Largest deflection or other vector value read, metres (or a unit stick): finite and far
#: beyond any real one.
_MAX_VALUE = MAX_COORDINATE
#: Longest name of a mode or a level in a row.
_MAX_NAME = 64


class _Batch(NamedTuple):
    source: str  # the file
    entity: str  # without the leading "/"
    static: bool
    batch: Any  # pyarrow.RecordBatch

    def _type(self, name: str) -> Any:
        index = self.batch.schema.get_field_index(name)
        return None if index < 0 else self.batch.schema.field(index).type

    def error(self, name: str, message: str, tick: int | None = None) -> InputError:
        where = f"{self.entity}: {name}" + ("" if tick is None else f" (tick {tick})")
        return InputError(message, source=self.source, field=where)

    def ticks(self) -> list[int | None]:
        """The ``tick`` timeline (``[]`` when the chunk lacks it): int64, 0..MAX_TICK."""
        kind = self._type("tick")
        if kind is None:
            return []
        if kind != _INT:
            raise self.error("tick", f"expected the tick timeline as int64, got {kind}")
        ticks: list[int | None] = self.batch.column("tick").to_pylist()
        for tick in ticks:
            if tick is not None and not 0 <= tick <= MAX_TICK:
                raise self.error("tick", f"expected a tick in 0..{MAX_TICK}, got {tick}")
        return ticks

    def seconds(self, name: str = "time") -> list[float | None]:
        """A duration timeline in seconds (``[]`` when the chunk lacks it)."""
        kind = self._type(name)
        if kind is None:
            return []
        if not pa.types.is_duration(kind):
            raise self.error(name, f"expected the {name} timeline as a duration, got {kind}")
        nanos = self.batch.column(name).cast("int64").to_pylist()
        return [None if n is None else n / 1e9 for n in nanos]

    def row_ids(self) -> list[bytes]:
        """Rerun's row ids (TUIDs: in logging order)."""
        name = "rerun.controls.RowId"
        kind = self._type(name)
        if kind is None or not (pa.types.is_fixed_size_binary(kind) and kind.byte_width == 16):
            raise self.error(name, f"expected rerun's 16-byte row ids, got {kind}")
        ids: list[bytes] = self.batch.column(name).to_pylist()
        return ids

    def lists(
        self, name: str, item: Any, sizes: Sequence[int], *, nan: bool = False
    ) -> list[list[Any] | None]:
        """The component ``name``, a list of ``item`` (float64, int64, string) per row with
        one of ``sizes`` values, as Python lists (``None`` where a row lacks it; ``[]``
        when the chunk lacks it). Floats are finite (``nan``: or NaN)."""
        kind = self._type(name)
        if kind is None:
            return []
        if not (pa.types.is_list(kind) and kind.value_type == item):
            raise self.error(name, f"expected a list of {_ITEM_NAMES[item]}, got {kind}")
        rows: list[list[Any] | None] = self.batch.column(name).to_pylist()
        for i, row in enumerate(rows):
            if row is None:
                continue
            if len(row) not in sizes:
                want = " or ".join(str(n) for n in sizes)
                noun = "value" if list(sizes) == [1] else "values"
                raise self.error(name, f"expected {want} {noun}, got {len(row)}", self.tick(i))
            if any(v is None for v in row):
                raise self.error(name, "expected values, got a null", self.tick(i))
            if item == _FLOAT and not all(math.isfinite(v) or (nan and v != v) for v in row):
                raise self.error(name, f"expected finite numbers, got {row!r}", self.tick(i))
        return rows

    def tick(self, row: int) -> int | None:
        """The tick of a row (to name it in an error)."""
        ticks = self.ticks()
        return ticks[row] if row < len(ticks) else None

    def column(
        self, name: str, item: Any, sizes: Sequence[int], *, nan: bool = False
    ) -> list[list[Any] | None]:
        """:meth:`lists`, with ``None`` for every row when the chunk lacks it."""
        return self.lists(name, item, sizes, nan=nan) or [None] * self.batch.num_rows


#: ``(device, inode, size, mtime, entities)`` -> the batches read (the last few reads: the
#: replay reads each stage's data from the same file in turn).
_READ: dict[tuple[Any, ...], list[_Batch]] = {}
_READ_KEEP = 8


def _check_path(path: Path) -> os.stat_result:
    source = str(path)
    if os.path.islink(path) and not os.path.exists(path):
        raise InputError(
            f"is a link to {os.path.realpath(path)}, which does not exist", source=source
        )
    try:
        return regular_file(path, "recording")
    except InputError as err:
        if not path.exists():
            raise InputError("no such file", source=source) from None
        if path.is_dir():
            raise InputError(
                "expected a rerun recording (.rrd), got a folder", source=source
            ) from None
        raise InputError(f"{err}; expected a rerun recording (.rrd)") from None


def _batches(path: Path, *entities: str) -> list[_Batch]:
    """Every chunk of the given entities (all if none) as an Arrow record batch."""
    source = str(path)
    st = _check_path(path)
    rrd_file.check_readable(path)
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, entities)
    if key in _READ:
        return _READ[key]
    captured = rrd_file.Captured()
    try:
        with rrd_file.quiet_stderr() as captured:
            stream = RrdReader(path).stream()
            if entities:
                stream = stream.filter(content=["/" + e for e in entities])
            batches = [
                _Batch(source, c.entity_path.lstrip("/"), c.is_static, c.to_record_batch())
                for c in stream.to_chunks()
            ]
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:  # RuntimeError, ValueError, OSError, or a Rust panic's
        text = " ".join(str(exc).split())
        reason = text.split(": ", 1)[-1] if source in text else text
        reason = reason or captured.reason or type(exc).__name__
        raise InputError(
            f"not a readable rerun recording (.rrd): {reason}", source=source
        ) from None
    while len(_READ) >= _READ_KEEP:
        del _READ[next(iter(_READ))]
    _READ[key] = batches
    return batches


def entity_paths(path: Path | str) -> set[str]:
    """Entity paths of a recording, without the leading ``/`` and rerun's ``__`` entries."""
    return {b.entity for b in _batches(Path(path)) if b.entity and not b.entity.startswith("__")}


def read_stages(path: Path | str) -> list[Stage]:
    """Every stage of a recording, by index.

    Raises:
        InputError: the file is missing, not an ``.rrd`` or damaged, holds no legws
            telemetry, or a stage document that does not validate (naming the field).
    """
    p = Path(path)
    docs: dict[int, tuple[StageDoc, dict[str, Any], str]] = {}
    for batch in _batches(p, GOALS_DOC, STAGES_DOC):
        texts = batch.column("TextDocument:text", _TEXT, (0, 1))
        ticks = batch.ticks() or [None] * len(texts)
        for text, tick in zip(texts, ticks, strict=True):
            if text:
                where = f"{p}: {batch.entity}" + ("" if tick is None else f" (tick {tick})")
                doc, data = parse_stage_doc(text[0], where, TELEMETRY_FORMAT)
                docs[doc.stage_index] = (doc, data, where)
    if not docs:
        raise InputError(f"no legws telemetry ({GOALS_DOC}) in the recording", source=str(p))
    return [_stage(*docs[i]) for i in sorted(docs)]


def _stage(doc: StageDoc, data: dict[str, Any], where: str) -> Stage:
    source = f"{where} stage {doc.stage_index}"
    goals: GoalSet | None = None
    try:
        if doc.inference:
            goals, params = goalset_from_data(data, source)
            candidates = goals.names
        else:  # a decision without inference: its candidates' names and the parameters
            assert doc.candidates is not None  # StageDoc requires them
            candidates = tuple(doc.candidates)
            params = params_from_schema(doc.params, source)
    except InputError as err:
        raise one_line(err) from None
    return Stage(
        index=doc.stage_index,
        name=doc.stage,
        goals=goals,
        params=params,
        p_thresh=params.p_thresh if doc.p_thresh is None else doc.p_thresh,
        scene=doc.scene,
        robot=doc.robot,
        goal_objects=dict(doc.goal_objects),
        candidates=tuple(candidates),
    )


def stage_labels(names: Sequence[str | None]) -> list[str]:
    """A label per stage that names it alone: its name, or ``NAME#K`` (the K-th stage of
    that name, from 1) where a name repeats (a task graph's stages run again); an unnamed
    stage is its index."""
    counts: dict[str, int] = {}
    for name in names:
        if name is not None:
            counts[name] = counts.get(name, 0) + 1
    seen: dict[str, int] = {}
    labels = []
    for i, name in enumerate(names):
        if name is None:
            labels.append(str(i))
            continue
        seen[name] = seen.get(name, 0) + 1
        labels.append(name if counts[name] == 1 else f"{name}#{seen[name]}")
    return labels


def select_index(names: Sequence[str | None], key: int | str, source: str) -> int:
    """The index of the stage ``key`` addresses among stages named ``names``.

    ``key``: an index (negative from the end, also as text), a label of
    :func:`stage_labels` (``sort#2``), ``NAME#K`` for any name, or a name that only one
    stage has. A name several stages have is refused in one line that lists them.
    """
    n = len(names)
    if isinstance(key, str):
        labels = stage_labels(names)
        if key in labels:
            return labels.index(key)
        named = [i for i, name in enumerate(names) if name == key]
        if len(named) > 1:
            choices = ", ".join(f"{i}={labels[i]}" for i in named)
            raise InputError(
                f"{len(named)} stages are named '{key}' ({choices}): give the index or NAME#K",
                source=source,
                field="stage",
            )
        name, _, k = key.rpartition("#")
        of_name = [i for i, other in enumerate(names) if other == name]
        if name and k.isdigit() and of_name:
            if 1 <= int(k) <= len(of_name):
                return of_name[int(k) - 1]
            raise InputError(
                f"no stage '{key}': {len(of_name)} stage(s) named '{name}' (#1..#{len(of_name)})",
                source=source,
                field="stage",
            )
        if not key.lstrip("-").isdigit():
            known = ", ".join(f"{i}={label}" for i, label in enumerate(labels))
            raise InputError(
                f"no stage is named '{key}'; stages: {known}", source=source, field="stage"
            )
        key = int(key)
    if -n <= key < n:
        return key % n
    raise InputError(
        f"no stage {key}; the recording has {n} (0..{n - 1})", source=source, field="stage"
    )


def select_stage(stages: list[Stage], stage: StageKey, source: str) -> Stage:
    """The stage ``stage`` addresses (:func:`select_index`; ``None``: the last one)."""
    if stage is None:
        return stages[-1]
    return stages[select_index([s.name for s in stages], stage, source)]


def read_goals(path: Path | str, stage: StageKey = None) -> GoalSet:
    """The goal set of a stage (default: the last one, as the viewer shows it).

    Raises:
        InputError: the stage has a single candidate (no goal set).
    """
    chosen = select_stage(read_stages(path), stage, str(path))
    if chosen.goals is None:
        raise InputError(
            f"stage {chosen.index} ({chosen.name}) has a single candidate, no goal set",
            source=str(path),
            field="stage",
        )
    return chosen.goals


def read_params(path: Path | str, stage: StageKey = None) -> Params:
    """The parameters of a stage (default: the last one)."""
    return select_stage(read_stages(path), stage, str(path)).params


def _stage_index(path: Path, stage: StageKey) -> int | None:
    if stage is None:
        return None
    return select_stage(read_stages(path), stage, str(path)).index


class _EeRow(NamedTuple):
    """One EE sample as recorded (``None``: the chunk lacks the component)."""

    tick: int
    stage: int
    t: float | None
    position: list[float] | None
    quaternion: list[float] | None
    deflection: list[float] | None
    mode: str | None


def _ee_rows(path: Path) -> list[_EeRow]:
    """Every EE sample of ``world/ee`` with a tick and a stage, each value validated: a
    position in the cell, a quaternion of a non-zero norm, finite times and deflections, a
    stage index in -1..MAX_STAGE, a mode's name."""
    rows: list[_EeRow] = []
    for batch in _batches(path, EE_PATH):
        if batch.static:
            continue
        ticks = batch.ticks()
        if not ticks:
            continue
        a = EE_ARCHETYPE
        stages = batch.column(f"{a}:stage", _INT, (1,))
        positions = batch.column(f"{a}:position", _FLOAT, (3,))
        quaternions = batch.column(f"{a}:quaternion", _FLOAT, (4,))
        times = batch.column(f"{a}:t", _FLOAT, (1,))
        deflections = batch.column(f"{a}:deflection", _FLOAT, (0, 3))
        modes = batch.column(f"{a}:mode", _TEXT, (1,))
        for tick, st, pos, quat, t, u, mode in zip(
            ticks, stages, positions, quaternions, times, deflections, modes, strict=True
        ):
            if tick is None or st is None:
                continue
            _check_ee(batch, tick, st[0], pos, quat, u, mode)
            rows.append(
                _EeRow(tick, st[0], None if t is None else t[0], pos, quat, u,
                       None if mode is None else mode[0])
            )  # fmt: skip
    return rows


def _check_ee(
    batch: _Batch,
    tick: int,
    stage: int,
    pos: list[float] | None,
    quat: list[float] | None,
    u: list[float] | None,
    mode: list[str] | None,
) -> None:
    a = EE_ARCHETYPE
    if not -1 <= stage <= MAX_STAGE:
        raise batch.error(f"{a}:stage", f"expected a stage index in -1..{MAX_STAGE}, got {stage}",
                          tick)  # fmt: skip
    if pos is not None and not (
        abs(pos[0]) <= CELL_XY and abs(pos[1]) <= CELL_XY and CELL_Z[0] <= pos[2] <= CELL_Z[1]
    ):
        raise batch.error(
            f"{a}:position",
            f"expected a position in the cell (|x|, |y| <= {CELL_XY:g} m, {CELL_Z[0]:g} <= z "
            f"<= {CELL_Z[1]:g} m), got {pos!r}",
            tick,
        )
    if quat is not None and not 1e-9 <= math.hypot(*quat) <= MAX_QUATERNION_NORM:
        raise batch.error(f"{a}:quaternion", f"expected a non-zero quaternion, got {quat!r}",
                          tick)  # fmt: skip
    if u is not None and any(abs(v) > _MAX_VALUE for v in u):
        raise batch.error(f"{a}:deflection", f"expected values within +-{_MAX_VALUE:g}, got "
                          f"{u!r}", tick)  # fmt: skip
    if mode is not None:
        _check_name(batch, f"{a}:mode", mode[0], tick)


def _check_name(batch: _Batch, name: str, text: str, tick: int | None) -> None:
    if not 1 <= len(text) <= _MAX_NAME or unsafe_character(text) is not None:
        shown = printable(text if len(text) <= 40 else text[:37] + "...")
        raise batch.error(name, f"expected a name of 1 to {_MAX_NAME} printable characters, "
                          f"got {shown!r}", tick)  # fmt: skip


def read_ee_path(path: Path | str, stage: StageKey = None) -> EePath:
    """The exact (float64) EE poses of every tick, of one stage or all, ordered by tick.

    Returns:
        ticks ``(K,)``, times ``(K,)`` in seconds, positions ``(K, 3)`` and quaternions
        ``(K, 4)`` ``[w, x, y, z]``.
    """
    p = Path(path)
    want = _stage_index(p, stage)
    rows = [
        r
        for r in _ee_rows(p)
        if r.position is not None
        and r.quaternion is not None
        and r.t is not None
        and (want is None or r.stage == want)
    ]
    rows.sort(key=lambda r: (r.stage, r.tick))
    return EePath(
        np.array([r.tick for r in rows], dtype=np.int64),
        np.array([r.t for r in rows], dtype=np.float64),
        np.array([r.position for r in rows], dtype=np.float64).reshape(-1, 3),
        np.array([r.quaternion for r in rows], dtype=np.float64).reshape(-1, 4),
    )


class Teleoperation(NamedTuple):
    """Every tick's EE position with the deflection that reached the controller and the
    mode, ordered by tick (recordings from before these were logged have none: empty).

    Attributes:
        ticks, stages: ``(K,)`` the tick and the stage index it was logged in.
        positions: ``(K, 3)``.
        deflections: ``(K, 3)``; ``NaN`` on a tick without input (deadman).
        modes: the controller's mode at each tick.
    """

    ticks: IntArray
    stages: IntArray
    positions: FloatArray
    deflections: FloatArray
    modes: tuple[str, ...]


def read_teleoperation(path: Path | str) -> Teleoperation:
    """:class:`Teleoperation` of a recording (what ``legws operator trace`` reads)."""
    rows = [
        r
        for r in _ee_rows(Path(path))
        if r.position is not None and r.mode is not None and r.deflection is not None
    ]
    rows.sort(key=lambda r: (r.tick, r.stage))
    return Teleoperation(
        np.array([r.tick for r in rows], dtype=np.int64),
        np.array([r.stage for r in rows], dtype=np.int64),
        np.array([r.position for r in rows], dtype=np.float64).reshape(-1, 3),
        np.array(
            [r.deflection if r.deflection else [math.nan] * 3 for r in rows], dtype=np.float64
        ).reshape(-1, 3),
        tuple(r.mode or "" for r in rows),
    )


class _TextRow(NamedTuple):
    tick: int
    row_id: bytes
    seconds: float | None
    level: str
    text: str
    stage: int | None


def _text_log(path: Path) -> list[_TextRow]:
    """Every row of the ``log`` entity with a tick and a text, in logging order (by tick,
    then row id: TUIDs are in logging order), each validated: a text of at most
    :data:`MAX_ROW` characters without control characters, a level's name, a stage index."""
    rows: list[_TextRow] = []
    for batch in _batches(path, TEXT_LOG):
        if batch.static:
            continue
        ticks = batch.ticks()
        texts = batch.lists("TextLog:text", _TEXT, (0, 1))
        if not ticks or not texts:
            continue
        row_ids = batch.row_ids()
        times = batch.seconds() or [None] * len(ticks)
        levels = batch.column("TextLog:level", _TEXT, (0, 1))
        stages = batch.column(f"{STAGE_ARCHETYPE}:stage", _INT, (0, 1))
        for tick, row_id, t, level, text, st in zip(
            ticks, row_ids, times, levels, texts, stages, strict=True
        ):
            if tick is None or not text:
                continue
            _check_row(batch, tick, text[0])
            if level:
                _check_name(batch, "TextLog:level", level[0], tick)
            stage = st[0] if st else None
            if stage is not None and not -1 <= stage <= MAX_STAGE:
                raise batch.error(f"{STAGE_ARCHETYPE}:stage", f"expected a stage index in "
                                  f"-1..{MAX_STAGE}, got {stage}", tick)  # fmt: skip
            rows.append(_TextRow(tick, row_id, t, level[0] if level else "", text[0], stage))
    rows.sort(key=lambda r: (r.tick, r.row_id))
    return rows


def _check_row(batch: _Batch, tick: int, text: str) -> None:
    if len(text) > MAX_ROW:
        raise batch.error("TextLog:text", f"a row of {len(text)} characters, more than "
                          f"{MAX_ROW}", tick)  # fmt: skip
    bad = unsafe_character(text)
    if bad is not None:
        raise batch.error(
            "TextLog:text",
            f"holds the control character U+{ord(bad):04X}; text may not hold control or "
            "bidirectional characters",
            tick,
        )


def read_text_lines(path: Path | str) -> list[tuple[int, int | None, str]]:
    """``(tick, stage index, text)`` of every row of the ``log`` entity, in logging order."""
    return [(r.tick, r.stage, r.text) for r in _text_log(Path(path))]


def _text_rows(path: Path, stage: StageKey) -> list[tuple[int, float | None, str, str]]:
    """``(tick, seconds, level, text)`` of the ``log`` entity, in logging order."""
    want = _stage_index(path, stage)
    return [
        (r.tick, r.seconds, r.level, r.text)
        for r in _text_log(path)
        if want is None or r.stage == want
    ]


def read_text_log(path: Path | str, stage: StageKey = None) -> list[tuple[int, str, str]]:
    """``(tick, level, text)`` of the ``log`` entity, in logging order (stable by tick)."""
    return [(tick, level, text) for tick, _, level, text in _text_rows(Path(path), stage)]


def read_commits(path: Path | str, stage: StageKey = None) -> list[tuple[int, str, float]]:
    """``(tick, goal, p)`` of the ``commit goal=<name> p=<prob>`` lines of the text log."""
    return [(c.tick, c.goal, c.p) for c in read_recorded_commits(path, stage)]


def read_recorded_commits(path: Path | str, stage: StageKey = None) -> list[RecordedCommit]:
    """Every commit line of the text log with its time and how it came, in logging order
    (its goal a name, its ``p`` in [0, 1]: :class:`~.recording_doc.CommitRow`)."""
    p = Path(path)
    out = []
    for tick, t, _, text in _text_rows(p, stage):
        commit = parse_commit(text)
        if commit is not None:
            row = commit_row(commit.goal, commit.p, commit.how, f"{p}: {TEXT_LOG} (tick {tick})")
            out.append(RecordedCommit(tick, t, row.goal, row.p, row.how))
    return out


def read_posterior(path: Path | str, stage: StageKey = None) -> Posterior:
    """The posterior the daemon plotted (``plots/posterior/<goal>``), of one stage or all.

    For a stage: its goals, at the ticks the stage spans (its first EE tick up to the
    next stage's first EE tick; a stage without EE samples spans none). For ``None``:
    the goals of every stage (in order of first appearance) at every tick. A tick where
    the daemon was not inferring has no row: no value, or a ``NaN`` (which ends a line in
    the viewer), is not a value. A value is a probability, in [0, 1].
    """
    p = Path(path)
    stages = read_stages(p)
    chosen = stages if stage is None else [select_stage(stages, stage, str(p))]
    goals = tuple(dict.fromkeys(g for s in chosen if s.goals for g in s.goals.names))
    column = {
        "/" + POSTERIOR_PREFIX + rr.escape_entity_path_part(g): j for j, g in enumerate(goals)
    }
    firsts: dict[int, int] = {}
    for row in _ee_rows(p):
        if row.stage >= 0:
            firsts[row.stage] = min(row.tick, firsts.get(row.stage, row.tick))
    values: dict[int, dict[int, float]] = {}
    times: dict[int, float] = {}
    for batch in _batches(p, POSTERIOR_PREFIX + "**"):
        j = column.get("/" + batch.entity)
        if batch.static or j is None:
            continue
        ticks = batch.ticks()
        scalars = batch.lists("Scalars:scalars", _FLOAT, (0, 1), nan=True)
        if not ticks or not scalars:
            continue
        seconds = batch.seconds() or [None] * len(ticks)
        for tick, t, scalar in zip(ticks, seconds, scalars, strict=True):
            if tick is None or not scalar or math.isnan(scalar[0]):
                continue
            if not 0.0 <= scalar[0] <= 1.0:
                raise batch.error("Scalars:scalars", f"expected a probability in [0, 1], got "
                                  f"{scalar[0]!r}", tick)  # fmt: skip
            values.setdefault(tick, {})[j] = float(scalar[0])
            if t is not None:
                times[tick] = t
    if stage is not None:
        lo, hi = _span(firsts, chosen[0].index)
        values = {t: v for t, v in values.items() if lo <= t < hi}
    ticks_sorted = sorted(values)
    table = np.full((len(ticks_sorted), len(goals)), np.nan)
    for i, tick in enumerate(ticks_sorted):
        for j, v in values[tick].items():
            table[i, j] = v
    return Posterior(
        goals,
        np.array(ticks_sorted, dtype=np.int64),
        np.array([times.get(t, np.nan) for t in ticks_sorted], dtype=np.float64),
        table,
    )


def _span(firsts: dict[int, int], index: int) -> tuple[float, float]:
    """The ticks ``[lo, hi)`` stage ``index`` spans (empty without EE samples)."""
    if index not in firsts:
        return (0.0, 0.0)
    later = [t for i, t in firsts.items() if i > index]
    return (float(firsts[index]), float(min(later)) if later else math.inf)
