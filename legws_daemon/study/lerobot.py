"""A study exported as a LeRobotDataset (format v3.0), written with pyarrow.

Every trial with frames (:mod:`.frames`; practice included, told apart by ``kind``) is one
episode, in the order of the study's trial table; every tick of it is one frame. The layout
is LeRobot's (``lerobot.datasets.utils`` of lerobot 0.4, the files a
``LeRobotDataset.create`` ... ``save_episode`` writes, byte for byte in their schemas):

- ``meta/info.json``: ``codebase_version`` ``"v3.0"``, the totals, the file templates and
  the features (:data:`FEATURES`: ``observation.state`` the EE position, ``action`` the
  joystick axes, and LeRobot's five index features);
- ``meta/stats.json``: per feature ``min``, ``max``, ``mean``, ``std``, ``count`` and the
  quantiles ``q01`` ... ``q99`` over every frame (exact, where LeRobot approximates them);
- ``meta/tasks.parquet``: the task strings (the pandas index LeRobot reads) and
  ``task_index``; a trial's task is ``"<task>: pick <object> then <object>"``;
- ``meta/episodes/chunk-000/file-000.parquet``: one row per episode, LeRobot's columns
  (``episode_index``, ``tasks``, ``length``, ``data/chunk_index``, ``data/file_index``,
  ``dataset_from_index``, ``dataset_to_index``, the episode's ``stats/<feature>/<stat>``,
  ``meta/episodes/chunk_index``, ``meta/episodes/file_index``), then the trial table's
  columns (:data:`~.table.COLUMNS`, ``index`` as ``step``, and the questionnaire's):
  pseudonym, condition, layout, certificates, measures, answers;
- ``data/chunk-CCC/file-FFF.parquet``: the frames, files of at most
  :data:`DATA_FILE_SIZE_IN_MB` (uncompressed), :data:`CHUNKS_SIZE` files a chunk.

:func:`check_lerobot` reads a dataset back and lists what does not hold together (the
features against the data's schema, the episodes' ranges against the rows, the totals).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_folder, regular_file, write_atomic
from legws_daemon.study.frames import Frames, read_frames
from legws_daemon.study.pseudonym import check_pseudonym
from legws_daemon.study.table import COLUMNS, Column, questionnaire_columns, read_table

CODEBASE_VERSION = "v3.0"
#: LeRobot's defaults: files a chunk folder, the data and video files' sizes (MB).
CHUNKS_SIZE = 1000
DATA_FILE_SIZE_IN_MB = 100
VIDEO_FILE_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
#: LeRobot's quantiles of the stats.
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
STATS = ("min", "max", "mean", "std", "count", *(f"q{round(q * 100):02d}" for q in QUANTILES))

FEATURES: dict[str, dict[str, Any]] = {
    "observation.state": {"dtype": "float32", "shape": [3], "names": ["ee_x", "ee_y", "ee_z"]},
    "action": {"dtype": "float32", "shape": [3], "names": ["axis_x", "axis_y", "axis_z"]},
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
#: The features of floating-point values (their min and max are floats, else integers).
_FLOATS = {name for name, f in FEATURES.items() if f["dtype"].startswith("float")}
#: Bytes of one frame in the data files, uncompressed (for the files' size).
FRAME_BYTES = 2 * 3 * 4 + 4 + 4 * 8
#: The trial table's columns in the episodes' metadata (``index``, the step, as ``step``).
STUDY_COLUMNS: tuple[Column, ...] = tuple(
    Column("step", c.kind, c.unit, c.meaning) if c.name == "index" else c for c in COLUMNS
)
_LAYOUT = re.compile(r"^(data|meta/episodes)/chunk-[0-9]{3,}/file-[0-9]{3,}\.parquet$")


@dataclass(frozen=True, slots=True)
class Episode:
    """One trial's episode: its row of the trial table, its frames, its task."""

    row: Mapping[str, Any]
    frames: Frames
    task: str


def task_text(row: Mapping[str, Any]) -> str:
    """The episode's task: ``"<task>: pick <object> then <object>"`` (the objects asked
    for), the task's name alone without any."""
    targets = [t for t in str(row.get("targets") or "").split(";") if t]
    return f"{row['task']}: pick {' then '.join(targets)}" if targets else str(row["task"])


