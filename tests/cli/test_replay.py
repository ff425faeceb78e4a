"""``legws replay``: the observer re-run on a recorded EE path, its report and its errors."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import rerun as rr

from legws_daemon.formats.log_lines import commit_text
from legws_daemon.telemetry.rerun_log import RerunLog
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.cli.helpers import Result, assert_bad_input
from tests.telemetry.helpers import log_episode, record, straight_episode, tick_kwargs

Cli = Callable[..., Result]


@pytest.fixture(scope="module")
def banana(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """A straight reach to the banana of breakfast_easy, the daemon committing on the way."""
    path = tmp_path_factory.mktemp("replay") / "banana.rrd"
    (commit,) = record(path, straight_episode("breakfast_easy", "banana"))
    assert commit is not None
    return path, commit


@pytest.fixture(scope="module")
def two_stages(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("replay") / "two.rrd"
    record(
        path,
        straight_episode("breakfast_easy", "banana"),
        straight_episode("breakfast_easy", "cereal_box"),
    )
    return path


def _report(cli: Cli, *argv: str | Path) -> dict[str, Any]:
    result = cli("replay", *argv, "--json")
    assert result.code == 0, result
    assert result.err == ""
    report: dict[str, Any] = json.loads(result.out)
    return report


def test_replay_commits_on_the_goal_reached(cli: Cli, banana: tuple[Path, int]) -> None:
    path, commit_tick = banana
    report = _report(cli, path)
    assert report["recording"] == str(path)
    (stage,) = report["stages"]
    commit = stage["commit"]
    assert commit["goal"] == "banana"
    assert commit["tick"] == commit_tick
    assert commit["time"] == pytest.approx(commit_tick * 0.05)
    assert commit["p"] >= 0.9
    assert stage["recorded_commit"]["goal"] == "banana"
    assert stage["recorded_commit"]["tick"] == commit_tick
    assert stage["agrees"] is True
    assert commit["posterior"]["banana"] == commit["p"]
    assert sum(commit["posterior"].values()) == pytest.approx(1.0)
    assert stage["recorded_commit"]["how"] == "inferred"
    assert stage["recorded_commit"]["recorded_posterior"] == commit["posterior"]
    assert stage["recorded_commit"]["replayed_posterior"] == commit["posterior"]
    assert stage["mismatches"] == []
    assert stage["params"] == stage["recorded_params"]
    assert "final_posterior" not in stage


def test_a_higher_threshold_does_not_commit_by_the_end_of_inference(
    cli: Cli, banana: tuple[Path, int], two_stages: Path
) -> None:
    """The replay is fed up to the daemon's commit, not the arm's motion after it."""
    path, commit_tick = banana
    (stage,) = _report(cli, path, "--threshold", "0.99")["stages"]
    assert stage["params"]["p_thresh"] == 0.99
    assert stage["recorded_params"]["p_thresh"] == 0.9
    assert stage["commit"] is None
    assert stage["replayed_samples"] == commit_tick + 1  # ticks 0..commit
    end = stage["end_of_inference"]
    assert (end["tick"], end["cause"]) == (commit_tick, "commit")
    assert end["replayed_posterior"] == stage["recorded_commit"]["recorded_posterior"]
    lower = _report(cli, path, "--threshold", "0.8")["stages"][0]["commit"]
    assert lower["goal"] == "banana" and lower["tick"] < commit_tick
    cereal = _report(cli, two_stages, "--stage", "s1", "--threshold", "0.99")["stages"]
    assert cereal[0]["commit"] is None
    assert cereal[0]["recorded_commit"]["goal"] == "cereal_box"
    assert cereal[0]["agrees"] is None


def test_overrides_reach_the_observer(cli: Cli, banana: tuple[Path, int]) -> None:
    path, commit_tick = banana
    (stage,) = _report(cli, path, "--beta", "20", "--cost", "ratio")["stages"]
    assert (stage["params"]["beta"], stage["params"]["cost"]) == (20.0, "ratio")
    assert stage["commit"]["goal"] == "banana"
    assert stage["commit"]["tick"] != commit_tick  # a sharper, different observer


def test_every_stage_is_replayed(cli: Cli, two_stages: Path) -> None:
    stages = _report(cli, two_stages)["stages"]
    assert [(s["index"], s["name"]) for s in stages] == [(0, "s0"), (1, "s1")]
    assert [s["commit"]["goal"] for s in stages] == ["banana", "cereal_box"]
    assert stages[1]["first_tick"] == stages[0]["last_tick"] + 1
    assert [s["index"] for s in _report(cli, two_stages, "--stage", "1")["stages"]] == [1]


def test_text_report(cli: Cli, banana: tuple[Path, int]) -> None:
    path, commit_tick = banana
    result = cli("replay", path)
    assert result.code == 0 and result.err == ""
    assert f"replayed commit: banana at tick {commit_tick} (" in result.out
    assert f"recorded commit: banana at tick {commit_tick} (" in result.out
    assert "(inferred) (same goal)" in result.out
    assert "posterior at the commit: cereal_box 0.1" in result.out
    assert f"recorded posterior at tick {commit_tick}: cereal_box 0.1" in result.out
    assert "final posterior" not in result.out
    assert f"up to the end of inference at tick {commit_tick} " in result.out
    assert "posterior at the end of inference" not in result.out  # both committed


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["--beta", "0"], ["--beta", "got 0.0"]),
        (["--beta", "-1"], ["--beta"]),
        (["--beta", "nan"], ["--beta"]),
        (["--beta", "1e9"], ["--beta"]),
        (["--threshold", "0.5"], ["--threshold", "(0.5, 1)"]),
        (["--threshold", "1"], ["--threshold", "(0.5, 1)"]),
        (["--threshold", "0.2"], ["--threshold"]),
        (["--threshold", "inf"], ["--threshold"]),
        (["--threshold", "x"], ["--threshold"]),
        (["--cost", "linear"], ["--cost", "dragan"]),
        (["--stage", "7"], ["stage", "no stage 7"]),
        (["--stage", "nope"], ["stage", "'nope'", "0=s0"]),
    ],
)
def test_bad_options_exit_2(
    cli: Cli, banana: tuple[Path, int], argv: list[str], needles: list[str]
) -> None:
    assert_bad_input(cli("replay", banana[0], *argv), *needles)


def test_bad_recordings_exit_2(cli: Cli, tmp_path: Path) -> None:
    missing = tmp_path / "missing.rrd"
    assert_bad_input(cli("replay", missing), str(missing), "no such file")
    text = tmp_path / "notes.rrd"
    text.write_text("hello")
    assert_bad_input(cli("replay", text), str(text), "not a readable rerun recording")
    other = tmp_path / "other.rrd"
    stream = rr.RecordingStream("someone-else")
    stream.save(other)
    stream.log("points", rr.Points3D([[0, 0, 0]]))
    stream.disconnect()
    assert_bad_input(cli("replay", other), str(other), "no legws telemetry")
    assert_bad_input(cli("replay"), "RECORDING")


@pytest.fixture(scope="module")
def older(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """A session as a legws before single-candidate stages were set up recorded it: a
    decision on the banana, then a single candidate (the bowl) whose commit and samples
    are logged in the banana's stage, then the banana again."""
    path = tmp_path_factory.mktemp("replay") / "older.rrd"
    ep = straight_episode("breakfast_easy", "banana")
    n = len(ep.positions)
    with RerunLog(f"save:{path}", robot="sawyer-sim") as log:
        log_episode(log, ep, tick0=0, stage="choose")
        log.log_text(n, n * 0.05, "INFO", "stage_done stage=choose goal=banana action=pick")
        log.log_text(n, n * 0.05, "INFO", commit_text("bowl", 1.0, how="single"))
        for k in range(10):
            log.log_tick(TickSnapshot(n + k, (n + k) * 0.05, **tick_kwargs(ep, k, None)))
        log.log_text(n + 9, (n + 9) * 0.05, "INFO", "stage_done stage=into goal=bowl action=place")
        log_episode(log, ep, tick0=n + 10, stage="choose")
    return path, n


