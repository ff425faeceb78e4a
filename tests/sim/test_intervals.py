"""Intervals on rates: where every pick succeeded (or none did) the percentile bootstrap cannot
leave 100 % (0 %), so the rate gets the Clopper–Pearson bound on its k of n picks; every other
rate keeps the bootstrap over groups. Checked on real reports of ``run_eval`` (its own
aggregation, intervals and Markdown) over hand-made picks."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.core.montecarlo import clopper_pearson
from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.sim import evaluate
from legws_daemon.sim.evaluate import (
    GroupStats,
    counts_of,
    format_rate,
    group_intervals,
    interval_seed,
    markdown,
    outward_percent,
    rate_intervals,
    run_eval,
)
from legws_daemon.sim.protocol import PickResult, metrics
from legws_daemon.sim.statistics import rate_interval, ratio_interval

SCENE = "breakfast_easy"


def _pick(goal: str, commit: bool = True, completed: bool = True) -> PickResult:
    """A pick that ran: an inferred commit on the true goal at 5 s, or (``commit=False``) the
    user's confirmation at the grasp; completed or stopped by ``assist_failed``."""
    failure = None if completed else "assist_failed"
    if commit:
        return PickResult(goal, True, goal, 5.0, None, goal, completed, 9.0 if completed else None,
                          failure, "", 20.0, 5.0)  # fmt: skip
    return PickResult(goal, True, None, None, goal, goal, completed,
                      12.0 if completed else None, failure, "", 25.0, 14.0)  # fmt: skip


def _layout_picks(
    goals: Sequence[str], per_goal: int, commits: int, failed: int = 0
) -> list[PickResult]:
    """``per_goal`` picks of every goal, the first ``commits`` of each with a commit (the
    others confirmed), the last ``failed`` of each not completed."""
    return [
        _pick(g, commit=i < commits, completed=i < per_goal - failed)
        for g in goals
        for i in range(per_goal)
    ]


def _report(
    monkeypatch: pytest.MonkeyPatch, picks: Sequence[list[PickResult]], **kwargs: Any
) -> dict[str, Any]:
    """``run_eval``'s report, its picks per layout given instead of simulated."""
    sc = load_scene(SCENE)

    def fake(job: evaluate.Job) -> tuple[int, dict[str, Any], list[PickResult]]:
        return job[0], {"infeasible": {}}, picks[job[0]]

    monkeypatch.setattr(evaluate, "_init_worker", lambda *_: None)
    monkeypatch.setattr(evaluate, "_evaluate", fake)
    report = run_eval(sc, [sc.default_layout()] * len(picks), 0, workers=1, resamples=500,
                      **kwargs)  # fmt: skip
    json.dumps(report, allow_nan=False)
    return report


@given(st.floats(0.0, 1.0), st.integers(0, 3))
def test_a_bound_is_rounded_away_from_the_rate_it_bounds(x: float, digits: int) -> None:
    """A printed lower bound never exceeds the bound, an upper one is never below it, and
    neither is farther from it than one unit of the last digit."""
    low = float(outward_percent(x, digits, "low"))
    high = float(outward_percent(x, digits, "high"))
    unit = 10.0**-digits
    assert 100 * x - unit - 1e-6 <= low <= 100 * x + 1e-6
    assert 100 * x - 1e-6 <= high <= 100 * x + unit + 1e-6
    assert outward_percent(0.9899, 1, "low") == "98.9" and outward_percent(0.99, 1, "low") == "99.0"