# --- reading the study ---------------------------------------------------------------------
def _frames_file(study: Path, row: Mapping[str, Any]) -> Path:
    """The trial's frames file (its participant folder checked to be a pseudonym, the
    relative path to stay inside it)."""
    person = check_pseudonym(str(row["participant"]), field="participant")
    relative = PurePosixPath(str(row["frames"]))
    if relative.is_absolute() or ".." in relative.parts:
        raise InputError(
            f"expected a path inside the participant's folder, got '{relative}'",
            source=str(study / "trials.parquet"),
            field=f"frames ({person} step {row['index']})",
        )
    return study / person / relative


def load_episodes(study: Path, fps: int) -> list[Episode]:
    """The study's episodes: every row of ``study/trials.parquet`` with a frames file, in
    the table's order, each file read and checked to be at ``fps``."""
    rows = read_table(study / "trials.parquet")
    episodes = []
    for row in rows:
        if not row.get("frames"):
            continue
        path = _frames_file(study, row)
        if not path.exists():
            raise InputError(
                f"the frames file of {row['participant']} step {row['index']} is missing",
                source=str(path),
                field="frames",
            )
        frames = read_frames(path)
        if not len(frames):
            continue
        _check_rate(path, frames, fps)
        episodes.append(Episode(row, frames, task_text(row)))
    if not episodes:
        raise InputError(
            "no trial with frames (the trial table's 'frames' column is empty)",
            source=str(study / "trials.parquet"),
            field="frames",
        )
    return episodes


def _check_rate(path: Path, frames: Frames, fps: int) -> None:
    if not np.allclose(frames.t, frames.tick / fps, rtol=0.0, atol=1e-6):
        raise InputError(
            f"expected t = tick / {fps} (the control rate, {fps} Hz), got another rate",
            source=str(path),
            field="t",
        )


# --- the tables ----------------------------------------------------------------------------
def _vectors(a: FloatArray, pa: Any) -> Any:
    flat = pa.array(np.ascontiguousarray(a, dtype=np.float32).reshape(-1), pa.float32())
    return pa.FixedSizeListArray.from_arrays(flat, a.shape[1])


def _hf_metadata() -> bytes:
    """The ``huggingface`` schema metadata LeRobot's data files carry (the features as
    ``datasets`` types)."""
    out: dict[str, Any] = {}
    for name, f in FEATURES.items():
        value = {"dtype": f["dtype"], "_type": "Value"}
        out[name] = (
            value if f["shape"] == [1] else {"feature": value, "length": f["shape"][0],
                                             "_type": "List"}
        )  # fmt: skip
    return json.dumps({"info": {"features": out}}).encode()


def data_columns(episodes: Sequence[Episode], tasks: Mapping[str, int]) -> dict[str, Any]:
    """Every frame's feature values (numpy), episode after episode."""
    lengths = np.array([len(e.frames) for e in episodes], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    total = int(lengths.sum())
    return {
        "observation.state": np.concatenate([e.frames.ee for e in episodes]).astype(np.float32),
        "action": np.concatenate([e.frames.axes for e in episodes]).astype(np.float32),
        "timestamp": np.concatenate([e.frames.t for e in episodes]).astype(np.float32),
        "frame_index": np.arange(total, dtype=np.int64) - np.repeat(starts, lengths),
        "episode_index": np.repeat(np.arange(len(episodes), dtype=np.int64), lengths),
        "index": np.arange(total, dtype=np.int64),
        "task_index": np.repeat(
            np.array([tasks[e.task] for e in episodes], dtype=np.int64), lengths
        ),
    }


def data_table(columns: Mapping[str, Any], rows: slice) -> Any:
    """The frames ``rows`` as LeRobot's data file (its schema and metadata)."""
    import pyarrow as pa  # type: ignore[import-untyped]

    arrays = [
        _vectors(columns[name][rows], pa)
        if FEATURES[name]["shape"] != [1]
        else pa.array(columns[name][rows], pa.float32() if FEATURES[name]["dtype"] ==
                      "float32" else pa.int64())
        for name in FEATURES
    ]  # fmt: skip
    table = pa.Table.from_arrays(arrays, names=list(FEATURES))
    return table.replace_schema_metadata({b"huggingface": _hf_metadata()})


def feature_stats(values: Any) -> dict[str, list[float] | list[int]]:
    """LeRobot's stats of one feature over ``values`` (``(K,)`` or ``(K, d)``): per
    dimension ``min``, ``max`` (of the values' type), ``mean``, ``std``, the quantiles, and
    ``count`` ``[K]``."""
    a = np.asarray(values)
    a2 = a.reshape(len(a), -1)
    wide = a2.astype(np.float64)
    out: dict[str, list[float] | list[int]] = {
        "min": a2.min(axis=0).tolist(),
        "max": a2.max(axis=0).tolist(),
        "mean": wide.mean(axis=0).tolist(),
        "std": wide.std(axis=0).tolist(),
        "count": [len(a)],
    }
    quantiles = np.quantile(wide, QUANTILES, axis=0)
    for key, q in zip(STATS[5:], quantiles, strict=True):
        out[key] = q.tolist()
    return out


def all_stats(columns: Mapping[str, Any], rows: slice | None = None) -> dict[str, Any]:
    """:func:`feature_stats` of every feature (over ``rows``: all)."""
    part = rows if rows is not None else slice(None)
    return {name: feature_stats(columns[name][part]) for name in FEATURES}


def tasks_table(tasks: Mapping[str, int]) -> Any:
    """``meta/tasks.parquet``: ``task_index`` and the task strings as the pandas index
    (the ``pandas`` schema metadata pandas' ``to_parquet`` writes: LeRobot reads the table
    with pandas and takes a task's string from the index)."""
    import pyarrow as pa

    index = "__index_level_0__"
    pandas = {
        "index_columns": [index],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode",
                            "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": None},
            {"name": None, "field_name": index, "pandas_type": "unicode",
             "numpy_type": "object", "metadata": None},
        ],
        "attributes": {},
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0",
    }  # fmt: skip
    table = pa.Table.from_arrays(
        [pa.array(list(tasks.values()), pa.int64()), pa.array(list(tasks), pa.string())],
        names=["task_index", index],
    )
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas).encode()})