def test_a_single_candidate_of_an_older_recording_is_a_stage_of_its_own(
    cli: Cli, older: tuple[Path, int]
) -> None:
    path, n = older
    stages = _report(cli, path)["stages"]
    assert [(s["index"], s["label"], s["inference"], s["set_up"]) for s in stages] == [
        (0, "choose#1", True, True),
        (1, "into", False, False),
        (2, "choose#2", True, True),
    ]
    first, single, _ = stages
    assert first["last_tick"] == n - 1 and [c["goal"] for c in first["recorded_commits"]] == [
        "banana"
    ]
    assert (single["first_tick"], single["last_tick"], single["samples"]) == (n, n + 9, 10)
    assert single["candidates"] == ["bowl"] and single["recorded_stage"] == 0
    (commit,) = single["recorded_commits"]
    assert (commit["goal"], commit["how"], commit["recorded_posterior"]) == ("bowl", "single", None)
    text = cli("replay", path, "--stage", "into").out
    assert "Stage 1 into (scene breakfast_easy): a single candidate, bowl: no inference" in text
    assert "made by an older legws: its commit is in stage 0's log" in text


def test_a_repeated_name_is_addressed_by_index_or_name_and_number(
    cli: Cli, older: tuple[Path, int]
) -> None:
    path, _ = older
    assert [s["index"] for s in _report(cli, path, "--stage", "choose#2")["stages"]] == [2]
    assert [s["index"] for s in _report(cli, path, "--stage", "-1")["stages"]] == [2]
    assert [s["index"] for s in _report(cli, path, "--stage", "into")["stages"]] == [1]
    result = cli("replay", path, "--stage", "choose")
    assert_bad_input(result, "2 stages are named 'choose' (0=choose#1, 2=choose#2)", "NAME#K")
    assert_bad_input(cli("replay", path, "--stage", "choose#3"), "'choose#3'", "(#1..#2)")
