"""Reading a recording back: entity paths, goals, params, the exact EE path, the text log."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.telemetry.recording import (
    entity_paths,
    parse_commit,
    read_commits,
    read_ee_path,
    read_goals,
    read_params,
    read_posterior,
    read_recorded_commits,
    read_stages,
    read_text_log,
    select_index,
    stage_labels,
)
from legws_daemon.telemetry.rerun_log import RerunLog, commit_text
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.telemetry.helpers import (
    Episode,
    record,
    setup,
    straight_episode,
    tick_kwargs,
    verify,
)

PARAMS = Params(beta=7.5, cost="ratio", p_thresh=0.85)


@pytest.fixture(scope="module")
def first() -> Episode:
    return straight_episode("breakfast_easy", "banana", params=PARAMS)


@pytest.fixture(scope="module")
def second() -> Episode:
    return straight_episode("desk", "white_mug", hold=0)


@pytest.fixture(scope="module")
def single(tmp_path_factory: pytest.TempPathFactory, first: Episode) -> tuple[Path, int | None]:
    path = tmp_path_factory.mktemp("single") / "one.rrd"
    (commit,) = record(path, first)
    return path, commit


@pytest.fixture(scope="module")
def two_stages(tmp_path_factory: pytest.TempPathFactory, first: Episode, second: Episode) -> Path:
    path = tmp_path_factory.mktemp("two") / "two.rrd"
    record(path, first, second)
    return path


def test_the_ee_path_round_trips_exactly(single: tuple[Path, int | None], first: Episode) -> None:
    ticks, times, positions, quaternions = read_ee_path(single[0])
    n = len(first.positions)
    assert ticks.dtype == np.int64 and ticks.tolist() == list(range(n))
    np.testing.assert_array_equal(times, np.arange(n) * PARAMS.dt)
    np.testing.assert_array_equal(positions, first.positions)
    np.testing.assert_array_equal(quaternions, np.tile(first.quaternion, (n, 1)))


def test_the_goals_and_params_round_trip(single: tuple[Path, int | None], first: Episode) -> None:
    goals = read_goals(single[0])
    assert goals.names == first.goals.names
    np.testing.assert_array_equal(goals.positions, first.goals.positions)
    np.testing.assert_allclose(goals.quaternions, first.goals.quaternions, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(goals.symmetry, first.goals.symmetry)
    np.testing.assert_array_equal(goals.x0.position, first.goals.x0.position)
    assert read_params(single[0]) == PARAMS


def test_the_stage_metadata(single: tuple[Path, int | None], first: Episode) -> None:
    (stage,) = read_stages(single[0])
    assert (stage.index, stage.name, stage.scene, stage.robot) == (
        0,
        "s0",
        "breakfast_easy",
        "sawyer-sim",
    )
    assert stage.p_thresh == PARAMS.p_thresh
    assert stage.goal_objects == {g: g for g in first.goals.names}


def test_the_text_log(single: tuple[Path, int | None], first: Episode) -> None:
    path, commit = single
    assert commit is not None
    log = read_text_log(path)
    assert [(t, lvl) for t, lvl, _ in log] == [(commit, "INFO"), (len(first.positions) - 1, "WARN")]
    assert log[-1][2] == "episode end"
    ((tick, goal, p),) = read_commits(path)
    assert (tick, goal) == (commit, "banana")
    assert PARAMS.p_thresh <= p < 1.0


def test_commits_with_their_time_and_how(tmp_path: Path, first: Episode) -> None:
    path = tmp_path / "confirmed.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, first, "s0")
        log.log_tick(TickSnapshot(0, 0.0, **tick_kwargs(first, 0, None)))
        log.log_text(3, 0.15, "INFO", commit_text("banana", 0.61, how="confirmed"))
        log.log_commit(7, 0.35, "cereal_box", 0.93)
        log.log_text(9, 0.45, "INFO", commit_text("banana", 1.0, how="single"))
    commits = read_recorded_commits(path)
    assert [(c.tick, c.goal, c.p, c.how) for c in commits] == [
        (3, "banana", 0.61, "confirmed"),
        (7, "cereal_box", 0.93, "inferred"),
        (9, "banana", 1.0, "single"),
    ]
    assert [c.seconds for c in commits] == pytest.approx([0.15, 0.35, 0.45])
    assert read_commits(path) == [(c.tick, c.goal, c.p) for c in commits]
    assert read_recorded_commits(path, "s0") == commits


def _observed(ep: Episode) -> np.ndarray:
    observer = IntentObserver(ep.goals, ep.params)
    return np.array([observer.update(x, ep.quaternion) for x in ep.positions])


def test_the_posterior_of_each_stage(two_stages: Path, first: Episode, second: Episode) -> None:
    n0, n1 = len(first.positions), len(second.positions)
    a = read_posterior(two_stages, 0)
    assert a.goals == first.goals.names
    assert a.ticks.tolist() == list(range(n0))
    np.testing.assert_allclose(a.times, np.arange(n0) * PARAMS.dt, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(a.values, _observed(first))
    b = read_posterior(two_stages, "s1")
    assert b.goals == second.goals.names
    assert b.ticks.tolist() == list(range(n0, n0 + n1))
    np.testing.assert_array_equal(b.values, _observed(second))
    every = read_posterior(two_stages)
    assert every.goals == first.goals.names + second.goals.names
    assert every.ticks.tolist() == list(range(n0 + n1))
    assert np.isnan(every.values[:n0, 2:]).all() and np.isnan(every.values[n0:, :2]).all()
    assert b.row_at(n0 - 1) is None and b.row_at(10**9) == n1 - 1
    row = b.row_at(n0 + 3)
    assert row == 3
    assert b.as_dict(row) == dict(zip(second.goals.names, b.values[3].tolist(), strict=True))
    assert every.as_dict(0)[second.goals.names[0]] is None


def test_the_posterior_is_absent_while_not_inferring(tmp_path: Path, first: Episode) -> None:
    path = tmp_path / "gaps.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, first)
        for k in range(6):
            post = (
                {"banana": 0.25 + k / 10, "cereal_box": 0.75 - k / 10} if k in (1, 2, 4) else None
            )
            log.log_tick(TickSnapshot(k, k * 0.05, **tick_kwargs(first, k, post)))
    posterior = read_posterior(path, 0)
    assert posterior.ticks.tolist() == [1, 2, 4]
    assert posterior.row_at(3) == 1 and posterior.row_at(0) is None
    assert posterior.as_dict(2) == {
        "cereal_box": pytest.approx(0.35),
        "banana": pytest.approx(0.65),
    }


@pytest.mark.parametrize("goal", ["banana", "my mug", "a p=0.5 b", "ünï/cödé"])
def test_commit_lines_round_trip(goal: str) -> None:
    assert parse_commit(commit_text(goal, 0.912345)) == (goal, 0.912345, "inferred")


@pytest.mark.parametrize(
    "text",
    [
        "commit goal=x",
        "commit goal= p=",
        "commit goal=x p=abc",
        "commit goal=x p=nan",
        "cancel goal=x p=0.5",
        "",
    ],
)
def test_other_lines_are_not_commits(text: str) -> None:
    assert parse_commit(text) is None


def test_entity_paths_without_rerun_internals(single: tuple[Path, int | None]) -> None:
    paths = entity_paths(single[0])
    assert {"world/ee", "log", "meta/goals", "plots/posterior/banana"} <= paths
    assert not any(p.startswith(("/", "__")) for p in paths)


def test_stages_are_read_separately(two_stages: Path, first: Episode, second: Episode) -> None:
    stages = read_stages(two_stages)
    assert [(s.index, s.name) for s in stages] == [(0, "s0"), (1, "s1")]
    assert read_goals(two_stages).names == second.goals.names  # default: the last stage
    assert read_goals(two_stages, 0).names == first.goals.names
    assert read_goals(two_stages, "s1").names == second.goals.names
    assert read_goals(two_stages, -2).names == first.goals.names
    assert read_params(two_stages, "s0") == PARAMS
    assert read_params(two_stages) == Params()
    n0 = len(first.positions)
    a, b = read_ee_path(two_stages, 0), read_ee_path(two_stages, "s1")
    assert a.ticks.tolist() == list(range(n0))
    assert b.ticks.tolist() == list(range(n0, n0 + len(second.positions)))
    np.testing.assert_array_equal(b.positions, second.positions)
    assert len(read_ee_path(two_stages).ticks) == n0 + len(second.positions)
    later = read_text_log(two_stages, 1)
    assert later and later == read_text_log(two_stages)[-len(later) :]
    assert all(t >= n0 for t, _, _ in read_text_log(two_stages, 1))


@pytest.mark.parametrize(
    ("stage", "needle"), [(2, "no stage 2"), (-3, "no stage -3"), ("s9", "no stage is named 's9'")]
)
def test_an_unknown_stage_is_an_input_error(
    two_stages: Path, stage: int | str, needle: str
) -> None:
    with pytest.raises(InputError, match=needle) as err:
        read_goals(two_stages, stage)
    message = str(err.value)
    assert str(two_stages) in message
    assert "0=s0, 1=s1" in message or "(0..1)" in message


NAMES = ["pick", "sort", "pick", "sort", None, "done"]


@pytest.mark.parametrize(
    ("key", "index"),
    [(3, 3), (-1, 5), ("-2", 4), ("4", 4), ("pick#1", 0), ("sort#2", 3), ("done", 5),
     ("done#1", 5)],
)  # fmt: skip
def test_a_stage_is_addressed_by_index_or_label(key: int | str, index: int) -> None:
    assert stage_labels(NAMES) == ["pick#1", "sort#1", "pick#2", "sort#2", "4", "done"]
    assert select_index(NAMES, key, "rec.rrd") == index


@pytest.mark.parametrize(
    ("key", "message"),
    [
        ("sort", "rec.rrd: stage: 2 stages are named 'sort' (1=sort#1, 3=sort#2): give the "
                 "index or NAME#K"),
        ("sort#3", "rec.rrd: stage: no stage 'sort#3': 2 stage(s) named 'sort' (#1..#2)"),
        ("nope", "rec.rrd: stage: no stage is named 'nope'; stages: 0=pick#1, 1=sort#1, "
                 "2=pick#2, 3=sort#2, 4=4, 5=done"),
        (6, "rec.rrd: stage: no stage 6; the recording has 6 (0..5)"),
    ],
)  # fmt: skip
def test_an_ambiguous_or_unknown_stage_is_one_line_with_the_choices(
    key: int | str, message: str
) -> None:
    with pytest.raises(InputError) as err:
        select_index(NAMES, key, "rec.rrd")
    assert str(err.value) == message


def test_a_single_candidate_stage_has_no_goal_set(tmp_path: Path, first: Episode) -> None:
    path = tmp_path / "single.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, first, "choose")
        log.log_setup(
            scene=first.scene,
            goals=["banana"],
            goal_objects={"banana": "banana"},
            planned=first.scene.default_layout(),
            p_thresh=0.9,
            params_json=json.dumps(PARAMS.as_dict()),
            stage="take",
        )
        log.log_tick(TickSnapshot(0, 0.0, **tick_kwargs(first, 0, None)))
    a, b = read_stages(path)
    assert (a.inference, a.candidates) == (True, first.goals.names)
    assert (b.name, b.inference, b.goals, b.candidates) == ("take", False, None, ("banana",))
    assert b.params == PARAMS and b.goal_objects == {"banana": "banana"}
    assert read_posterior(path, 1).goals == ()
    with pytest.raises(InputError, match="stage 1 \\(take\\) has a single candidate"):
        read_goals(path)
    assert read_goals(path, "choose").names == first.goals.names


def test_a_recording_without_ticks(tmp_path: Path, first: Episode) -> None:
    path = tmp_path / "setup-only.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, first)
    path_ = read_ee_path(path)
    assert path_.positions.shape == (0, 3) and path_.quaternions.shape == (0, 4)
    assert read_text_log(path) == []


def test_ticks_before_the_first_setup_belong_to_no_stage(tmp_path: Path, first: Episode) -> None:
    path = tmp_path / "early.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        log.log_tick(TickSnapshot(0, 0.0, **tick_kwargs(first, 0, None)))
        setup(log, first)
        log.log_tick(TickSnapshot(1, 0.05, **tick_kwargs(first, 1, None)))
    assert read_ee_path(path).ticks.tolist() == [0, 1]
    assert read_ee_path(path, 0).ticks.tolist() == [1]


def _error(path: Path) -> str:
    with pytest.raises(InputError) as err:
        read_goals(path)
    message = str(err.value)
    assert str(path) in message and "\n" not in message
    return message


def test_read_errors_name_the_file(tmp_path: Path) -> None:
    assert "no such file" in _error(tmp_path / "missing.rrd")
    assert "folder" in _error(tmp_path)
    text = tmp_path / "text.rrd"
    text.write_text(json.dumps({"not": "rrd"}))
    assert "not a readable rerun recording" in _error(text)
    truncated = tmp_path / "truncated.rrd"
    other = tmp_path / "other.rrd"
    stream = rr.RecordingStream("someone-else")
    stream.save(other)
    stream.log("points", rr.Points3D([[0, 0, 0]]))
    stream.disconnect()
    assert "no legws telemetry (meta/goals)" in _error(other)
    truncated.write_bytes(other.read_bytes()[:-200])
    assert "not a readable rerun recording" in _error(truncated)
    alien = tmp_path / "alien.rrd"
    stream = rr.RecordingStream("someone-else")
    stream.save(alien)
    stream.log("meta/goals", rr.TextDocument("hello"), static=True)
    stream.disconnect()
    assert "not legws telemetry" in _error(alien)


_CRASH = """
import os, signal, sys
from legws_daemon.telemetry.rerun_log import RerunLog
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.telemetry.helpers import setup, straight_episode, tick_kwargs

ep = straight_episode()
log = RerunLog("save:" + sys.argv[1], robot="r")
setup(log, ep)
for k in range(20):
    log.log_tick(TickSnapshot(k, k * 0.05, **tick_kwargs(ep, k, None)))
log.flush()
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.slow
def test_a_crashed_recording_without_footer_is_still_read(tmp_path: Path) -> None:
    path = tmp_path / "crashed.rrd"
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run(
        [sys.executable, "-c", _CRASH, str(path)], cwd=root, timeout=60, check=False
    )
    assert proc.returncode == -signal.SIGKILL
    assert verify(path).returncode != 0  # no footer: `rerun rrd verify` refuses it
    assert read_ee_path(path).ticks.tolist() == list(range(20))
    assert read_goals(path).names == ("cereal_box", "banana")