def episodes_table(
    episodes: Sequence[Episode], columns: Mapping[str, Any], files: Sequence[tuple[int, int]]
) -> Any:
    """``meta/episodes/chunk-000/file-000.parquet``: LeRobot's columns, then the study's."""
    import pyarrow as pa

    lengths = [len(e.frames) for e in episodes]
    ends = np.cumsum(lengths).tolist()
    starts = [0, *ends[:-1]]
    data: dict[str, Any] = {
        "episode_index": pa.array(range(len(episodes)), pa.int64()),
        "tasks": pa.array([[e.task] for e in episodes], pa.list_(pa.string())),
        "length": pa.array(lengths, pa.int64()),
        "data/chunk_index": pa.array([c for c, _ in files], pa.int64()),
        "data/file_index": pa.array([f for _, f in files], pa.int64()),
        "dataset_from_index": pa.array(starts, pa.int64()),
        "dataset_to_index": pa.array(ends, pa.int64()),
    }
    per_episode = [all_stats(columns, slice(s, e)) for s, e in zip(starts, ends, strict=True)]
    for name in FEATURES:
        for key in STATS:
            values = [stats[name][key] for stats in per_episode]
            integer = key == "count" or (key in ("min", "max") and name not in _FLOATS)
            data[f"stats/{name}/{key}"] = pa.array(
                values, pa.list_(pa.int64() if integer else pa.float64())
            )
    data["meta/episodes/chunk_index"] = pa.array([0] * len(episodes), pa.int64())
    data["meta/episodes/file_index"] = pa.array([0] * len(episodes), pa.int64())
    types = {"string": pa.string(), "int": pa.int64(), "float": pa.float64(), "bool": pa.bool_()}
    likert = max((_likert_items(e.row) for e in episodes), default=0)
    for c in (*STUDY_COLUMNS, *questionnaire_columns(likert)):
        key = "index" if c.name == "step" else c.name
        data[c.name] = pa.array([_cell(e.row.get(key)) for e in episodes], types[c.kind])
    return pa.Table.from_pydict(data)


def _likert_items(row: Mapping[str, Any]) -> int:
    """How many Likert items the trial table's row has (its ``likert_<k>`` columns)."""
    return sum(1 for k in row if re.fullmatch(r"likert_[0-9]+", k))


def _cell(value: Any) -> Any:
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def info_json(episodes: Sequence[Episode], tasks: int, fps: int, robot_type: str | None) -> Any:
    """``meta/info.json``."""
    frames = sum(len(e.frames) for e in episodes)
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "total_episodes": len(episodes),
        "total_frames": frames,
        "total_tasks": tasks,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILE_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILE_SIZE_IN_MB,
        "fps": fps,
        "splits": {"train": f"0:{len(episodes)}"},
        "data_path": DATA_PATH,
        "video_path": None,
        "features": FEATURES,
    }


