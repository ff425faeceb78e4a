"""Episodes and the evaluation protocol on the real MuJoCo model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.cli.main import run
from legws_daemon.core.params import Params
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose
from legws_daemon.sim.episode import ARRIVAL_TOLERANCE, run_episode
from legws_daemon.sim.evaluate import random_layouts, run_eval
from legws_daemon.sim.protocol import Evaluator, pick_orders


@pytest.fixture(scope="module")
def kitchen() -> tuple[World, np.ndarray]:
    sc = load_scene("kitchen_prep")
    w = World(sc)
    return w, home_configuration(w, sc.home.position, sc.home.rotation).q


def test_episode_ends_at_commit_with_the_right_goal(kitchen: tuple[World, np.ndarray]) -> None:
    w, q = kitchen
    sc = w.scene
    # well separated goals: every episode commits, and to the true goal
    layout = {
        "red_apple": ObjectPose(0.8, 0.35, 0.0),
        "red_can": ObjectPose(0.8, -0.35, 0.0),
        "green_bottle": ObjectPose(0.35, 0.3, 0.0),
    }
    w.set_layout(sc.poses(layout))
    goals = sc.goal_set(layout)
    rng = np.random.default_rng(0)
    for name in goals.names:
        ep = run_episode(w, goals, name, q, rng)
        assert ep.committed == name
        assert ep.correct
        assert ep.commit_time is not None
        assert ep.duration == pytest.approx(ep.commit_time)
        assert 0 < ep.commit_time < 30


def test_episode_without_commit_ends_on_arrival(kitchen: tuple[World, np.ndarray]) -> None:
    w, q = kitchen
    sc = w.scene
    w.set_layout(sc.poses())
    goals = sc.goal_set()
    ep = run_episode(w, goals, "red_can", q, np.random.default_rng(1), Params(p_thresh=0.999999))
    assert ep.committed is None
    assert ep.arrived
    assert (
        np.linalg.norm(w.ee_position() - goals.positions[goals.index("red_can")])
        < ARRIVAL_TOLERANCE
    )
    assert ep.final_goal == "red_can"


def test_episode_times_out(kitchen: tuple[World, np.ndarray]) -> None:
    w, q = kitchen
    goals = w.scene.goal_set()
    ep = run_episode(
        w, goals, "red_can", q, np.random.default_rng(1), Params(p_thresh=0.999999), timeout=2.0
    )
    assert ep.committed is None
    assert not ep.arrived
    assert ep.duration == pytest.approx(2.0)


def test_pick_orders() -> None:
    rng = np.random.default_rng(0)
    assert len(pick_orders(["a", "b", "c"], rng)) == 6
    assert len(set(pick_orders(["a", "b", "c", "d"], rng))) == 24
    orders = pick_orders([f"g{i}" for i in range(8)], rng)
    assert len(orders) == 120
    assert all(sorted(o) == sorted(orders[0]) for o in orders)


def test_infeasible_grasps_count_as_failures() -> None:
    sc = load_scene("desk")
    ev = Evaluator(sc)
    mug = sc.poses()["white_mug"]
    layout = sc.default_layout() | {"black_stapler": ObjectPose(mug.x - 0.13, mug.y, np.pi / 2)}
    result = ev.evaluate(layout, seed=0)
    assert not result.feasibility["white_mug"].feasible
    mug_picks = [p for p in result.picks if p.true_goal == "white_mug"]
    assert len(mug_picks) == 6  # one per permutation of three goals
    assert all(p.episode is None and not p.correct for p in mug_picks)
    others = [p for p in result.picks if p.true_goal != "white_mug"]
    assert all(p.episode is not None for p in others)
    assert result.metrics()["infeasible_picks"] == 6


def test_short_eval_is_identical_twice_under_one_seed() -> None:
    sc = load_scene("breakfast_easy")
    layouts = random_layouts(sc, 3, seed=5)
    a = run_eval(sc, layouts, 5, workers=2)
    b = run_eval(sc, layouts, 5, workers=1)
    assert a["aggregate"] == b["aggregate"]
    assert a["per_layout"] == b["per_layout"]
    assert a["aggregate"]["episodes"] == 3 * 2 * 2


def test_eval_command_writes_json_and_markdown(tmp_path: Path) -> None:
    code = run(["eval", "--scene", "breakfast_easy", "--layouts", "random:2", "--seed", "3",
                "--out", str(tmp_path), "--quiet", "--workers", "1"])  # fmt: skip
    assert code == 0
    report = json.loads((tmp_path / "eval.json").read_text())
    assert report["layouts"] == 2
    assert set(report["aggregate"]) >= {
        "accuracy", "t_infer_mean", "t_infer_sd", "commit_rate", "wrong_commit_rate",
        "no_commit_rate",
    }  # fmt: skip
    assert "| accuracy |" in (tmp_path / "eval.md").read_text()


def test_eval_rejects_bad_layout_specs(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["eval", "--scene", "desk", "--layouts", "random:zero", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "random:N" in err
    assert run(["eval", "--scene", "nope", "--quiet"]) == 2
