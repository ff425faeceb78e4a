"""A trial's per-tick frames: written and read back, every schema error named; a trial's
recording gives the same frames; the protocol's pick and a task graph's trial record one
frame per tick without changing what they measure."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pyarrow.parquet as pq  # type: ignore[import-untyped]
import pytest

from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.sim.protocol import Evaluator
from legws_daemon.study.frames import (
    FrameRecorder,
    Frames,
    frames_from_recording,
    frames_path,
    frames_table,
    make_frames,
    read_frames,
    write_frames,
)
from legws_daemon.study.population import load_population
from legws_daemon.study.protocol import load_protocol
from legws_daemon.study.schedule import make_schedule
from legws_daemon.study.simulate import simulate_study
from legws_daemon.telemetry.rerun_log import RerunLog
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.telemetry.helpers import setup, straight_episode, tick_kwargs

DT = Params().dt


def _frames(n: int = 6) -> Frames:
    rng = np.random.default_rng(1)
    axes = rng.uniform(-1, 1, (n, 3))
    axes[:2] = np.nan  # no input on the first two ticks
    modes = ["teleop"] * (n - 1) + ["assist"]
    return make_frames(np.arange(n), rng.normal(size=(n, 3)), axes, modes, DT)


def test_frames_are_written_and_read_back(tmp_path: Path) -> None:
    frames = _frames()
    path = write_frames(tmp_path / "f.parquet", frames)
    back = read_frames(path)
    assert len(back) == 6 and back.mode == frames.mode
    np.testing.assert_array_equal(back.tick, np.arange(6))
    np.testing.assert_allclose(back.t, np.arange(6) * DT)
    np.testing.assert_array_equal(back.ee, frames.ee)
    np.testing.assert_array_equal(back.axes, frames.axes)
    assert np.all(back.axes[:2] == 0.0)  # a tick without input is zeros, never NaN
    schema = pq.read_schema(path)
    assert schema.names == ["tick", "t", "ee", "axes", "mode"]
    assert schema.field("ee").metadata[b"unit"] == b"m"
    assert frames_path(7) == "frames/step-007.parquet"


def _write(path: Path, table: Any) -> Path:
    pq.write_table(table, path)
    return path


@pytest.mark.parametrize(
    ("change", "field", "text"),
    [
        (lambda t: t.drop_columns(["axes"]), "axes", "expected a column 'axes'"),
        (lambda t: t.set_column(0, "tick", pa.array(np.arange(6.0))), "tick", "int64"),
        (lambda t: t.set_column(4, "mode", pa.array([None] + ["teleop"] * 5, pa.string())),
         "mode", "1 empty"),
        (lambda t: t.set_column(0, "tick", pa.array([0, 1, 1, 2, 3, 4])), "tick", "increasing"),
        (lambda t: t.set_column(2, "ee", pa.array([[0.0, 0.0]] * 6, pa.list_(pa.float64()))),
         "ee", "3 float64"),
        (lambda t: t.set_column(3, "axes", pa.array([[2.0, 0.0, 0.0]] * 6,
                                                    pa.list_(pa.float64(), 3))),
         "axes", "[-1, 1], row 0"),
        (lambda t: t.set_column(2, "ee", pa.array([[math.nan, 0.0, 0.0]] * 6,
                                                  pa.list_(pa.float64(), 3))),
         "ee", "finite"),
        (lambda t: t.set_column(1, "t", pa.array([0.0] * 6)), "t", "increasing"),
    ],
)  # fmt: skip
def test_a_frames_file_out_of_its_schema_is_one_error_naming_file_and_field(
    tmp_path: Path, change: Callable[[Any], Any], field: str, text: str
) -> None:
    table = frames_table(_frames())
    path = _write(tmp_path / "bad.parquet", change(table))
    with pytest.raises(InputError) as err:
        read_frames(path)
    assert err.value.source == str(path) and err.value.field == field
    assert text in str(err.value)


def test_a_missing_or_unreadable_frames_file_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        read_frames(tmp_path / "none.parquet")
    (tmp_path / "text.parquet").write_text("not parquet")
    with pytest.raises(InputError, match="not a readable Parquet table"):
        read_frames(tmp_path / "text.parquet")


def test_a_trials_recording_gives_the_same_frames(tmp_path: Path) -> None:
    ep = straight_episode("breakfast_easy", "banana")
    path = tmp_path / "trial.rrd"
    first = 40  # the daemon's ticks count from its start, not the trial's
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, ep, "choose")
        for k in range(len(ep.positions)):
            kwargs = tick_kwargs(ep, k, None)
            if k < 3:
                kwargs.update(joystick=None)  # no input yet
            if k == len(ep.positions) - 1:
                kwargs.update(mode="assist")
            log.log_tick(TickSnapshot(first + k, (first + k) * DT, **kwargs))
    frames = frames_from_recording(path, DT)
    n = len(ep.positions)
    assert len(frames) == n
    np.testing.assert_array_equal(frames.tick, np.arange(n))
    np.testing.assert_allclose(frames.t, np.arange(n) * DT)
    np.testing.assert_allclose(frames.ee, ep.positions)
    assert np.all(frames.axes[:3] == 0.0) and np.all(np.isfinite(frames.axes))
    moving = tick_kwargs(ep, 3, None)["joystick"]
    np.testing.assert_allclose(frames.axes[3], moving)
    assert frames.mode[0] == "teleop" and frames.mode[-1] == "assist"
    back = read_frames(write_frames(tmp_path / "f.parquet", frames))
    np.testing.assert_array_equal(back.ee, frames.ee)


def test_a_recording_without_teleoperation_ticks_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "empty.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, straight_episode("breakfast_easy", "banana"), "choose")
    with pytest.raises(InputError, match="found none") as err:
        frames_from_recording(path, DT)
    assert err.value.source == str(path)


def test_the_picks_frames_are_one_a_tick_and_change_nothing_of_the_pick() -> None:
    sc = load_scene("breakfast_easy")
    ev = Evaluator(sc)
    ev.prepare(sc.default_layout())
    plain = ev.pick("banana", np.random.default_rng(3), onset=1.0)
    recorder = FrameRecorder()
    recorded = ev.pick("banana", np.random.default_rng(3), onset=1.0, on_tick=recorder)
    assert recorded == plain and plain.completed
    frames = recorder.frames(DT)
    assert len(frames) == round(plain.duration / DT)
    np.testing.assert_array_equal(frames.tick, np.arange(len(frames)))
    assert np.all(frames.axes[frames.t < 1.0] == 0.0)  # hesitating: the stick held still
    assert np.any(frames.axes[frames.t >= 1.0] != 0.0)
    np.testing.assert_allclose(frames.ee[0], sc.home.position, atol=1e-3)
    assert frames.mode[0] == "teleop" and "assist" in frames.mode and frames.mode[-1] == "idle"


@pytest.mark.slow
def test_a_task_graph_trial_writes_one_frame_a_tick(tmp_path: Path) -> None:
    path = tmp_path / "teas.toml"
    path.write_text("""schema_version = 1
name = "teas"
title = "t"
seed = 2
[design]
counterbalance = "fixed"
trials_per_condition = 1
calibrate = false
[tasks.tea]
taskgraph = "tea"
[[conditions]]
name = "random"
task = "tea"
layout = "random"
assist = "blend"
""")  # fmt: skip
    p = load_protocol(path)
    out = tmp_path / "out"
    (row,) = simulate_study(p, make_schedule(p, 1), load_population("lab"), out)
    assert row["completed"] and row["frames"] == frames_path(row["index"])
    frames = read_frames(out / row["participant"] / row["frames"])
    # the trial ends on the tick its task is done
    assert len(frames) == round(row["time_to_task_s"] / DT)
    hesitating = frames.t < row["hesitation_s"]
    assert np.all(frames.axes[hesitating] == 0.0) and np.any(frames.axes[~hesitating] != 0.0)
    assert {"teleop", "assist"} <= set(frames.mode)