def file_of_episodes(lengths: Sequence[int]) -> list[tuple[int, int]]:
    """Each episode's ``(chunk, file)``: episodes fill a file up to
    :data:`DATA_FILE_SIZE_IN_MB` (an episode is never split), :data:`CHUNKS_SIZE` files a
    chunk."""
    limit = DATA_FILE_SIZE_IN_MB * 1024 * 1024 // FRAME_BYTES
    out: list[tuple[int, int]] = []
    number, filled = 0, 0
    for n in lengths:
        if filled and filled + n > limit:
            number, filled = number + 1, 0
        filled += n
        out.append(divmod(number, CHUNKS_SIZE))
    return out


# --- writing -------------------------------------------------------------------------------
def _parquet(path: Path, table: Any) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq  # type: ignore[import-untyped]

    output_folder(path.parent)
    buf = pa.BufferOutputStream()
    pq.write_table(table, buf, compression="snappy")
    return write_atomic(path, buf.getvalue().to_pybytes())


def _json(path: Path, data: Any) -> Path:
    output_folder(path.parent)
    return write_atomic(path, (json.dumps(data, indent=4) + "\n").encode())


def check_out(out: Path, force: bool) -> None:
    """Refuse a non-empty ``out`` (a file, or a folder with files) unless ``force``."""
    if out.exists() and not out.is_dir():
        raise InputError("expected a folder for the dataset, found a file", source=str(out))
    if out.is_dir() and any(out.iterdir()) and not force:
        raise InputError(
            "the dataset folder is not empty; use another folder or --force", source=str(out)
        )


def _remove_stale(out: Path, written: set[Path]) -> None:
    """Data and episode files of an earlier export that this one did not write (LeRobot
    reads every ``chunk-*/file-*.parquet`` it finds)."""
    for path in sorted(out.glob("*/**/chunk-*/file-*.parquet")):
        relative = path.relative_to(out).as_posix()
        if path not in written and _LAYOUT.match(relative) and path.is_file():
            path.unlink()


def export_lerobot(
    study: Path, out: Path, *, fps: int, robot_type: str | None = "sawyer", force: bool = False
) -> dict[str, Any]:
    """Write the study in ``study`` as a LeRobotDataset v3.0 into ``out`` (see the module's
    text); ``fps`` the control rate (``1 / Params().dt``). Returns what was written:
    ``episodes``, ``frames``, ``tasks``, ``participants``, ``files``."""
    if fps < 1:
        raise InputError(f"expected a positive control rate, got {fps}", field="fps")
    study, out = Path(study), Path(out)
    check_out(out, force)
    episodes = load_episodes(study, fps)
    tasks: dict[str, int] = {}
    for e in episodes:
        tasks.setdefault(e.task, len(tasks))
    columns = data_columns(episodes, tasks)
    files = file_of_episodes([len(e.frames) for e in episodes])
    output_folder(out)
    written = {_write_data(out, columns, episodes, files, f) for f in sorted(set(files))}
    written.add(_parquet(out / EPISODES_PATH.format(chunk_index=0, file_index=0),
                         episodes_table(episodes, columns, files)))  # fmt: skip
    _parquet(out / TASKS_PATH, tasks_table(tasks))
    _json(out / STATS_PATH, all_stats(columns))
    _json(out / INFO_PATH, info_json(episodes, len(tasks), fps, robot_type))
    _remove_stale(out, written)
    return {
        "episodes": len(episodes),
        "frames": len(columns["index"]),
        "tasks": len(tasks),
        "participants": len({e.row["participant"] for e in episodes}),
        "files": len(written),
    }


def _write_data(
    out: Path,
    columns: Mapping[str, Any],
    episodes: Sequence[Episode],
    files: Sequence[tuple[int, int]],
    file: tuple[int, int],
) -> Path:
    """The data file ``file`` (``(chunk, file)``): the frames of its episodes."""
    lengths = np.array([len(e.frames) for e in episodes])
    ends = np.cumsum(lengths)
    mine = [i for i, f in enumerate(files) if f == file]
    rows = slice(int(ends[mine[0]] - lengths[mine[0]]), int(ends[mine[-1]]))
    path = out / DATA_PATH.format(chunk_index=file[0], file_index=file[1])
    return _parquet(path, data_table(columns, rows))


