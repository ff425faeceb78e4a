"""A study exported as a LeRobotDataset v3.0: LeRobot's layout and schemas, the episodes'
metadata the trial table's, the frames the frames files'; a damaged dataset is reported."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pyarrow.parquet as pq  # type: ignore[import-untyped]
import pytest

from legws_daemon.cli.main import run
from legws_daemon.cli.study_export import export_cmd
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.study.frames import frames_path, make_frames, read_frames, write_frames
from legws_daemon.study.lerobot import (
    DATA_FILE_SIZE_IN_MB,
    FEATURES,
    FRAME_BYTES,
    STATS,
    check_lerobot,
    export_lerobot,
    feature_stats,
    file_of_episodes,
    task_text,
)
from legws_daemon.study.table import read_table, write_table

DATA = Path(__file__).parent / "data"
FPS = round(1.0 / Params().dt)
EPISODES = "meta/episodes/chunk-000/file-000.parquet"
FRAMES = "data/chunk-000/file-000.parquet"


def _fake_study(folder: Path, lengths: tuple[int, ...] = (5, 7, 4)) -> list[dict[str, Any]]:
    """A study folder as ``study run`` leaves it (the columns the export reads): trials of
    two participants, the first a practice trial, with random frames."""
    rng = np.random.default_rng(0)
    rows = []
    for k, n in enumerate(lengths):
        person = "P01" if k < 2 else "P02"
        row: dict[str, Any] = {
            "participant": person, "protocol": "fake", "index": k + 2,
            "kind": "practice" if k == 0 else "trial", "condition": ["", "a", "b"][k % 3],
            "trial": k, "task": "pick", "targets": "banana" if k % 2 else "cereal_box;banana",
            "layout_source": "shipped", "layout": '{"banana":[0.5,0.1,0.0]}',
            "slack_j": 2.5 - k, "commit_k": 0.7, "person_slack_j": None if k else 2.4,
            "person_commit_k": 0.6, "completed": k != 1, "correct": True,
            "commit_time_s": 1.5 + k, "time_to_task_s": None if k == 1 else 9.0,
            "frames": frames_path(k + 2),
        }  # fmt: skip
        axes = rng.uniform(-1, 1, (n, 3))
        frames = make_frames(np.arange(n), rng.normal(size=(n, 3)), axes, ["teleop"] * n, 1 / FPS)
        (folder / person / "frames").mkdir(parents=True, exist_ok=True)
        write_frames(folder / person / row["frames"], frames)
        rows.append(row)
    rows.append({**rows[-1], "index": 9, "frames": ""})  # a trial that did not run
    write_table(folder, "trials", rows, 0)
    return rows


@pytest.fixture
def fake(tmp_path: Path) -> tuple[Path, Path]:
    study, out = tmp_path / "study", tmp_path / "dataset"
    _fake_study(study)
    export_lerobot(study, out, fps=FPS)
    return study, out


def test_the_export_has_lerobots_v3_layout_and_schemas(fake: tuple[Path, Path]) -> None:
    _, out = fake
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == [
        FRAMES, "meta/episodes/chunk-000/file-000.parquet", "meta/info.json",
        "meta/stats.json", "meta/tasks.parquet",
    ]  # fmt: skip
    info = json.loads((out / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == FPS
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (3, 16, 2)
    assert info["splits"] == {"train": "0:3"} and info["video_path"] is None
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["features"]["observation.state"] == {
        "dtype": "float32", "shape": [3], "names": ["ee_x", "ee_y", "ee_z"]
    }  # fmt: skip
    data = pq.read_schema(out / FRAMES)
    assert data.names == list(FEATURES)
    assert data.field("action").type == pa.list_(pa.float32(), 3)
    assert data.field("timestamp").type == pa.float32()
    assert b"huggingface" in data.metadata
    episodes = pq.read_schema(out / EPISODES)
    assert episodes.names[:7] == [
        "episode_index", "tasks", "length", "data/chunk_index", "data/file_index",
        "dataset_from_index", "dataset_to_index",
    ]  # fmt: skip
    assert episodes.field("tasks").type == pa.list_(pa.string())
    assert episodes.field("stats/observation.state/count").type == pa.list_(pa.int64())
    assert episodes.field("stats/frame_index/min").type == pa.list_(pa.int64())
    assert episodes.field("stats/action/q50").type == pa.list_(pa.float64())
    tasks = pq.read_table(out / "meta/tasks.parquet")
    assert tasks.to_pydict() == {
        "task_index": [0, 1], "__index_level_0__": ["pick: pick cereal_box then banana",
                                                    "pick: pick banana"]
    }  # fmt: skip
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["__index_level_0__"]
    assert check_lerobot(out) == []


def test_the_episodes_carry_the_trial_table_and_the_frames_are_the_frames_files(
    fake: tuple[Path, Path],
) -> None:
    study, out = fake
    rows = [r for r in read_table(study / "trials.parquet") if r["frames"]]
    episodes = pq.read_table(out / EPISODES).to_pylist()
    data = pq.read_table(out / FRAMES).to_pydict()
    assert len(episodes) == len(rows)
    for e, row in zip(episodes, rows, strict=True):
        for key in ("participant", "condition", "kind", "trial", "layout_source", "layout",
                    "slack_j", "commit_k", "person_slack_j", "person_commit_k", "completed",
                    "correct", "commit_time_s", "time_to_task_s", "frames"):  # fmt: skip
            assert e[key] == row[key], key
        assert e["step"] == row["index"] and e["tasks"] == [task_text(row)]
        frames = read_frames(study / row["participant"] / row["frames"])
        part = slice(e["dataset_from_index"], e["dataset_to_index"])
        assert e["length"] == len(frames)
        np.testing.assert_allclose(data["observation.state"][part], frames.ee, rtol=1e-6)
        np.testing.assert_allclose(data["action"][part], frames.axes, rtol=1e-6)
        np.testing.assert_allclose(data["timestamp"][part], frames.t, rtol=1e-6)
        assert data["frame_index"][part] == list(range(len(frames)))
        assert set(data["episode_index"][part]) == {e["episode_index"]}
        state = np.asarray(data["observation.state"][part])
        np.testing.assert_allclose(e["stats/observation.state/mean"], state.mean(axis=0))
        assert e["stats/observation.state/count"] == [len(frames)]
    stats = json.loads((out / "meta/stats.json").read_text())
    assert set(stats) == set(FEATURES) and set(stats["action"]) == set(STATS)
    assert stats["index"]["max"] == [15] and stats["action"]["count"] == [16]


def test_stats_are_lerobots_per_dimension() -> None:
    values = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]], dtype=np.float32)
    s = feature_stats(values)
    assert s["min"] == [0.0, 1.0] and s["max"] == [4.0, 5.0] and s["count"] == [3]
    np.testing.assert_allclose(s["std"], values.std(axis=0))
    np.testing.assert_allclose(s["q50"], [2.0, 3.0])
    scalar = feature_stats(np.arange(4, dtype=np.int64))
    assert scalar["min"] == [0] and isinstance(scalar["max"][0], int) and scalar["mean"] == [1.5]


def test_episodes_fill_data_files_up_to_their_size() -> None:
    limit = DATA_FILE_SIZE_IN_MB * 1024 * 1024 // FRAME_BYTES
    assert file_of_episodes([10, 20]) == [(0, 0), (0, 0)]
    assert file_of_episodes([limit - 5, 10, limit]) == [(0, 0), (0, 1), (0, 2)]


def test_a_damaged_dataset_is_reported(fake: tuple[Path, Path], tmp_path: Path) -> None:
    _, out = fake
    wrong = tmp_path / "wrong_total"
    shutil.copytree(out, wrong)
    info = json.loads((wrong / "meta/info.json").read_text())
    info["total_frames"] += 1
    (wrong / "meta/info.json").write_text(json.dumps(info))
    assert check_lerobot(wrong) == ["info.json: total_frames is 17, the files hold 16"]

    no_action = tmp_path / "no_action"
    shutil.copytree(out, no_action)
    table = pq.read_table(no_action / FRAMES)
    pq.write_table(table.drop_columns(["action"]), no_action / FRAMES)
    assert check_lerobot(no_action) == ["data file-000.parquet: no column 'action' of the features"]

    gap = tmp_path / "gap"
    shutil.copytree(out, gap)
    episodes = pq.read_table(gap / EPISODES)
    starts = episodes.column("dataset_from_index").to_pylist()
    starts[1] += 1
    index = episodes.schema.get_field_index("dataset_from_index")
    pq.write_table(episodes.set_column(index, "dataset_from_index", pa.array(starts)),
                   gap / EPISODES)  # fmt: skip
    problems = check_lerobot(gap)
    assert any("not contiguous" in p for p in problems)
    assert any("length is not" in p for p in problems)

    float64 = tmp_path / "float64"
    shutil.copytree(out, float64)
    table = pq.read_table(float64 / FRAMES)
    index = table.schema.get_field_index("timestamp")
    table = table.set_column(index, "timestamp", table.column("timestamp").cast(pa.float64()))
    pq.write_table(table, float64 / FRAMES)
    assert check_lerobot(float64) == ["data column 'timestamp': expected float32, got double"]
    assert check_lerobot(tmp_path / "nothing")[0].startswith("info.json: ")


def test_a_missing_frames_file_is_an_input_error_naming_it(tmp_path: Path) -> None:
    study = tmp_path / "study"
    rows = _fake_study(study)
    missing = study / rows[1]["participant"] / rows[1]["frames"]
    missing.unlink()
    with pytest.raises(InputError, match="frames file of P01 step 3 is missing") as err:
        export_lerobot(study, tmp_path / "dataset", fps=FPS)
    assert err.value.source == str(missing)


def test_frames_at_another_rate_are_refused(tmp_path: Path) -> None:
    study = tmp_path / "study"
    _fake_study(study)
    with pytest.raises(InputError, match="tick / 10"):
        export_lerobot(study, tmp_path / "dataset", fps=10)


def test_the_command_refuses_a_folder_that_is_not_empty_without_force(
    fake: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    study, out = fake
    with pytest.raises(InputError, match="not empty; use another folder or --force"):
        export_cmd.main([str(study), "--out", str(out)], standalone_mode=False)
    stale = out / "data/chunk-000/file-001.parquet"
    shutil.copy(out / FRAMES, stale)  # an earlier, bigger export's second file
    capsys.readouterr()
    export_cmd.main([str(study), "--out", str(out), "--force"], standalone_mode=False)
    assert capsys.readouterr().err == (
        f"legws: 3 episodes (16 frames at {FPS} Hz, 2 tasks) of 2 participants -> {out} "
        "(LeRobotDataset v3.0)\n"
    )
    assert not stale.exists() and check_lerobot(out) == []


# --- a simulated study -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def twin(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The twin protocol with two simulated participants, and its export."""
    base = tmp_path_factory.mktemp("twin")
    study, out = base / "study", base / "dataset"
    code = run(["study", "run", str(DATA / "twin.toml"), "--simulate",
                str(DATA / "planted.toml"), "--participants", "2",
                "--out", str(study)])  # fmt: skip
    assert code == 0
    export_lerobot(study, out, fps=FPS)
    return study, out


