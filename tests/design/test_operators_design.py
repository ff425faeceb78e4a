"""Designing for people (`legws optimize|plan --operator FILE | --operators A,B`): the search
scores each person's model with the robot's clip and takes the worst; the reports give each
person's certificates from the numpy reference; bad operator files are one line, exit 2."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.cli.main import run
from legws_daemon.core.certificate import certify, certify_batch
from legws_daemon.core.commit import (
    certify_commit,
    commit_batch,
    commit_chance_batch,
    commit_rate_estimate,
    commit_time_batch,
    commit_time_estimate,
)
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.design.operators import design_for
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.design.stage_plan import plan_taskgraph
from legws_daemon.errors import InputError
from legws_daemon.formats.goalset import load_goalset
from legws_daemon.formats.operator_file import load_operator
from legws_daemon.scene.catalog import load_scene
from legws_daemon.task.plan_file import check_plan, plan_from_data, plan_to_data
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from tests.cli.helpers import Result, assert_bad_input
from tests.core.test_operator import orbiting

ALICE = OperatorModel(0.8, 0.03, 0.5, 20.0, "axes")
BOB = OperatorModel(0.6, 0.03, 0.8, -10.0, "axes+diagonals")


def operator_file(name: str, model: OperatorModel) -> dict[str, Any]:
    """An operator file whose certify_with is ``model`` (the fit's fields as the example)."""
    m = model.as_dict()
    return {
        "schema": 1, "name": name, **m, "segments": 20, "ticks": 3000,
        "intervals": {k: [m[k], m[k]] for k in ("speed", "sigma", "rho", "bias_deg")},
        "certify_with": m,
    }  # fmt: skip


@pytest.fixture
def people(tmp_path: Path) -> dict[str, Path]:
    out = {}
    for name, model in (("alice", ALICE), ("bob", BOB)):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(operator_file(name, model)), encoding="utf-8")
        out[name] = path
    return out