# --- checking ------------------------------------------------------------------------------
def _read_parquet(path: Path, problems: list[str], what: str) -> Any:
    import pyarrow.parquet as pq

    try:
        regular_file(path, "study table")
        return pq.read_table(path)
    except InputError as err:
        problems.append(f"{what}: {err}")
    except Exception as err:  # pyarrow's errors have no common base beyond ArrowException
        problems.append(f"{what}: {path}: not a readable Parquet table: {err}")
    return None


def _type_problem(name: str, feature: Mapping[str, Any], kind: Any) -> str | None:
    """What is wrong with the data column ``name`` of Arrow type ``kind`` for its
    feature (``None``: nothing)."""
    import pyarrow as pa

    shape, dtype = list(feature.get("shape", [])), str(feature.get("dtype"))
    value = kind
    if shape != [1]:
        if not (pa.types.is_fixed_size_list(kind) or pa.types.is_list(kind)):
            return f"data column '{name}': expected a list of {shape} {dtype}, got {kind}"
        if pa.types.is_fixed_size_list(kind) and [kind.list_size] != shape:
            return f"data column '{name}': expected {shape} values, got {kind.list_size}"
        value = kind.value_type
    if str(value) != {"float32": "float", "float64": "double"}.get(dtype, dtype):
        return f"data column '{name}': expected {dtype}, got {value}"
    return None


def check_lerobot(out: Path) -> list[str]:
    """What does not hold together in the LeRobotDataset in ``out`` (empty: nothing found):
    ``info.json``'s keys and totals, its features against every data file's columns and
    types, the episodes' indices (0, 1, ...), ranges (contiguous, ``length`` frames each,
    covering the data rows) and files, every frame's ``index``, ``episode_index``,
    ``frame_index`` and ``task_index``, and the stats' features."""
    from legws_daemon.formats.validation import read_json

    out = Path(out)
    problems: list[str] = []
    try:
        info = read_json(out / INFO_PATH, "summary")
    except InputError as err:
        return [f"info.json: {err}"]
    if not isinstance(info, dict):
        return [f"info.json: expected a JSON object, got {type(info).__name__}"]
    problems += _check_info(info)
    features = info.get("features")
    if not isinstance(features, dict):
        return [*problems, "info.json: expected 'features', an object"]
    episodes = _read_parquet(
        out / EPISODES_PATH.format(chunk_index=0, file_index=0), problems, "episodes"
    )
    tasks = _read_parquet(out / TASKS_PATH, problems, "tasks")
    if episodes is None or tasks is None:
        return problems
    problems += _check_episodes(episodes.to_pydict(), info, tasks.num_rows)
    data = _read_data(out, info, episodes.to_pydict(), problems)
    if data is not None:
        problems += _check_frames(data, episodes.to_pydict(), info)
    problems += _check_stats(out, features)
    return problems


def _check_info(info: Mapping[str, Any]) -> list[str]:
    keys = ("codebase_version", "robot_type", "total_episodes", "total_frames", "total_tasks",
            "chunks_size", "data_files_size_in_mb", "fps", "splits", "data_path", "video_path",
            "features")  # fmt: skip
    problems = [f"info.json: no '{k}'" for k in keys if k not in info]
    if info.get("codebase_version") != CODEBASE_VERSION:
        problems.append(
            f"info.json: codebase_version {info.get('codebase_version')!r}, expected "
            f"{CODEBASE_VERSION!r}"
        )
    features = info.get("features")
    if isinstance(features, dict):
        missing = [k for k in FEATURES if k not in features]
        if missing:
            problems.append(f"info.json: features without {missing}")
    return problems


def _check_episodes(ep: Mapping[str, list[Any]], info: Mapping[str, Any], tasks: int) -> list[str]:
    need = ("episode_index", "tasks", "length", "data/chunk_index", "data/file_index",
            "dataset_from_index", "dataset_to_index")  # fmt: skip
    missing = [k for k in need if k not in ep]
    if missing:
        return [f"episodes: no column {missing}"]
    n = len(ep["episode_index"])
    problems = []
    if ep["episode_index"] != list(range(n)):
        problems.append("episodes: episode_index is not 0, 1, ... in order")
    starts, ends, lengths = ep["dataset_from_index"], ep["dataset_to_index"], ep["length"]
    if starts[:1] not in ([0], []) or starts[1:] != ends[:-1]:
        problems.append("episodes: the ranges [dataset_from_index, dataset_to_index) are not "
                        "contiguous from 0")  # fmt: skip
    bad = [i for i in range(n) if ends[i] - starts[i] != lengths[i] or lengths[i] < 1]
    if bad:
        problems.append(f"episodes: length is not dataset_to_index - dataset_from_index (>= 1) "
                        f"in episode {bad[0]}")  # fmt: skip
    totals = {"total_episodes": n, "total_frames": sum(lengths), "total_tasks": tasks}
    for key, value in totals.items():
        if info.get(key) != value:
            problems.append(f"info.json: {key} is {info.get(key)!r}, the files hold {value}")
    if info.get("splits") != {"train": f"0:{n}"}:
        problems.append(f"info.json: splits {info.get('splits')!r}, expected train 0:{n}")
    return problems


