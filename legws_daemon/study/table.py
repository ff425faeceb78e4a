"""The trial table: one row per trial (practice included), the data a lab publishes.

:data:`COLUMNS` is the data dictionary: each column's name, type, unit and meaning, written
beside the table (``data_dictionary.md`` and ``.json``) so the files explain themselves.
Written as CSV and Parquet (pyarrow, the schema typed from the dictionary).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from legws_daemon.errors import InputError
from legws_daemon.formats.files import write_atomic
from legws_daemon.study.protocol import NASA_TLX

Kind = Literal["string", "int", "float", "bool"]


@dataclass(frozen=True, slots=True)
class Column:
    name: str
    kind: Kind
    unit: str
    meaning: str


#: The trial table's columns (questionnaire columns follow: ``tlx_<subscale>``, ``tlx_raw``
#: and ``likert_<k>``, see :func:`questionnaire_columns`).
COLUMNS: tuple[Column, ...] = (
    Column("participant", "string", "", "the participant's pseudonym (P01, ...)"),
    Column("protocol", "string", "", "the study protocol's name"),
    Column("protocol_sha256", "string", "", "the hash of the protocol file's text"),
    Column("index", "int", "", "the step's place in the participant's session (schedule.csv)"),
    Column("kind", "string", "", "practice or trial"),
    Column("condition", "string", "", "the condition (empty: the first practice trials)"),
    Column("position", "int", "", "the condition's place in the participant's order, 1-based"),
    Column("trial", "int", "", "the trial's number within its condition (practice apart)"),
    Column("task", "string", "", "the protocol's task"),
    Column("source", "string", "", "the scene or task graph it runs"),
    Column("assist", "string", "", "the assistance policy: commit, blend, hindsight, none"),
    Column("layout_source", "string", "", "shipped, random, optimised, optimised_for_operator"),
    Column("layout_origin", "string", "", "the random seed, or the optimisation run or plan"),
    Column("layout", "string", "m, m, rad", "the starting layout, JSON {object: [x, y, yaw]}"),
    Column("goal", "string", "", "the first object the participant was asked for"),
    Column("targets", "string", "", "every object asked for, in order, joined by ';'"),
    Column("chosen", "string", "", "the objects the robot acted on at each choice, ';'"),
    Column("decisions", "int", "", "decisions with inference (two or more candidates)"),
    Column("slack_j", "float", "", "J of the layout (method.md §4), the weakest decision"),
    Column("commit_k", "float", "", "K of the layout (method.md §9, exact sum), the largest"),
    Column("person_slack_j", "float", "", "J for the participant's operator model (§10)"),
    Column("person_commit_k", "float", "", "K for the participant's operator model (§10)"),
    Column("commit_time_s", "float", "s", "mean over choices of the first push to the commit"),
    Column("correct", "bool", "", "the robot acted on every object asked for, no other"),
    Column("wrong", "int", "", "choices acted on (or grasped) that were not asked for"),
    Column("confirms", "int", "", "choices the participant confirmed (no commit before)"),
    Column("cancels", "int", "", "cancels (the button, or the stick held against)"),
    Column("overrides", "int", "", "overrides of the robot's motion (docs/daemon.md)"),
    Column("time_to_grasp_s", "float", "s", "trial start to the gripper first closing"),
    Column("time_to_task_s", "float", "s", "trial start to the task done (a pick: lifted)"),
    Column("effort_s", "float", "s", "the participant's effort, the integral of |u| dt"),
    Column("completed", "bool", "", "the trial's task was done"),
    Column("failure", "string", "", "why not (empty when completed)"),
    Column("hesitation_s", "float", "s", "time before the first push"),
    Column("recording", "string", "", "the trial's Rerun recording, relative to the folder"),
    Column(
        "frames",
        "string",
        "",
        "the trial's per-tick frames (Parquet), relative to the participant's folder",
    ),
)


def questionnaire_columns(likert_items: int) -> tuple[Column, ...]:
    """The questionnaire's columns: the six raw NASA-TLX subscales, their mean, the Likert
    items (answers of the questionnaire after the trial's condition)."""
    out = [
        Column(f"tlx_{key}", "float", "0-100", f"NASA-TLX {text.split(':')[0].lower()}")
        for key, text in NASA_TLX
    ]
    out.append(Column("tlx_raw", "float", "0-100", "raw TLX: the mean of the six subscales"))
    out += [
        Column(f"likert_{k}", "int", "points", f"Likert item {k} (the protocol's order)")
        for k in range(1, likert_items + 1)
    ]
    return tuple(out)


def columns(likert_items: int) -> tuple[Column, ...]:
    return COLUMNS + questionnaire_columns(likert_items)


def _cell(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def csv_text(rows: Sequence[Mapping[str, Any]], cols: Sequence[Column]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=[c.name for c in cols], lineterminator="\n")
    writer.writeheader()
    for row in rows:
        out = {}
        for c in cols:
            v = _cell(row.get(c.name))
            out[c.name] = "" if v is None else (str(v).lower() if c.kind == "bool" else v)
        writer.writerow(out)
    return buf.getvalue()


def write_table(folder: Path, stem: str, rows: Sequence[Mapping[str, Any]], likert: int) -> None:
    """``folder/stem.csv`` and ``folder/stem.parquet`` of ``rows``."""
    import pyarrow as pa  # type: ignore[import-untyped]
    import pyarrow.parquet as pq  # type: ignore[import-untyped]

    cols = columns(likert)
    unknown = {k for row in rows for k in row} - {c.name for c in cols}
    if unknown:
        raise InputError(f"trial rows with unknown columns: {sorted(unknown)}", field=stem)
    write_atomic(folder / f"{stem}.csv", csv_text(rows, cols).encode())
    types = {"string": pa.string(), "int": pa.int64(), "float": pa.float64(), "bool": pa.bool_()}
    schema = pa.schema(
        [pa.field(c.name, types[c.kind], metadata={"unit": c.unit, "meaning": c.meaning})
         for c in cols]
    )  # fmt: skip
    data = {c.name: [_cell(row.get(c.name)) for row in rows] for c in cols}
    table = pa.Table.from_pydict(data, schema=schema)
    buf = pa.BufferOutputStream()
    pq.write_table(table, buf)
    write_atomic(folder / f"{stem}.parquet", buf.getvalue().to_pybytes())


def read_table(path: Path) -> list[dict[str, Any]]:
    """The rows of a trial table's Parquet file."""
    import pyarrow.parquet as pq

    from legws_daemon.formats.files import regular_file

    regular_file(path, "study table")
    try:
        return list(pq.read_table(path).to_pylist())
    except Exception as err:  # pyarrow's errors have no common base beyond ArrowException
        raise InputError(f"not a readable Parquet table: {err}", source=str(path)) from None


def write_dictionary(folder: Path, likert_texts: Sequence[str]) -> None:
    """``data_dictionary.md`` and ``data_dictionary.json``: every column's meaning."""
    cols = columns(len(likert_texts))
    texts = dict(
        zip((f"likert_{k}" for k in range(1, len(likert_texts) + 1)), likert_texts, strict=True)
    )
    entries = [
        {"name": c.name, "type": c.kind, "unit": c.unit,
         "meaning": f"{c.meaning}: {texts[c.name]}" if c.name in texts else c.meaning}
        for c in cols
    ]  # fmt: skip
    lines = ["# Data dictionary: the trial table", "",
             "One row per trial (practice included); `trials.csv` and `trials.parquet` hold the "
             "same rows. Empty cells: not measured (no commit, no grasp).", "",
             "| column | type | unit | meaning |", "|---|---|---|---|"]  # fmt: skip
    lines += [f"| `{e['name']}` | {e['type']} | {e['unit']} | {e['meaning']} |" for e in entries]
    write_atomic(folder / "data_dictionary.md", ("\n".join(lines) + "\n").encode())
    write_atomic(folder / "data_dictionary.json", (json.dumps(entries, indent=1) + "\n").encode())