@pytest.mark.slow
def test_the_simulator_writes_every_trials_frames(twin: tuple[Path, Path]) -> None:
    study, _ = twin
    rows = read_table(study / "trials.parquet")
    assert len(rows) == 16
    for row in rows:
        assert row["frames"] == frames_path(row["index"])
        frames = read_frames(study / row["participant"] / row["frames"])
        # a pick runs past its task's end: the arm carries the object home
        assert len(frames) > row["time_to_task_s"] * FPS
        hesitating = frames.t < row["hesitation_s"]
        assert np.all(frames.axes[hesitating] == 0.0)
        assert np.any(frames.axes[~hesitating] != 0.0)
        assert frames.mode[-1] == "idle"


@pytest.mark.slow
def test_a_simulated_study_exports_as_a_consistent_dataset(twin: tuple[Path, Path]) -> None:
    study, out = twin
    assert check_lerobot(out) == []
    rows = read_table(study / "trials.parquet")
    episodes = pq.read_table(out / EPISODES).to_pylist()
    data = pq.read_table(out / FRAMES).to_pydict()
    assert [e["participant"] for e in episodes] == [r["participant"] for r in rows]
    for e, row in zip(episodes, rows, strict=True):
        for key in ("condition", "kind", "layout", "slack_j", "commit_k", "person_slack_j",
                    "person_commit_k", "correct", "commit_time_s", "time_to_task_s"):  # fmt: skip
            assert e[key] == row[key], key
        frames = read_frames(study / row["participant"] / row["frames"])
        part = slice(e["dataset_from_index"], e["dataset_to_index"])
        np.testing.assert_allclose(data["observation.state"][part], frames.ee, rtol=1e-6)
        np.testing.assert_allclose(data["action"][part], frames.axes, rtol=1e-6, atol=1e-7)
    info = json.loads((out / "meta/info.json").read_text())
    assert info["total_episodes"] == 16 and info["total_frames"] == len(data["index"])