def _read_data(
    out: Path, info: Mapping[str, Any], ep: Mapping[str, list[Any]], problems: list[str]
) -> Any:
    """Every data file the episodes name, in order, concatenated (``None``: unreadable);
    each file's columns checked against the features."""
    import pyarrow as pa

    template = str(info.get("data_path", DATA_PATH))
    names = sorted(set(zip(ep.get("data/chunk_index", []), ep.get("data/file_index", []),
                           strict=True)))  # fmt: skip
    tables = []
    features = info["features"]
    for chunk, file in names:
        path = out / template.format(chunk_index=chunk, file_index=file)
        table = _read_parquet(path, problems, "data")
        if table is None:
            return None
        columns = set(table.column_names)
        for name in features.keys() - columns:
            problems.append(f"data {path.name}: no column '{name}' of the features")
        for name in columns - features.keys():
            problems.append(f"data {path.name}: column '{name}' is not a feature")
        for name in features.keys() & columns:
            problem = _type_problem(name, features[name], table.schema.field(name).type)
            if problem is not None:
                problems.append(problem)
        tables.append(table.select([n for n in FEATURES if n in columns]))
    if not tables:
        return None
    try:
        return pa.concat_tables(tables)
    except Exception as err:  # pyarrow's errors have no common base beyond ArrowException
        problems.append(f"data: the files' schemas differ: {err}")
        return None


def _check_frames(data: Any, ep: Mapping[str, list[Any]], info: Mapping[str, Any]) -> list[str]:
    columns = set(data.column_names)
    need = {"index", "episode_index", "frame_index", "task_index", "timestamp"}
    if not need <= columns or "dataset_to_index" not in ep:
        return []
    problems = []
    n = data.num_rows
    if n != sum(ep["length"]):
        problems.append(f"data: {n} rows, the episodes hold {sum(ep['length'])} frames")
        return problems
    index = data.column("index").to_numpy()
    if not np.array_equal(index, np.arange(n)):
        problems.append("data: index is not 0, 1, ... in order")
    lengths = np.asarray(ep["length"], dtype=np.int64)
    episode = np.repeat(np.arange(len(lengths)), lengths)
    if not np.array_equal(data.column("episode_index").to_numpy(), episode):
        problems.append("data: episode_index does not match the episodes' ranges")
    starts = np.repeat(np.asarray(ep["dataset_from_index"], dtype=np.int64), lengths)
    if not np.array_equal(data.column("frame_index").to_numpy(), np.arange(n) - starts):
        problems.append("data: frame_index is not 0, 1, ... within each episode")
    task = data.column("task_index").to_numpy()
    if task.size and (task.min() < 0 or task.max() >= int(info.get("total_tasks") or 0)):
        problems.append("data: task_index outside the tasks")
    t = data.column("timestamp").to_numpy().astype(np.float64)
    if np.any((np.diff(t) <= 0) & (np.diff(episode) == 0)):
        problems.append("data: timestamp does not increase within an episode")
    return problems


def _check_stats(out: Path, features: Mapping[str, Any]) -> list[str]:
    from legws_daemon.formats.validation import read_json

    try:
        stats = read_json(out / STATS_PATH, "summary")
    except InputError as err:
        return [f"stats.json: {err}"]
    if not isinstance(stats, dict):
        return ["stats.json: expected a JSON object"]
    problems = [f"stats.json: no stats of '{k}'" for k in features if k not in stats]
    for name, entry in stats.items():
        if not isinstance(entry, dict) or not {"min", "max", "mean", "std", "count"} <= set(entry):
            problems.append(f"stats.json: '{name}' lacks min, max, mean, std or count")
    return problems