def cli(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> Result:
    capsys.readouterr()
    code = run([str(a) for a in argv])
    captured = capsys.readouterr()
    return Result(code, captured.out, captured.err)


# --- the search's scores ---------------------------------------------------------------


@pytest.mark.parametrize("objective", ["slack", "commit", "rate", "time"])
def test_the_worst_of_a_group_is_the_min_or_max_over_each_person(objective: str) -> None:
    sc = load_scene("desk")
    x = np.random.default_rng(4).uniform(size=(24, 9))
    group = LayoutProblem(sc, objective=objective, operators=[ALICE, BOB]).evaluate(x)
    one = [
        LayoutProblem(sc, objective=objective, operators=[op]).evaluate(x) for op in (ALICE, BOB)
    ]
    np.testing.assert_array_equal(group.certificate, np.minimum(*(e.certificate for e in one)))
    if objective == "commit":
        assert group.commit is not None and all(e.commit is not None for e in one)
        np.testing.assert_array_equal(group.commit, np.maximum(*(e.commit for e in one)))  # type: ignore[arg-type]
    if objective == "rate":
        np.testing.assert_array_equal(group.rate, np.minimum(*(e.rate for e in one)))  # type: ignore[arg-type]
    if objective == "time":
        np.testing.assert_array_equal(group.time, np.maximum(*(e.time for e in one)))  # type: ignore[arg-type]
    np.testing.assert_array_equal(group.score, np.minimum(*(e.score for e in one)))


def test_one_persons_scores_are_the_numpy_certificates_with_the_robots_clip() -> None:
    sc = load_scene("meal_assembly")
    p = LayoutProblem(sc, objective="commit", operators=[ALICE])
    x = np.random.default_rng(5).uniform(size=(16, p.dim))
    g = p.goals.poses(p.decode(x))
    params = Params()
    user = ALICE.motion(params, clip=True)
    args = (sc.home.position, sc.home.rotation, g.positions, g.rotations, g.symmetry, params)
    ev = p.evaluate(x)
    np.testing.assert_allclose(
        ev.certificate, certify_batch(*args, ALICE, user).objective, rtol=0, atol=1e-9
    )
    assert ev.commit is not None
    np.testing.assert_allclose(
        ev.commit, commit_batch(*args, user, "sum", ALICE).objective, rtol=0, atol=1e-9
    )
    for objective, ref in (
        ("rate", commit_chance_batch(*args, user, ALICE).mean(axis=1)),
        ("time", commit_time_batch(*args, user, ALICE).mean(axis=1)),
    ):
        got = LayoutProblem(sc, objective=objective, operators=[ALICE]).evaluate(x)
        np.testing.assert_allclose(got.rate if objective == "rate" else got.time, ref,
                                   rtol=0, atol=1e-9)  # fmt: skip


def test_a_goal_no_designed_for_person_reaches_is_finite_and_infeasible() -> None:
    """An operator whose nominal never arrives: K is infinite there; the archive takes
    finite numbers, so the layout scores NOT_REACHED_SCORE and is infeasible."""
    from legws_daemon.design.problem import NOT_REACHED_SCORE

    sc = load_scene("desk")
    lost = orbiting()
    p = LayoutProblem(sc, objective="commit", operators=[lost])
    ev = p.evaluate(np.random.default_rng(6).uniform(size=(40, p.dim)))
    assert ev.unreached is not None and ev.commit is not None
    assert np.all(np.isfinite(ev.objective))
    never = ev.unreached > 0
    assert never.any()
    assert np.all(np.isinf(ev.commit[never])) and not ev.feasible[never].any()
    assert np.all(ev.objective[never] <= NOT_REACHED_SCORE)


def test_without_operators_the_problem_scores_as_before() -> None:
    sc = load_scene("desk")
    x = np.random.default_rng(7).uniform(size=(12, 9))
    p = LayoutProblem(sc, objective="commit")
    g = p.goals.poses(p.decode(x))
    args = (sc.home.position, sc.home.rotation, g.positions, g.rotations, g.symmetry, Params())
    ev = p.evaluate(x)
    np.testing.assert_array_equal(ev.certificate, certify_batch(*args).objective)
    assert ev.unreached is None and ev.commit is not None
    np.testing.assert_allclose(ev.commit, commit_batch(*args, form="sum").objective,
                               rtol=0, atol=1e-9)  # fmt: skip


# --- legws optimize --------------------------------------------------------------------


def test_design_for_says_for_whom() -> None:
    assert design_for([]) == "section 2's user"
    assert design_for(["alice"]) == "alice"
    assert design_for(["alice", "bob"]) == "worst of alice, bob"


@pytest.mark.slow  # two short optimisation runs: ~15 s
def test_optimize_for_a_person_reports_their_certificates(
    tmp_path: Path, people: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["optimize", "--scene", "breakfast_easy", "--iterations", "15", "--quiet",
            "--objective", "commit"]  # fmt: skip
    r = cli(capsys, *base, "--operator", people["alice"], "--out", tmp_path / "a")
    assert r.code == 0, r.err
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["design_for"] == "alice"
    (entry,) = summary["operators"]
    assert entry["name"] == "alice" and entry["model"] == ALICE.as_dict()
    goals, params = load_goalset(tmp_path / "a" / "goals.json")
    user = ALICE.motion(params, clip=True)
    # section 2's user's objective stays what `legws certify goals.json` gives
    assert summary["objective"] == certify(goals, params).objective
    assert entry["objective"] == certify(goals, params, ALICE, user).objective
    k = certify_commit(goals, params, user, "sum", ALICE)
    assert entry["commit_objective"] == (k.objective if np.isfinite(k.objective) else None)
    assert entry["commit_certified"] == k.certified
    assert entry["commit_rate_estimate"] == commit_rate_estimate(goals, params, ALICE)
    t = commit_time_estimate(goals, params, ALICE)
    assert entry["commit_time_estimate"] == (t if np.isfinite(t) else None)
    # for a group: both people, worst of them, and another cache key than for one person
    r = cli(capsys, *base, "--operators", f"{people['alice']},{people['bob']}", "--out",
            tmp_path / "g")  # fmt: skip
    assert r.code == 0, r.err
    group = json.loads((tmp_path / "g" / "summary.json").read_text())
    assert group["design_for"] == "worst of alice, bob"
    assert [o["name"] for o in group["operators"]] == ["alice", "bob"]
    assert group["key"] != summary["key"]


def test_a_bad_operator_file_is_one_line_and_exit_2(
    tmp_path: Path, people: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    data = operator_file("carol", ALICE)
    data["certify_with"]["speed"] = 0.0
    bad = tmp_path / "carol.json"
    bad.write_text(json.dumps(data), encoding="utf-8")
    garbage = tmp_path / "garbage.json"
    garbage.write_text("{not json", encoding="utf-8")
    for command in (["optimize", "--scene", "desk"], ["plan", "tea"]):
        assert_bad_input(cli(capsys, *command, "--operator", bad), "carol.json",
                         "certify_with.speed")  # fmt: skip
        assert_bad_input(cli(capsys, *command, "--operators", f"{people['alice']},{garbage}"),
                         "garbage.json")  # fmt: skip
        assert_bad_input(cli(capsys, *command, "--operator", tmp_path / "nobody.json"),
                         "nobody.json")  # fmt: skip
        assert_bad_input(
            cli(capsys, *command, "--operator", people["alice"], "--operators",
                str(people["bob"])),
            "--operators", "not both",
        )  # fmt: skip
        assert_bad_input(
            cli(capsys, *command, "--operators", f"{people['alice']},{people['alice']}"),
            "given twice",
        )


# --- legws plan ------------------------------------------------------------------------


def test_a_plan_for_people_records_them_and_validates(people: dict[str, Path]) -> None:
    graph, sc = load_taskgraph(resolve_taskgraph("feeding"))
    files = [load_operator(people["alice"]), load_operator(people["bob"])]
    plan = plan_taskgraph(graph, sc, iterations=3, use_cache=False, render=False,
                          operators=files)  # fmt: skip
    assert plan.settings["design_for"] == "worst of alice, bob"
    assert [o["name"] for o in plan.settings["operators"]] == ["alice", "bob"]
    assert plan.settings["operators"][0]["model"] == ALICE.as_dict()
    data = plan_to_data(plan)
    check_plan(plan_from_data(data, "plan.json", sc), graph, sc, "plan.json")
    plain = plan_taskgraph(graph, sc, iterations=3, use_cache=False, render=False)
    assert plain.key != plan.key and "operators" not in plain.settings
    for edit, needle in (
        (lambda d: d["settings"]["operators"][1]["model"].update(rho=1.5),
         "settings.operators[1].model.rho"),
        (lambda d: d["settings"].update(design_for="alice"), "settings.design_for"),
        (lambda d: d["settings"].pop("design_for"), "settings.design_for"),
    ):  # fmt: skip
        tampered = copy.deepcopy(data)
        edit(tampered)
        with pytest.raises(InputError, match=needle.replace("[", r"\[").replace("]", r"\]")):
            check_plan(plan_from_data(tampered, "plan.json", sc), graph, sc, "plan.json")
