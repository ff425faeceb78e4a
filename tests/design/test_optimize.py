"""`legws optimize` end to end on the real stand-in: outputs, reproducibility, constraints."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.cli.main import run
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.design.search import METHODS, search
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
    ],
)
def test_bad_input_exits_2_with_one_line(
    args: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run(["optimize", *args, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert needle in err
