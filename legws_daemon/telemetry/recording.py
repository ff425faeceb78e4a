"""Reading a daemon recording (``.rrd`` written by :class:`~.rerun_log.RerunLog`) headless.

Uses :class:`rerun.chunk.RrdReader`: no viewer, no server. Every error (missing file, not
an ``.rrd``, no legws telemetry in it) is an :class:`InputError` naming the file.

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

import json
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import rerun as rr
from rerun.chunk import RrdReader

from legws_daemon.core.geometry import FloatArray, IntArray
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.goalset import ParamsSchema, goalset_from_data, params_from_schema
from legws_daemon.formats.log_lines import How
from legws_daemon.formats.log_lines import parse_commit as parse_commit
from legws_daemon.formats.validation import validate
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


class _Batch(NamedTuple):
    entity: str  # without the leading "/"
    static: bool
    batch: Any  # pyarrow.RecordBatch

    def column(self, name: str) -> list[Any]:
        """The column as Python values, or ``[]`` when the chunk lacks it."""
        index = self.batch.schema.get_field_index(name)
        return [] if index < 0 else list(self.batch.column(index).to_pylist())

    def seconds(self, name: str = "time") -> list[float | None]:
        """A duration timeline in seconds (``[]`` when the chunk lacks it)."""
        index = self.batch.schema.get_field_index(name)
        if index < 0:
            return []
        nanos = self.batch.column(index).cast("int64").to_pylist()
        return [None if n is None else n / 1e9 for n in nanos]


def _batches(path: Path, *entities: str) -> list[_Batch]:
    """Every chunk of the given entities (all if none) as an Arrow record batch."""
    source = str(path)
    if not path.exists():
        raise InputError("no such file", source=source)
    if not path.is_file():
        raise InputError("expected a rerun recording (.rrd), got a folder", source=source)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer": a recording that was cut short
            stream = RrdReader(path).stream()
            if entities:
                stream = stream.filter(content=["/" + e for e in entities])
            chunks = stream.to_chunks()
    except (RuntimeError, ValueError, OSError) as exc:
        reason = str(exc).split(": ", 1)[-1] if source in str(exc) else str(exc)
        raise InputError(
            f"not a readable rerun recording (.rrd): {reason}", source=source
        ) from None
    return [_Batch(c.entity_path.lstrip("/"), c.is_static, c.to_record_batch()) for c in chunks]


def entity_paths(path: Path | str) -> set[str]:
    """Entity paths of a recording, without the leading ``/`` and rerun's ``__`` entries."""
    return {b.entity for b in _batches(Path(path)) if b.entity and not b.entity.startswith("__")}


def read_stages(path: Path | str) -> list[Stage]:
    """Every stage of a recording, by index.

    Raises:
        InputError: the file is missing or not an ``.rrd``, or holds no legws telemetry.
    """
    p = Path(path)
    docs: dict[int, dict[str, Any]] = {}
    for batch in _batches(p, GOALS_DOC, STAGES_DOC):
        for text in batch.column("TextDocument:text"):
            if text:
                doc = _parse_doc(text[0], p)
                docs[doc["stage_index"]] = doc
    if not docs:
        raise InputError(f"no legws telemetry ({GOALS_DOC}) in the recording", source=str(p))
    return [_stage(docs[i], p) for i in sorted(docs)]


def _parse_doc(text: str, path: Path) -> dict[str, Any]:
    where = {"source": str(path), "field": GOALS_DOC}
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise InputError(f"not legws telemetry (not JSON: {exc})", **where) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("stage_index"), int):
        raise InputError("not legws telemetry (no stage_index)", **where)
    version = doc.get("legws_telemetry")
    if not isinstance(version, int) or version > TELEMETRY_FORMAT:
        raise InputError(
            f"telemetry format {version!r} is not supported (this legws reads up to "
            f"{TELEMETRY_FORMAT})",
            **where,
        )
    return doc


