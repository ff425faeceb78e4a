"""`legws optimize` end to end on the real stand-in: outputs, reproducibility, constraints."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.cli.main import run
from legws_daemon.core.params import Params
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.design.search import METHODS, search
from legws_daemon.errors import InputError
from legws_daemon.robot.feasibility import check_grasps
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.layout_file import load_layout


def optimize(tmp_path: Path, *args: str) -> dict[str, object]:
    out = tmp_path / "run"
    code = run(["optimize", *args, "--out", str(out), "--quiet", "--no-cache"])
    assert code == 0
    return dict(json.loads((out / "summary.json").read_text()))


def test_outputs_certify_and_constraints(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    summary = optimize(tmp_path, "--scene", "breakfast_easy", "--iterations", "40", "--seed", "3")
    out = tmp_path / "run"
    for name in ("summary.json", "best_layout.json", "goals.json", "archive.csv", "archive.png"):
        assert (out / name).is_file()
    for key in ("objective", "coverage", "elites", "evaluations", "seconds"):
        assert key in summary
    capsys.readouterr()
    assert run(["certify", str(out / "goals.json"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["objective"] == summary["objective"]
    sc = load_scene("breakfast_easy")
    layout = load_layout(out / "best_layout.json", sc)
    assert LayoutConstraints.of(sc).problems(sc.poses(layout)) == []
    w = World(sc)
    q = home_configuration(w, sc.home.position, sc.home.rotation).q
    checks = check_grasps(w, sc.goal_set(layout), q, sc.poses(layout))
    assert all(c.feasible for c in checks.values())


def test_same_seed_same_result(tmp_path: Path) -> None:
    a = optimize(tmp_path / "a", "--scene", "desk", "--iterations", "30", "--seed", "5")
    b = optimize(tmp_path / "b", "--scene", "desk", "--iterations", "30", "--seed", "5")
    assert a["objective"] == b["objective"]
    la = (tmp_path / "a" / "run" / "best_layout.json").read_text()
    assert la == (tmp_path / "b" / "run" / "best_layout.json").read_text()


def test_fixed_objects_never_move(tmp_path: Path) -> None:
    optimize(tmp_path, "--scene", "meal_assembly", "--iterations", "30",
             "--movable", "banana,red_can")  # fmt: skip
    sc = load_scene("meal_assembly")
    layout = json.loads((tmp_path / "run" / "best_layout.json").read_text())
    assert set(layout) == {"banana", "red_can"}
    goals = json.loads((tmp_path / "run" / "goals.json").read_text())
    assert [g["name"] for g in goals["goals"]] == ["banana", "red_can"]
    poses = sc.poses(load_layout(tmp_path / "run" / "best_layout.json", sc))
    for fixed in ("cereal_box", "red_apple", "green_bottle", "bowl"):
        assert poses[fixed] == sc.poses()[fixed]


def test_second_run_is_served_from_the_cache(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["optimize", "--scene", "breakfast_easy", "--iterations", "20", "--quiet"]
    assert run([*args, "--out", str(tmp_path / "1")]) == 0
    first = json.loads(capsys.readouterr().out)
    assert run([*args, "--out", str(tmp_path / "2")]) == 0
    second = json.loads(capsys.readouterr().out)
    assert second["cached"] is True
    assert second["objective"] == first["objective"]


@pytest.mark.parametrize("method", METHODS)
def test_every_method_fills_the_archive(method: str) -> None:
    p = LayoutProblem(load_scene("desk"))
    r = search(p, method, iterations=15, seed=1)
    assert r.coverage > 0.05
    assert r.evaluations >= 15 * 90 - 200
    assert r.elites == sorted(r.elites, key=lambda e: -e.objective)
    assert np.isfinite(r.elites[0].objective)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--scene", "nope"], "known: "),
        (["--scene", "desk", "--movable", "white_mug,teapot"], "teapot"),
        (["--scene", "desk", "--movable", "white_mug,tape_dispenser"], "fixed"),
        (["--scene", "desk", "--method", "random"], "cma-me"),
        (["--scene", "desk", "--objective", "speed"], "slack"),
    ],
)
def test_bad_input_exits_2_with_one_line(
    args: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run(["optimize", *args, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert needle in err


def test_commit_objective_designs_for_early_commits(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--objective commit` minimises K; summary.json reports K of the written goals.json
    (reproduced by `legws certify --commit` to the last digit); elites.json lists the
    elites checked in full, best first, the best verified one being best_layout.json."""
    summary = optimize(tmp_path, "--scene", "desk", "--iterations", "40", "--seed", "2",
                       "--objective", "commit")  # fmt: skip
    out = tmp_path / "run"
    assert summary["objective_kind"] == "commit"
    capsys.readouterr()
    assert run(["certify", str(out / "goals.json"), "--json", "--commit"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["commit"]["objective"] == summary["commit_objective"]
    assert report["commit"]["certified"] == summary["commit_certified"]
    assert report["objective"] == summary["objective"]  # J is still the contract's objective
    elites = json.loads((out / "elites.json").read_text())
    ranks = [e["rank"] for e in elites]
    assert ranks == sorted(ranks) and ranks[0] == 0
    verified = [e for e in elites if e["verified"]]
    assert [e["rank"] for e in verified] == summary["verified_ranks"]
    assert verified[0]["rank"] == summary["verified_rank"]
    sc = load_scene("desk")
    best = load_layout(out / "best_layout.json", sc)
    assert {n: [p.x, p.y, p.yaw] for n, p in best.items()} == {
        n: [p["x"], p["y"], p["yaw"]] for n, p in verified[0]["layout"].items()
    }
    # the objective searched is -K (of the exact-sum form, the default) minus penalties:
    # the best verified elite's is -K; §9's K (the contract's) is never smaller
    assert summary["commit_form"] == "sum"
    assert verified[0]["objective"] == pytest.approx(-summary["commit_objective_sum"], abs=1e-9)
    assert summary["commit_objective"] >= summary["commit_objective_sum"]
    for e in elites:
        assert e["verified"] or e["reason"]
    # the searched score went the right way: K beats the desk's shipped layout
    from legws_daemon.core.commit import certify_commit
    from legws_daemon.core.params import Params

    shipped = certify_commit(sc.goal_set(sc.default_layout()), Params()).objective
    assert summary["commit_objective"] < shipped


def test_problem_scores_minus_k_with_the_commit_objective() -> None:
    from legws_daemon.core.commit import commit_batch
    from legws_daemon.design.problem import INFEASIBLE_OFFSET

    sc = load_scene("desk")
    slack = LayoutProblem(sc)
    commit = LayoutProblem(sc, objective="commit")
    rng = np.random.default_rng(0)
    x = rng.uniform(size=(12, slack.dim))
    a, b = slack.evaluate(x), commit.evaluate(x)
    np.testing.assert_array_equal(a.certificate, b.certificate)
    assert a.commit is None and b.commit is not None
    pos, rot, sym = sc.grasp_batch(slack.names, slack.decode(x))
    k = commit_batch(
        sc.home.position, sc.home.rotation, pos, rot, sym, Params(), form="sum"
    ).objective
    np.testing.assert_allclose(b.commit, k)
    np.testing.assert_allclose(b.score, -k)
    # the same penalties: objective = score - penalties
    np.testing.assert_allclose(a.certificate - a.objective, b.score - b.objective)
    assert np.all((b.score - b.objective >= INFEASIBLE_OFFSET) | b.feasible)
    with pytest.raises(InputError, match="objective"):
        LayoutProblem(sc, objective="fast")
    with pytest.raises(InputError, match="commit form"):
        LayoutProblem(sc, objective="commit", commit_form="max")


def test_rate_objective_designs_for_more_commits(tmp_path: Path) -> None:
    """`--objective rate` maximises R, the estimated commit rate over all goals; the summary
    reports R of the written goals.json (for every objective) and the search raised it
    above the shipped layout's."""
    from legws_daemon.core.commit import commit_rate_estimate
    from legws_daemon.formats.goalset import load_goalset

    summary = optimize(tmp_path, "--scene", "meal_assembly", "--iterations", "30", "--seed",
                       "1", "--objective", "rate")  # fmt: skip
    out = tmp_path / "run"
    assert summary["objective_kind"] == "rate" and "commit_form" not in summary
    written, params = load_goalset(out / "goals.json")
    assert summary["commit_rate_estimate"] == commit_rate_estimate(written, params)
    assert 0.0 <= summary["commit_rate_estimate"] <= 1.0
    elites = json.loads((out / "elites.json").read_text())
    best = next(e for e in elites if e["verified"])
    assert best["objective"] == pytest.approx(summary["commit_rate_estimate"], abs=1e-9)
    sc = load_scene("meal_assembly")
    shipped = commit_rate_estimate(sc.goal_set(sc.default_layout()), Params())
    assert summary["commit_rate_estimate"] > shipped


def test_problem_scores_the_commit_rate_with_the_rate_objective() -> None:
    from legws_daemon.core.commit import clipped_user, commit_chance_batch

    sc = load_scene("desk")
    slack = LayoutProblem(sc)
    rate = LayoutProblem(sc, objective="rate")
    x = np.random.default_rng(1).uniform(size=(12, slack.dim))
    a, b = slack.evaluate(x), rate.evaluate(x)
    assert a.rate is None and b.rate is not None and b.commit is None
    pos, rot, sym = sc.grasp_batch(slack.names, slack.decode(x))
    r = commit_chance_batch(
        sc.home.position, sc.home.rotation, pos, rot, sym, Params(), clipped_user(Params())
    ).mean(axis=1)
    np.testing.assert_allclose(b.score, r)
    assert np.all((r >= 0) & (r <= 1))
    np.testing.assert_allclose(a.certificate - a.objective, b.score - b.objective)


def test_time_objective_minimises_the_estimated_commit_time(tmp_path: Path) -> None:
    """`--objective time` minimises T, the estimated commit time in seconds; the summary
    reports T of the written goals.json (for every objective), below the shipped layout's."""
    from legws_daemon.core.commit import commit_time_estimate
    from legws_daemon.formats.goalset import load_goalset

    summary = optimize(tmp_path, "--scene", "desk", "--iterations", "30", "--seed", "3",
                       "--objective", "time")  # fmt: skip
    out = tmp_path / "run"
    assert summary["objective_kind"] == "time"
    written, params = load_goalset(out / "goals.json")
    assert summary["commit_time_estimate"] == commit_time_estimate(written, params)
    best = next(e for e in json.loads((out / "elites.json").read_text()) if e["verified"])
    assert best["objective"] == pytest.approx(-summary["commit_time_estimate"], abs=1e-9)
    sc = load_scene("desk")
    shipped = commit_time_estimate(sc.goal_set(sc.default_layout()), Params())
    assert summary["commit_time_estimate"] < shipped
