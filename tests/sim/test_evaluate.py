"""The person's metrics of ``legws eval`` (method.md §9): commit on the true goal per goal,
wrong commits, the Kaplan–Meier median with its censoring, bootstrap intervals over layouts
and optimisation runs, N picks per goal, and the verified elites of run folders."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.cli.main import run
from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.layout_file import layout_to_data
from legws_daemon.sim.evaluate import (
    INTERVAL_KEYS,
    GroupStats,
    load_elites,
    markdown,
    random_layouts,
    run_eval,
)
from legws_daemon.sim.protocol import TIMEOUT_S, PickResult, km_sample, metrics
from legws_daemon.sim.statistics import bootstrap_ci
from tests.cli.helpers import Result, assert_bad_input

#: Hand-made picks: (goal, what happened).
PICKS = [
    # a: an inferred commit on the true goal at 2 s
    PickResult("a", True, "a", 2.0, None, "a", True, 9.0, duration=20.0, decision_time=2.0),
    # a: no commit, the user confirmed at the grasp after 6 s
    PickResult("a", True, None, None, "a", "a", True, 12.0, duration=20.0, decision_time=6.0),
    # a: a wrong commit at 1 s
    PickResult(
        "a",
        True,
        "b",
        1.0,
        None,
        "b",
        False,
        None,
        "wrong_commit",
        "acted on 'b'",
        duration=1.0,
        decision_time=1.0,
    ),
    # b: an inferred commit at 4 s
    PickResult("b", True, "b", 4.0, None, "b", True, 10.0, duration=18.0, decision_time=4.0),
    # b: nothing within the limit
    PickResult(
        "b",
        True,
        None,
        None,
        None,
        "a",
        False,
        None,
        "no_commit",
        "",
        duration=TIMEOUT_S,
        decision_time=TIMEOUT_S,
    ),
    # b: the only feasible candidate, taken at once (no inference, no time)
    PickResult("b", True, "b", None, None, "b", True, 5.0, duration=15.0, decision_time=0.0),
    # c: infeasible, no episode
    PickResult("c", False, failure="infeasible_grasp", detail="out of reach"),
]


def test_metrics_as_the_person_sees_them() -> None:
    m = metrics(PICKS)
    assert m["episodes"] == 7
    # commits on the true goal: a's first, b's inferred one and b's single candidate
    assert m["commit_true_rate"] == pytest.approx(3 / 7)
    assert m["single_commit_rate"] == pytest.approx(1 / 7)
    assert m["commit_rate_by_goal"] == pytest.approx({"a": 1 / 3, "b": 2 / 3, "c": 0.0})
    assert list(m["commit_rate_by_goal"]) == ["a", "b", "c"]
    assert m["commit_rate_min_goal"] == 0.0  # c never: its grasp is infeasible
    assert m["wrong_commit_rate"] == pytest.approx(1 / 7)
    assert m["commit_rate"] == pytest.approx(4 / 7)  # the paper's: wrong and single included
    assert m["t_infer_mean"] == pytest.approx((2 + 1 + 4) / 3)  # timed commits, wrong included
    # KM subjects: the five picks with inference (not the infeasible one, not the single one):
    # 2 event, 4 event, 6 censored (confirmed), 30 censored (wrong commit), 30 censored
    # (timeout) -> S(2) = 4/5, S(4) = 4/5 * 3/4 = 0.6: never half, the median is beyond 30 s
    assert km_sample(PICKS) == ([2.0, 6.0, TIMEOUT_S, 4.0, TIMEOUT_S],
                                [True, False, False, True, False])  # fmt: skip
    assert m["t_infer_km_picks"] == 5 and m["t_infer_km_events"] == 2
    assert m["t_infer_km_median"] is None
    assert m["t_infer_km_max_time"] == TIMEOUT_S
    # were the wrong commit censored at its own 1 s, it would leave the risk set before the
    # first event, as if it had not been picked, and the median would be reached:
    # 2 E (3/4), 4 E (3/4 * 2/3 = 1/2)
    assert metrics(PICKS[:2] + PICKS[3:])["t_infer_km_median"] == 4.0
    json.dumps(m, allow_nan=False)


def test_km_censors_a_confirmation_at_the_end_of_steering_not_of_the_pick() -> None:
    picks = [
        PickResult("a", True, "a", 5.0, None, "a", True, 9.0, duration=20.0, decision_time=5.0),
        PickResult("a", True, "a", 5.5, None, "a", True, 9.0, duration=20.0, decision_time=5.5),
        # confirmed at 3 s, the pick (assistance, the way home) ran 20 s
        PickResult("b", True, None, None, "b", "b", True, 9.0, duration=20.0, decision_time=3.0),
    ]
    # censored at 3: 5 has two at risk -> 1/2 -> median 5 (at 20 s it would be 5.5)
    assert metrics(picks)["t_infer_km_median"] == 5.0
    m = metrics(picks[2:])
    assert m["t_infer_km_median"] is None and m["t_infer_km_picks"] == 1
    empty = metrics([])
    assert empty["commit_true_rate"] is None and empty["commit_rate_min_goal"] is None
    assert empty["t_infer_km_median"] is None and empty["t_infer_km_max_time"] is None


def _as_float(x: float | None) -> float:
    return math.nan if x is None else x


def test_group_statistics_are_the_metrics_of_the_pooled_picks() -> None:
    groups = [PICKS[:3], PICKS[3:6], PICKS[6:]]
    stats = GroupStats(groups)
    counts = np.array([[1.0, 1.0, 1.0], [2.0, 0.0, 1.0], [0.0, 3.0, 0.0], [0.0, 0.0, 3.0]])
    got = stats.statistics(counts)
    for b, drawn in enumerate(([0, 1, 2], [0, 0, 2], [1, 1, 1], [2, 2, 2])):
        m = metrics([p for g in drawn for p in groups[g]])
        for key in INTERVAL_KEYS:
            if key == "t_infer_km_median" and m[key] is None and m["t_infer_km_picks"]:
                assert got[key][b] == math.inf, (drawn, key)  # not reached
            else:
                np.testing.assert_allclose(got[key][b], _as_float(m[key]), err_msg=f"{drawn} {key}")
    # only the infeasible group: nothing timed, no KM subject -> undefined, not "not reached"
    assert math.isnan(got["t_infer_km_median"][3]) and math.isnan(got["t_infer_mean"][3])
    iv = stats.intervals([0], n=400)
    assert set(iv) == set(INTERVAL_KEYS)
    lo, hi = iv["commit_true_rate"] or (None, None)
    assert lo is not None and hi is not None and lo <= 3 / 7 <= hi and lo < hi
    assert iv == stats.intervals([0], n=400)
    # the same resamples as the generic bootstrap recomputing metrics() on the drawn groups
    for key in ("commit_true_rate", "commit_rate_min_goal", "wrong_commit_rate", "t_infer_mean"):

        def of(drawn: Sequence[Sequence[PickResult]], key: str = key) -> float | None:
            value: float | None = metrics([p for g in drawn for p in g])[key]
            return value

        ci = bootstrap_ci(groups, of, np.random.default_rng([0]), n=400)
        assert ci is not None
        assert iv[key] == pytest.approx(list(ci)), key
    assert GroupStats([PICKS]).intervals([0], n=50)["accuracy"] is None  # one group


def test_episodes_per_goal_on_the_default_layout() -> None:
    sc = load_scene("breakfast_easy")
    report = run_eval(sc, [sc.default_layout()], 0, workers=1, episodes_per_goal=2)
    m = len(sc.goal_names)
    a = report["aggregate"]
    assert report["episodes_per_goal"] == 2
    assert a["episodes"] == 2 * m
    assert set(a["commit_rate_by_goal"]) == set(sc.goal_names)
    assert a["commit_rate_min_goal"] <= a["commit_true_rate"] <= a["commit_rate"]
    assert a["commit_true_rate"] + a["wrong_commit_rate"] == pytest.approx(a["commit_rate"])
    assert a["t_infer_km_picks"] == 2 * m - a["infeasible_picks"] - round(
        a["single_commit_rate"] * 2 * m
    )
    assert a["t_infer_km_events"] <= a["t_infer_km_picks"]
    if a["t_infer_km_events"] == a["t_infer_km_picks"]:
        assert a["t_infer_km_median"] is not None
        assert a["t_infer_km_median"] <= a["t_infer_km_max_time"]
    # one layout: no spread to resample
    assert report["aggregate"]["intervals"]["layouts"]["groups"] == 1
    assert all(report["aggregate"]["intervals"]["layouts"][k] is None for k in INTERVAL_KEYS)
    json.dumps(report, allow_nan=False)
    text = markdown(report)
    assert "2 picks per goal" in text and "T_infer KM median" in text


def test_episodes_per_goal_picks_each_goal_n_times_from_home_with_decision_times() -> None:
    from legws_daemon.sim.protocol import Evaluator

    sc = load_scene("kitchen_prep")
    ev = Evaluator(sc)
    result = ev.evaluate(sc.default_layout(), [0, 0], episodes_per_goal=3)
    assert len(result.picks) == 3 * len(sc.goal_names)
    for goal in sc.goal_names:
        assert sum(p.true_goal == goal for p in result.picks) == 3
    for p in result.picks:
        assert p.decision_time is not None and p.decision_time <= p.duration
        if p.commit_time is not None:
            assert p.decision_time == p.commit_time
    again = ev.evaluate(sc.default_layout(), [0, 0], episodes_per_goal=3)
    assert again.picks == result.picks
    with pytest.raises(InputError, match="episodes_per_goal must be >= 1"):
        ev.evaluate(sc.default_layout(), 0, episodes_per_goal=0)


def _elite(layout: Any, rank: int, verified: bool, objective: float = 0.5) -> dict[str, Any]:
    return {"rank": rank, "layout": layout_to_data(layout), "objective": objective,
            "verified": verified}  # fmt: skip


def _run_folder(path: Path, elites: list[dict[str, Any]]) -> Path:
    path.mkdir(parents=True)
    (path / "elites.json").write_text(json.dumps(elites))
    return path


def test_load_elites_takes_the_best_verified(tmp_path: Path) -> None:
    sc = load_scene("breakfast_easy")
    layouts = random_layouts(sc, 3, seed=2)
    elites = [
        _elite(layouts[0], 0, False, 0.2),
        _elite(layouts[1], 1, True, 0.4),
        _elite(layouts[2], 2, True, 0.7),
    ]
    run_dir = _run_folder(tmp_path / "run", elites)
    got = load_elites(run_dir, sc, 2)
    assert [layout_to_data(layout) for layout, _ in got] == [
        layout_to_data(layouts[1]),
        layout_to_data(layouts[2]),
    ]
    assert [(e.rank, e.position, e.objective) for _, e in got] == [(1, 1, 0.4), (2, 2, 0.7)]
    with pytest.raises(InputError, match=r"2 verified elites, --top-k asks for 3"):
        load_elites(run_dir, sc, 3)
    # a run folder without elites.json: K = 1 reads best_layout.json
    old = tmp_path / "old"
    old.mkdir()
    (old / "best_layout.json").write_text(json.dumps(layout_to_data(layouts[0])))
    (old / "summary.json").write_text(json.dumps({"objective": 0.3, "verified_rank": 4}))
    [(layout, e)] = load_elites(old, sc, 1)
    assert layout_to_data(layout) == layout_to_data(layouts[0])
    assert (e.rank, e.position, e.objective) == (4, 1, 0.3)
    with pytest.raises(InputError, match=r"no elites\.json"):
        load_elites(old, sc, 2)
    bad = _run_folder(tmp_path / "bad", [{"rank": 0, "layout": {}, "verified": "yes"}])
    with pytest.raises(InputError, match=r"elites.json:1: \[0\].verified"):
        load_elites(bad, sc, 1)


def test_elites_of_several_runs_give_intervals_over_runs(tmp_path: Path) -> None:
    sc = load_scene("breakfast_easy")
    layouts = random_layouts(sc, 6, seed=4)
    runs = [
        _run_folder(
            tmp_path / f"seed{i}",
            [_elite(layouts[2 * i], 0, True), _elite(layouts[2 * i + 1], 3, True)],
        )
        for i in range(3)
    ]
    out = tmp_path / "out"
    code = run(["eval", "--scene", "breakfast_easy", "--layouts", ",".join(map(str, runs)),
                "--top-k", "2", "--episodes-per-goal", "1", "--workers", "1", "--quiet",
                "--out", str(out)])  # fmt: skip
    assert code == 0
    report = json.loads((out / "eval.json").read_text())
    assert report["layouts"] == 6 and report["runs"] == [str(r) for r in runs]
    assert [row["elite_position"] for row in report["per_layout"]] == [1, 2] * 3
    assert [row["elite_rank"] for row in report["per_layout"]] == [0, 3] * 3
    assert [b["position"] for b in report["by_elite"]] == [1, 2]
    assert sum(b["episodes"] for b in report["by_elite"]) == report["aggregate"]["episodes"]
    iv = report["aggregate"]["intervals"]
    assert iv["layouts"]["groups"] == 6 and iv["runs"]["groups"] == 3
    assert set(iv["runs"]) == {"groups", *INTERVAL_KEYS}
    text = (out / "eval.md").read_text()
    assert "| runs (3) |" in text and "Per elite" in text and "seed1, 2 |" in text


def test_eval_command_with_episodes_per_goal(capsys: pytest.CaptureFixture[str]) -> None:
    code = run(["eval", "--scene", "breakfast_easy", "--layouts", "random:1",
                "--episodes-per-goal", "1", "--workers", "1", "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert "1 picks per goal" in out and "| layouts (1) |" in out


def _call(capsys: pytest.CaptureFixture[str], *argv: str) -> Result:
    capsys.readouterr()
    code = run(list(argv))
    captured = capsys.readouterr()
    return Result(code, captured.out, captured.err)


def test_eval_rejects_a_bad_top_k(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sc = load_scene("breakfast_easy")
    layout = random_layouts(sc, 1, seed=0)[0]
    run_dir = _run_folder(tmp_path / "run", [_elite(layout, 0, True)])
    base = ("eval", "--scene", "breakfast_easy", "--quiet", "--workers", "1")
    assert_bad_input(_call(capsys, *base, "--layouts", str(run_dir), "--top-k", "0"), "--top-k")
    assert_bad_input(
        _call(capsys, *base, "--layouts", "random:1", "--top-k", "2"), "--top-k", "run folders"
    )
    assert_bad_input(
        _call(capsys, *base, "--layouts", str(run_dir), "--top-k", "2"),
        "elites.json", "1 verified elites, --top-k asks for 2",
    )  # fmt: skip
    layout_file = tmp_path / "layout.json"
    layout_file.write_text(json.dumps(layout_to_data(layout)))
    assert_bad_input(
        _call(capsys, *base, "--layouts", f"{run_dir},{layout_file}"), "--layouts", "mixed"
    )
    assert_bad_input(
        _call(capsys, *base, "--layouts", "random:1", "--episodes-per-goal", "0"),
        "--episodes-per-goal",
    )


def test_eval_json_summarises_the_value_of_the_help(capsys: pytest.CaptureFixture[str]) -> None:
    summaries = {}
    for assist in ("commit", "blend"):
        result = _call(capsys, "eval", "--scene", "desk", "--layouts", "random:1",
                       "--episodes-per-goal", "1", "--workers", "1", "--quiet", "--json",
                       "--assist", assist)  # fmt: skip
        assert result.code == 0, result.err
        report = json.loads(result.out)
        assert report["assist"] == report["aggregate"]["assist"] == assist
        summaries[assist] = s = report["summary"]
        assert s["assist"] == assist
        for key in ("time_to_grasp_s", "time_to_task_s", "effort", "robot_share", "completion"):
            assert isinstance(s[key], float), key
        assert 0 < s["time_to_grasp_s"] < s["time_to_task_s"]
        assert 0.0 < s["robot_share"] < 1.0  # the assistance drove part of every approach
        assert s["completion"] == s["completed"] / s["acted_on"]
        assert s["wrong_grasps"] == 0 and s["overrides"] == 0
    # the same picks (seeded): the blend's robot drove more of the approach and the
    # operator pushed less (how much sooner, if at all: docs/benchmarks.md)
    commit, blend = summaries["commit"], summaries["blend"]
    assert blend["robot_share"] > commit["robot_share"]
    assert blend["effort"] < commit["effort"]


def test_without_assistance_the_simulated_operator_picks_by_hand() -> None:
    from legws_daemon.sim.protocol import Evaluator

    sc = load_scene("desk")
    ev = Evaluator(sc, assist="none")
    picks = [p for p in ev.evaluate(sc.default_layout(), [0, 0], 2).picks if p.feasible]
    assert picks
    for p in picks:
        assert p.completed and p.grasped == p.true_goal, p
        assert p.committed is None and p.confirmed is None  # nothing assisted
        assert p.robot_share == 0.0 and p.robot_distance == 0.0
        assert p.grasp_time is not None and p.complete_time is not None
        assert p.grasp_time < p.complete_time == p.duration  # the pick ends lifted
    m = metrics(picks)
    assert m["completion"] == 1.0 and m["counts"]["acted_on"] == len(picks)
    assert [e.kind for e in ev.events] == []  # no commit, no warning


def test_pick_results_time_the_grasp_and_split_the_approach() -> None:
    from legws_daemon.sim.protocol import Evaluator

    sc = load_scene("desk")
    for assist in ("commit", "hindsight"):
        picks = Evaluator(sc, assist=assist).evaluate(sc.default_layout(), [0, 0], 1).picks
        for p in picks:
            if not p.feasible:
                continue
            assert p.completed and p.grasped == p.true_goal and not p.wrong_grasp
            assert p.grasp_time is not None and p.complete_time is not None
            assert p.grasp_time < p.complete_time <= p.duration
            assert 0.0 < p.effort <= p.duration  # |u| <= 1
            share = p.robot_share
            assert share is not None and 0.0 < share < 1.0