def _stage(doc: dict[str, Any], path: Path) -> Stage:
    source = f"{path} ({GOALS_DOC} stage {doc['stage_index']})"
    goals: GoalSet | None = None
    if doc.get("inference", True):
        goals, params = goalset_from_data(doc, source)
        candidates = goals.names
    else:  # a decision without inference: its candidates' names and the parameters
        names = doc.get("candidates")
        if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
            raise InputError("expected the candidates' names", source=source, field="candidates")
        candidates = tuple(names)
        schema = validate(ParamsSchema, doc.get("params") or {}, source)
        params = params_from_schema(schema, source)
    objects = doc.get("goal_objects") or {}
    return Stage(
        index=doc["stage_index"],
        name=doc.get("stage"),
        goals=goals,
        params=params,
        p_thresh=float(doc.get("p_thresh", params.p_thresh)),
        scene=doc.get("scene"),
        robot=doc.get("robot"),
        goal_objects={str(k): str(v) for k, v in objects.items()},
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


def read_ee_path(path: Path | str, stage: StageKey = None) -> EePath:
    """The exact (float64) EE poses of every tick, of one stage or all, ordered by tick.

    Returns:
        ticks ``(K,)``, times ``(K,)`` in seconds, positions ``(K, 3)`` and quaternions
        ``(K, 4)`` ``[w, x, y, z]``.
    """
    p = Path(path)
    want = _stage_index(p, stage)
    rows: list[tuple[int, int, float, list[float], list[float]]] = []
    for batch in _batches(p, EE_PATH):
        if batch.static:
            continue
        ticks = batch.column("tick")
        fields = [batch.column(f"{EE_ARCHETYPE}:{n}") for n in ("position", "quaternion", "t")]
        stages = batch.column(f"{EE_ARCHETYPE}:stage")
        if not ticks or not stages or not all(fields):
            continue
        for tick, pos, quat, t, st in zip(ticks, *fields, stages, strict=True):
            if tick is None or not (pos and quat and t and st):
                continue
            if want is None or st[0] == want:
                rows.append((st[0], tick, t[0], pos, quat))
    rows.sort(key=lambda r: (r[0], r[1]))
    return EePath(
        np.array([r[1] for r in rows], dtype=np.int64),
        np.array([r[2] for r in rows], dtype=np.float64),
        np.array([r[3] for r in rows], dtype=np.float64).reshape(-1, 3),
        np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, 4),
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
    p = Path(path)
    rows: list[tuple[int, int, list[float], list[float], str]] = []
    for batch in _batches(p, EE_PATH):
        if batch.static:
            continue
        ticks = batch.column("tick")
        positions = batch.column(f"{EE_ARCHETYPE}:position")
        stages = batch.column(f"{EE_ARCHETYPE}:stage")
        deflections = batch.column(f"{EE_ARCHETYPE}:deflection")
        modes = batch.column(f"{EE_ARCHETYPE}:mode")
        if not (ticks and positions and stages and deflections and modes):
            continue
        for tick, pos, st, u, mode in zip(
            ticks, positions, stages, deflections, modes, strict=True
        ):
            if tick is None or not (pos and st and mode) or u is None:
                continue
            deflection = list(u) if len(u) == 3 else [math.nan] * 3
            rows.append((tick, st[0], list(pos), deflection, str(mode[0])))
    rows.sort(key=lambda r: (r[0], r[1]))
    return Teleoperation(
        np.array([r[0] for r in rows], dtype=np.int64),
        np.array([r[1] for r in rows], dtype=np.int64),
        np.array([r[2] for r in rows], dtype=np.float64).reshape(-1, 3),
        np.array([r[3] for r in rows], dtype=np.float64).reshape(-1, 3),
        tuple(r[4] for r in rows),
    )


def read_text_lines(path: Path | str) -> list[tuple[int, int | None, str]]:
    """``(tick, stage index, text)`` of every row of the ``log`` entity, in logging order."""
    p = Path(path)
    rows: list[tuple[int, bytes, int | None, str]] = []
    for batch in _batches(p, TEXT_LOG):
        ticks, texts = batch.column("tick"), batch.column("TextLog:text")
        if batch.static or not ticks or not texts:
            continue
        row_ids = batch.column("rerun.controls.RowId")
        stages = batch.column(f"{STAGE_ARCHETYPE}:stage") or [None] * len(ticks)
        for tick, row_id, text, st in zip(ticks, row_ids, texts, stages, strict=True):
            if tick is not None and text:
                rows.append((tick, row_id, st[0] if st else None, text[0]))
    rows.sort(key=lambda r: (r[0], r[1]))
    return [(tick, st, text) for tick, _, st, text in rows]


def _text_rows(path: Path, stage: StageKey) -> list[tuple[int, float | None, str, str]]:
    """``(tick, seconds, level, text)`` of the ``log`` entity, in logging order."""
    want = _stage_index(path, stage)
    rows: list[tuple[int, bytes, float | None, str, str]] = []
    for batch in _batches(path, TEXT_LOG):
        ticks, texts = batch.column("tick"), batch.column("TextLog:text")
        if batch.static or not ticks or not texts:
            continue
        row_ids = batch.column("rerun.controls.RowId")
        times = batch.seconds() or [None] * len(ticks)
        levels = batch.column("TextLog:level") or [None] * len(ticks)
        stages = batch.column(f"{STAGE_ARCHETYPE}:stage") or [None] * len(ticks)
        for tick, row_id, t, level, text, st in zip(
            ticks, row_ids, times, levels, texts, stages, strict=True
        ):
            if tick is None or not text or (want is not None and (not st or st[0] != want)):
                continue
            rows.append((tick, row_id, t, level[0] if level else "", text[0]))
    rows.sort(key=lambda r: (r[0], r[1]))  # row ids (TUIDs) are in logging order
    return [(tick, t, level, text) for tick, _, t, level, text in rows]


def read_text_log(path: Path | str, stage: StageKey = None) -> list[tuple[int, str, str]]:
    """``(tick, level, text)`` of the ``log`` entity, in logging order (stable by tick)."""
    return [(tick, level, text) for tick, _, level, text in _text_rows(Path(path), stage)]


def read_commits(path: Path | str, stage: StageKey = None) -> list[tuple[int, str, float]]:
    """``(tick, goal, p)`` of the ``commit goal=<name> p=<prob>`` lines of the text log."""
    return [(c.tick, c.goal, c.p) for c in read_recorded_commits(path, stage)]


def read_recorded_commits(path: Path | str, stage: StageKey = None) -> list[RecordedCommit]:
    """Every commit line of the text log with its time and how it came, in logging order."""
    out = []
    for tick, t, _, text in _text_rows(Path(path), stage):
        commit = parse_commit(text)
        if commit is not None:
            out.append(RecordedCommit(tick, t, commit.goal, commit.p, commit.how))
    return out


def read_posterior(path: Path | str, stage: StageKey = None) -> Posterior:
    """The posterior the daemon plotted (``plots/posterior/<goal>``), of one stage or all.

    For a stage: its goals, at the ticks the stage spans (its first EE tick up to the
    next stage's first EE tick; a stage without EE samples spans none). For ``None``:
    the goals of every stage (in order of first appearance) at every tick. A tick where
    the daemon was not inferring has no row: no value, or a ``NaN`` (which ends a line in
    the viewer), is not a value.
    """
    p = Path(path)
    stages = read_stages(p)
    chosen = stages if stage is None else [select_stage(stages, stage, str(p))]
    goals = tuple(dict.fromkeys(g for s in chosen if s.goals for g in s.goals.names))
    column = {
        "/" + POSTERIOR_PREFIX + rr.escape_entity_path_part(g): j for j, g in enumerate(goals)
    }
    firsts: dict[int, int] = {}
    values: dict[int, dict[int, float]] = {}
    times: dict[int, float] = {}
    for batch in _batches(p, EE_PATH, POSTERIOR_PREFIX + "**"):
        if batch.static:
            continue
        ticks = batch.column("tick")
        if batch.entity == EE_PATH:
            for tick, st in zip(ticks, batch.column(f"{EE_ARCHETYPE}:stage"), strict=False):
                if tick is not None and st and st[0] >= 0:
                    firsts[st[0]] = min(tick, firsts.get(st[0], tick))
            continue
        j = column.get("/" + batch.entity)
        scalars = batch.column("Scalars:scalars")
        if j is None or not ticks or not scalars:
            continue
        for tick, t, v in zip(ticks, batch.seconds() or [None] * len(ticks), scalars, strict=True):
            if tick is not None and v and v[0] is not None and math.isfinite(v[0]):
                values.setdefault(tick, {})[j] = float(v[0])
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