def test_rate_interval_is_clopper_pearson_at_0_and_100_percent_else_the_bootstrap() -> None:
    every = rate_interval(300, 300, [1.0, 1.0])
    assert every.kind == "at_least" and every.high == 1.0
    assert every.low == pytest.approx(0.025 ** (1 / 300))  # the exact bound at k = n
    assert every.low == clopper_pearson(300, 300)[0]
    assert format_rate(every) == "100.0 % [≥ 98.7]"  # 98.78: rounded outward
    none = rate_interval(0, 300, [0.0, 0.0])
    assert none.kind == "at_most" and none.low == 0.0
    assert none.high == pytest.approx(1 - 0.025 ** (1 / 300))
    assert format_rate(none) == "0.0 % [≤ 1.3]"  # 1.22: rounded outward
    assert format_rate(none, 0, 1, "") == "0 [≤ 1.3]"
    normal = rate_interval(170, 240, [0.61, 0.80])
    assert normal.kind == "bootstrap" and (normal.low, normal.high) == (0.61, 0.80)
    assert format_rate(normal) == "70.8 % [61.0, 80.0]"
    assert format_rate(normal, 0, 1, "") == "71 [61, 80]"
    # every group at the same rate: nothing to resample, no interval
    flat = rate_interval(180, 240, [0.75, 0.75])
    assert flat.kind == "no_spread" and format_rate(flat) == "75.0 % (no spread)"
    assert rate_interval(5, 10).kind == "none" and format_rate(rate_interval(5, 10)) == "50.0 %"
    assert rate_interval(0, 0).rate is None and format_rate(rate_interval(0, 0)) == "—"
    assert format_rate(None) == "—"
    # the bound does not depend on the bootstrap, and shrinks with more picks
    assert rate_interval(20, 20).low == rate_interval(20, 20, [1.0, 1.0]).low
    assert rate_interval(20, 20).low < rate_interval(300, 300).low  # type: ignore[operator]
    with pytest.raises(InputError):
        rate_interval(3, 2)


def test_a_report_where_every_pick_commits_gets_clopper_pearson_bounds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    goals = load_scene(SCENE).goal_names
    assert len(goals) == 2
    # 3 layouts x 2 goals x 50 picks: every one commits on the true goal and completes
    report = _report(monkeypatch, [_layout_picks(goals, 50, 50) for _ in range(3)])
    a = report["aggregate"]
    assert a["commit_true_rate"] == 1.0 and a["episodes"] == 300
    assert a["counts"] == {
        "picks": 300, "commit_true": 300, "wrong_commit": 0, "correct": 300, "acted_on": 300,
        "completed": 300, "goal_picks": dict.fromkeys(goals, 150),
        "goal_commit_true": dict.fromkeys(goals, 150),
        "grasped_true": 0, "wrong_grasps": 0, "overrides": 0,  # (no grasp in these picks)
    }  # fmt: skip
    # the bootstrap sits on one point, whatever the number of picks
    assert a["intervals"]["layouts"]["commit_true_rate"] == [1.0, 1.0]
    rates = rate_intervals(a, a["intervals"]["layouts"])
    commit, worst, wrong = (rates[k] for k in ("commit_true_rate", "commit_rate_min_goal",
                                                "wrong_commit_rate"))  # fmt: skip
    assert commit is not None and commit.kind == "at_least" and (commit.k, commit.n) == (300, 300)
    assert worst is not None and (worst.k, worst.n) == (150, 150)  # one goal's picks
    assert wrong is not None and wrong.kind == "at_most" and (wrong.k, wrong.n) == (0, 300)
    text = markdown(report)
    row = next(line for line in text.splitlines() if line.startswith("| layouts (3) |"))
    cells = [c.strip() for c in row.split("|")[2:-1]]
    assert cells[:5] == [
        "100.0 % [≥ 98.7]",  # commit on the true goal: 300 of 300 (98.78, outward)
        "100.0 % [≥ 97.5]",  # worst goal: 150 of 150 (97.57)
        "0.0 % [≤ 1.3]",  # wrong commit: 0 of 300 (1.22)
        "100.0 % [≥ 98.7]",  # accuracy
        "100.0 % [≥ 98.7]",  # completed, of the 300 acted on
    ]
    assert "[100.0, 100.0]" not in text and "[0.0, 0.0]" not in text
    assert "σ = 0.03 m/s" in text and "Clopper–Pearson" in text


def test_a_normal_rate_keeps_its_bootstrap_interval(monkeypatch: pytest.MonkeyPatch) -> None:
    goals = load_scene(SCENE).goal_names
    # commits on the true goal 6, 8 and 7 of 10 picks per goal; one layout's last pick of
    # every goal stops before the lift
    picks = [_layout_picks(goals, 10, 6), _layout_picks(goals, 10, 8, failed=1),
             _layout_picks(goals, 10, 7)]  # fmt: skip
    report = _report(monkeypatch, picks)
    a = report["aggregate"]
    iv = a["intervals"]["layouts"]
    lo, hi = iv["commit_true_rate"]
    assert lo < 0.7 < hi
    commit = rate_intervals(a, iv)["commit_true_rate"]
    assert (
        commit is not None and commit.kind == "bootstrap" and (commit.low, commit.high) == (lo, hi)
    )
    completion = rate_intervals(a, iv)["completion_committed"]
    assert completion is not None and completion.kind == "bootstrap"
    assert (completion.k, completion.n) == (58, 60)
    assert [completion.low, completion.high] == iv["completion_committed"]
    text = markdown(report)
    assert f"70.0 % [{100 * lo:.1f}, {100 * hi:.1f}]" in text
    assert f"96.7 % [{100 * completion.low:.1f}, {100 * completion.high:.1f}]" in text  # type: ignore[operator]
    assert "Failures: assist_failed 2." in text
    # no wrong commit in 60 picks: a bound, not [0, 0]
    assert "0.0 % [≤ 6.0]" in text


def test_every_layout_at_the_same_rate_has_no_spread(monkeypatch: pytest.MonkeyPatch) -> None:
    goals = load_scene(SCENE).goal_names
    report = _report(monkeypatch, [_layout_picks(goals, 4, 3) for _ in range(3)])
    a = report["aggregate"]
    assert a["intervals"]["layouts"]["commit_true_rate"] == [0.75, 0.75]
    assert "75.0 % (no spread)" in markdown(report)


def test_counts_of_a_report_written_before_counts_were_kept(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    goals = load_scene(SCENE).goal_names
    picks = [_layout_picks(goals, 10, 6), _layout_picks(goals, 10, 8, failed=1),
             _layout_picks(goals, 10, 0, failed=10)]  # fmt: skip
    report = _report(monkeypatch, picks)
    for m in [report["aggregate"], *report["per_layout"]]:
        old = {k: v for k, v in m.items() if k != "counts"}
        recovered = counts_of(old)  # the counts the rates tell (not the grasps': newer)
        assert recovered == {k: v for k, v in m["counts"].items() if k in recovered}
        assert set(m["counts"]) - set(recovered) == {"grasped_true", "wrong_grasps", "overrides"}
    # without per-goal rates nothing is told per goal
    bare = {
        k: v for k, v in report["aggregate"].items() if k not in ("counts", "commit_rate_by_goal")
    }
    assert counts_of(bare)["goal_picks"] == {}
    assert rate_intervals(bare, None)["commit_rate_min_goal"] is None


def test_completion_interval_of_an_old_report_is_the_one_run_eval_gives_now(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    goals = load_scene(SCENE).goal_names
    picks = [_layout_picks(goals, 10, 6, failed=2), _layout_picks(goals, 10, 8),
             _layout_picks(goals, 10, 7, failed=1), _layout_picks(goals, 10, 7)]  # fmt: skip
    runs = [evaluate.Elite(str(tmp_path / f"run{i // 2}"), 0, i % 2 + 1, None) for i in range(4)]
    report = _report(monkeypatch, picks, elites=runs)
    for group in ("layouts", "runs"):
        now = report["aggregate"]["intervals"][group]
        assert now["completion_committed"] is not None
        old = json.loads(json.dumps(report))
        del old["aggregate"]["intervals"][group]["completion_committed"]
        for row in old["per_layout"]:
            del row["counts"]
        assert group_intervals(old, group) == now, group
    # the statistic is what GroupStats computes on the same groups and resamples
    by_run = [picks[0] + picks[1], picks[2] + picks[3]]
    stats = GroupStats(by_run).intervals(interval_seed(0, "runs"), 500)
    num = [sum(p.completed for p in g) for g in by_run]
    den = [len(g) for g in by_run]
    direct = ratio_interval(num, den, np.random.default_rng(interval_seed(0, "runs")), 500)
    assert direct is not None and stats["completion_committed"] == list(direct)


def test_metrics_keep_the_counts_behind_every_rate() -> None:
    picks = [_pick("a"), _pick("a", commit=False), _pick("b", completed=False),
             PickResult("b", False, failure="infeasible_grasp")]  # fmt: skip
    m = metrics(picks)
    c = m["counts"]
    assert c["picks"] == m["episodes"] == 4
    assert c["commit_true"] / c["picks"] == m["commit_true_rate"]
    assert c["correct"] / c["picks"] == m["accuracy"]
    assert c["wrong_commit"] == 0 and m["wrong_commit_rate"] == 0.0
    assert (c["completed"], c["acted_on"]) == (2, 3)
    assert c["completed"] / c["acted_on"] == m["completion_committed"]
    assert c["goal_picks"] == {"a": 2, "b": 2} and c["goal_commit_true"] == {"a": 1, "b": 1}
    assert metrics([])["counts"]["picks"] == 0
