"""The simulation protocol on the deployed controller, on the real MuJoCo model: every
feasible pick of every shipped scene's default layout commits (or is confirmed) and
completes; failures are named; same seed, same numbers."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.cli.main import run
from legws_daemon.core.params import Params
from legws_daemon.scene.catalog import load_scene, scene_names
from legws_daemon.scene.scene import ObjectPose
from legws_daemon.sim.evaluate import random_layouts, run_eval
from legws_daemon.sim.protocol import (
    LIFT_CLEARANCE,
    TIMEOUT_S,
    Evaluator,
    PickResult,
    metrics,
    pick_orders,
)
from legws_daemon.task.runner import scene_graph


@pytest.mark.slow
@pytest.mark.parametrize("name", scene_names())
def test_every_feasible_pick_of_every_shipped_scene_commits_and_completes(name: str) -> None:
    """The daemon's controller, the simulated user, simulated time: one pick of every
    candidate goal of the scene's default layout."""
    scene = load_scene(name)
    ev = Evaluator(scene)
    checks = ev.check(scene.default_layout())
    feasible = [n for n in scene.goal_names if checks[n].feasible]
    assert feasible, "a shipped default layout has a feasible grasp"
    ev.controller.load(scene, scene.default_layout(), scene_graph(scene, feasible))
    rng = np.random.default_rng(0)
    for goal in feasible:
        pick = ev.pick(goal, rng)
        assert pick.failure is None, (goal, pick.failure, pick.detail)
        assert pick.committed == goal or pick.confirmed == goal
        assert pick.completed, goal
        assert pick.duration < TIMEOUT_S + 60
        assert ev.stand_in.held == goal  # carried home in the gripper
        np.testing.assert_allclose(
            ev.stand_in.read_state().ee_position, scene.home.position, atol=0.005
        )


#: Slack elites of docs/results/tables whose cereal box picks ended `assist_failed` ('home':
#: no clear joint-space path: the straight one leaves the workspace box).
EDGE_LAYOUTS = {
    # breakfast-easy, seed 1, 3rd best: the box at the table's side edge, grasped at its side
    "breakfast_easy": {
        "cereal_box": ObjectPose(0.3, -0.45, 2.443712333633032),
        "banana": ObjectPose(0.3795045434914211, 0.45, -1.5856634065491304),
    },
    # breakfast, seed 0, best: the box near the base, the rise cut short at a wrist limit
    # (the withdrawal goes on diagonally, up to the home height)
    "breakfast": {
        "cereal_box": ObjectPose(0.3, 0.34845918823090655, 0.8947970864083059),
        "banana": ObjectPose(0.8280039126164247, 0.18246609723542634, 1.6227470353262792),
        "milk_carton": ObjectPose(0.5182932286212425, -0.32902792453566754, 1.3599943695436583),
    },
}


@pytest.mark.parametrize("name", sorted(EDGE_LAYOUTS))
def test_the_way_home_from_the_edge_of_the_box_withdraws_first_and_completes(name: str) -> None:
    """After the lift every joint line home swings the EE out of the workspace box; a
    straight withdrawal toward home first, then the way home, and the pick completes."""
    sc = load_scene(name)
    ev = Evaluator(sc)
    layout = EDGE_LAYOUTS[name]
    phases: list[str] = []
    planner = ev.controller.planner
    withdraw = planner.withdraw

    def watched(*args: Any, **kwargs: Any) -> Any:
        move = withdraw(*args, **kwargs)
        phases.append("withdraw" if move is not None else "none")
        return move

    planner.withdraw = watched  # type: ignore[method-assign]
    result = ev.evaluate(layout, seed=0, episodes_per_goal=1)
    box = next(p for p in result.picks if p.true_goal == "cereal_box")
    assert box.completed and box.failure is None, box.detail
    assert phases == ["withdraw"]  # asked once, on that pick's way home, and it found one
    assert all(p.failure is None for p in result.picks)
    np.testing.assert_allclose(ev.stand_in.kinematics.ee_position(), sc.home.position, atol=0.01)


#: Random layouts of benchmarks/assist.py whose way home failed before the turn in place
#: (name -> layout, seed, picks per goal, the goal, the policy)
WRIST_LAYOUTS: dict[str, tuple[dict[str, ObjectPose], list[int], int, str, str]] = {
    # the red can's grasp leaves the wrist far from home's: a joint line home leaves the box
    # and the home pose is out of one IK solve's reach from there (a turn in steps is not)
    "meal_assembly": (
        {
            "cereal_box": ObjectPose(0.6851168615973775, -0.2481091899806648, 1.8403388775846228),
            "banana": ObjectPose(0.4473975705643815, -0.31837537793205295, 1.4845105383671937),
            "red_apple": ObjectPose(0.7101323579278898, -0.0061963854386541, -2.4157868429749505),
            "red_can": ObjectPose(0.5585394461338291, -0.17191924837021128, 1.5888236523302384),
            "green_bottle": ObjectPose(0.7033924964355998, 0.18312411092634667, 0.373754039386631),
        },
        [0, 23], 2, "red_can", "commit",
    ),
    # the milk carton: a withdrawal home that the arm's own path ends elsewhere than the
    # planner's IK, whose joint line home then sweeps a finger through the cereal box
    "breakfast": (
        {
            "cereal_box": ObjectPose(0.520223469573612, -0.17439843162966157, -1.9603045585151173),
            "banana": ObjectPose(0.8009863153613455, 0.239669732891528, 0.39069863246295755),
            "milk_carton": ObjectPose(0.38248494666965893, -0.15209553806825754, -0.89888698141),
        },
        [0, 27], 4, "milk_carton", "blend",
    ),
    # breakfast's slack elite (seed 3, 1st): the cereal box near the base, grasped on
    # another IK branch than home's; no joint line home from anywhere near: back to where
    # the carry arrived, then home the way it came
    "breakfast_elite": (
        {
            "cereal_box": ObjectPose(0.3, 0.2719795079574518, 0.625616525254709),
            "banana": ObjectPose(0.530594768491021, -0.29725360038147375, 1.6723749136556103),
            "milk_carton": ObjectPose(0.8377907434559397, 0.23758272035810107, 1.58444795386),
        },
        [0, 9], 7, "cereal_box", "commit",
    ),
}  # fmt: skip

#: kitchen-prep's slack elite (seed 0, 2nd): the green bottle near the base, whose straight
#: reach is held 3 cm short by a joint at its limit (the reach's joint-space fallback)
REACH_LAYOUT = {
    "red_apple": ObjectPose(0.8258938671067686, 0.11111857715094203, -2.449207461800995),
    "red_can": ObjectPose(0.4654693919891828, -0.34244362392634475, -1.1418965425767196),
    "green_bottle": ObjectPose(0.3, 0.21714202293500678, 0.3798939072265646),
}


#: The commit-optimised Med-B elite (seed 1) whose cereal box, grasped from the side next to
#: the base, had its pre-pose 0.4 mm outside the box's face x = 0.20: the move down to it
#: stalled there (9 of its 10 picks of the cereal box failed).
FACE_LAYOUT = {
    "cereal_box": ObjectPose(0.3, 0.31702352518468807, 0.5100698352506163),
    "banana": ObjectPose(0.8356701407944009, 0.25740588743604836, -1.4409774237100164),
    "milk_carton": ObjectPose(0.572235914104483, -0.35590839672571867, 1.9334076128815099),
}


def test_a_grasp_whose_pre_pose_is_on_the_box_face_comes_in_from_inside() -> None:
    sc = load_scene("breakfast")
    ev = Evaluator(sc)
    ev.check(FACE_LAYOUT)
    ev.controller.load(sc, FACE_LAYOUT, scene_graph(sc))
    rng = np.random.default_rng(0)
    for _ in range(2):
        pick = ev.pick("cereal_box", rng)
        assert pick.completed and pick.failure is None, pick.detail


def test_a_carry_whose_joint_line_grazes_the_box_face_goes_another_way_and_completes() -> None:
    """breakfast-easy's edge layout under the slow, biased operator with ``blend``: the
    carry's joint line from home to above the cereal box (6 mm inside the face y = -0.55)
    came within 0.03 mm of the face on the way as planned, and the arm's own line (from
    where the move before ended) left it between two of the check's samples: the arm
    stalled on the face ('carry' made no progress, the pick failed). Lines are checked
    between the samples near a face and keep 0.5 mm clear now: the carry goes another way
    (either alone would do).
    The picks are benchmarks/assist.py's (seed [0, 4], 16 rounds), up to the one that
    failed."""
    from legws_daemon.core.operator import OperatorModel

    sc = load_scene("breakfast_easy")
    layout = EDGE_LAYOUTS["breakfast_easy"]
    slow_biased = OperatorModel(0.6, 0.03, 0.0, 20.0, "free")
    ev = Evaluator(sc, operator=slow_biased, assist="blend")
    rng = np.random.default_rng([0, 4])
    ev.check(layout)
    ev.controller.load(sc, layout, scene_graph(sc))
    names = list(sc.goal_names)
    rounds = [[names[i] for i in rng.permutation(len(names))] for _ in range(16)]
    picks = [ev.pick(name, rng) for name in [n for r in rounds for n in r][:6]]
    assert picks[5].true_goal == "cereal_box" and picks[5].confirmed == "cereal_box"
    for pick in picks:
        assert pick.completed and pick.failure is None, pick.detail


def test_a_carry_with_no_clear_joint_line_from_home_withdraws_and_vias_and_completes() -> None:
    """breakfast-easy's commit-optimised elite (seed 0, 3rd best; Table 1's run): the cereal
    box at the corner x = 0.30, y = -0.42. The carry's joint line from home (a 4 rad swing
    to the grasp's IK branch) comes within 0.2 mm of the face y = -0.55; the way round was a
    withdrawal and the home configuration as a via, whose onward line passed the check when
    planned and failed it from where the arm really reached home: the arm went back and
    forth, and each tick planned again a via where it already stood (120 s of simulated
    time, 12 minutes of the machine's, then 'limit'). With vias apart from the ends, onward
    lines planned with 2 mm of room and at most three vias per move, every pick of the elite
    completes."""
    sc = load_scene("breakfast_easy")
    layout = {
        "cereal_box": ObjectPose(0.3, -0.4197526314024083, 2.1796889932189805),
        "banana": ObjectPose(0.6902053216442042, 0.45, -1.6538091663499512),
    }
    ev = Evaluator(sc)
    result = ev.evaluate(layout, seed=[0, 2], episodes_per_goal=3)
    for pick in result.picks:
        assert pick.completed and pick.failure is None, pick.detail
        assert pick.duration < TIMEOUT_S + 30


@pytest.mark.slow
def test_a_reach_held_short_at_a_joint_limit_completes_in_joint_space() -> None:
    sc = load_scene("kitchen_prep")
    ev = Evaluator(sc)
    result = ev.evaluate(REACH_LAYOUT, seed=[0, 1], episodes_per_goal=7)
    assert all(p.completed and p.failure is None for p in result.picks), [
        p.detail for p in result.picks if p.failure
    ]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(WRIST_LAYOUTS))
def test_the_way_home_turns_in_place_at_home_when_the_wrist_is_far_from_homes(
    name: str,
) -> None:
    layout, seed, per_goal, goal, assist = WRIST_LAYOUTS[name]
    sc = load_scene(name.removesuffix("_elite"))
    ev = Evaluator(sc, assist=assist)  # type: ignore[arg-type]
    planner = ev.controller.planner
    withdraw = planner.withdraw
    turned: list[int] = []

    def watched(*args: Any, **kwargs: Any) -> Any:
        moves = withdraw(*args, **kwargs)
        if moves is not None and (len(moves) > 1 or name.endswith("_elite")):
            turned.append(len(moves))  # to home and a turn in steps; or back the way in
        return moves

    planner.withdraw = watched  # type: ignore[method-assign]
    result = ev.evaluate(layout, seed=seed, episodes_per_goal=per_goal)
    picks = [p for p in result.picks if p.true_goal == goal]
    assert picks and all(p.completed and p.failure is None for p in picks), [
        p.detail for p in picks
    ]
    assert turned  # it took the turn in place (or the way back) at least once
    assert all(p.failure in (None, "infeasible_grasp") for p in result.picks)


def test_a_pick_lifts_the_true_goal_clear_of_the_table() -> None:
    sc = load_scene("kitchen_prep")
    ev = Evaluator(sc)
    layout = {
        "red_apple": ObjectPose(0.8, 0.35, 0.0),
        "red_can": ObjectPose(0.8, -0.35, 0.0),
        "green_bottle": ObjectPose(0.35, 0.3, 0.0),
    }
    result = ev.evaluate(layout, seed=0)
    assert len(result.picks) == 18  # every order of three goals
    for p in result.picks:
        # well separated goals: the observer commits to the true goal, the robot picks it
        assert p.committed == p.true_goal and p.correct
        assert p.commit_time is not None and 0 < p.commit_time < TIMEOUT_S
        assert p.completed and p.failure is None
        assert p.complete_time is not None and p.complete_time > p.commit_time
    m = metrics(result.picks)
    assert m["completion_rate"] == 1.0 and m["completion_committed"] == 1.0
    assert m["failures"] == {}
    # what "lifted" means, measured on the stand-in after the last pick
    a = ev.stand_in
    name = result.picks[-1].true_goal
    assert a.held == name
    position, _ = a.kinematics.object_pose(name)
    assert position[2] - sc.z_center(name) > LIFT_CLEARANCE


def test_without_a_commit_the_user_confirms_at_the_grasp() -> None:
    sc = load_scene("kitchen_prep")
    ev = Evaluator(sc, Params(p_thresh=0.999999))
    result = ev.evaluate(sc.default_layout(), seed=1)
    for p in result.picks:
        assert p.committed is None and p.commit_time is None
        assert p.confirmed == p.true_goal and p.correct
        assert p.completed
    m = metrics(result.picks)
    assert m["commit_rate"] == 0.0 and m["confirmed_rate"] == 1.0
    assert m["t_infer_mean"] is None


def test_a_confirm_at_the_grasp_takes_the_object_there_when_the_lagging_argmax_is_another() -> None:
    """With help before the commit the observer reads the operator's integrated input, which
    lags the EE: at the grasp its argmax can be a neighbour. The confirm acts on the object
    the hand is at; the pick's inferred goal (the paper's accuracy) stays the observer's."""
    sc = load_scene("cluttered")
    layout = random_layouts(sc, 6, 0)[5]
    result = Evaluator(sc, assist="hindsight").evaluate(layout, seed=[0, 5], episodes_per_goal=2)
    overruled = [p for p in result.picks if p.confirmed is not None and p.final_goal != p.confirmed]
    assert overruled  # the argmax at the confirmation named a neighbour
    for p in overruled:
        assert p.confirmed == p.true_goal and not p.correct
        assert p.completed and not p.wrong_grasp and p.failure is None
    assert not any(p.wrong_grasp for p in result.picks)


def test_a_single_feasible_candidate_is_taken_at_once_and_scored() -> None:
    """With one feasible grasp the robot needs no inference: the pick is a commit (without a
    time), correct, and completed (the restart itself commits: it counts)."""
    sc = load_scene("breakfast_easy")
    ev = Evaluator(sc)
    ev.check(sc.default_layout())
    ev.controller.load(sc, sc.default_layout(), scene_graph(sc, ["banana"]))
    pick = ev.pick("banana", np.random.default_rng(0))
    assert pick.committed == "banana" and pick.commit_time is None
    assert pick.correct and pick.completed and pick.failure is None
    m = metrics([pick])
    assert m["accuracy"] == 1.0 and m["commit_rate"] == 1.0 and m["t_infer_mean"] is None


def test_pick_orders() -> None:
    rng = np.random.default_rng(0)
    assert len(pick_orders(["a", "b", "c"], rng)) == 6
    assert len(set(pick_orders(["a", "b", "c", "d"], rng))) == 24
    orders = pick_orders([f"g{i}" for i in range(8)], rng)
    assert len(orders) == 120
    assert all(sorted(o) == sorted(orders[0]) for o in orders)


def test_infeasible_grasps_count_as_failures_with_their_reason() -> None:
    sc = load_scene("desk")
    ev = Evaluator(sc)
    mug = sc.poses()["white_mug"]
    layout = sc.default_layout() | {"black_stapler": ObjectPose(mug.x - 0.13, mug.y, np.pi / 2)}
    result = ev.evaluate(layout, seed=0)
    assert not result.feasibility["white_mug"].feasible
    mug_picks = [p for p in result.picks if p.true_goal == "white_mug"]
    assert len(mug_picks) == 6  # one per permutation of three goals
    for p in mug_picks:
        assert not p.feasible and not p.correct and not p.completed
        assert p.failure == "infeasible_grasp"
        assert p.detail == result.feasibility["white_mug"].reason
    others = [p for p in result.picks if p.true_goal != "white_mug"]
    assert all(p.feasible and p.completed for p in others)
    # the infeasible goal is not offered: the observer infers over the other two
    assert set(ev.controller.graph.stages["pick"].candidates) == {"black_stapler", "maroon_pen_cup"}
    m = metrics(result.picks)
    assert m["infeasible_picks"] == 6
    assert m["failures"] == {"infeasible_grasp": 6}


def test_metrics_name_every_failure() -> None:
    picks = [
        PickResult("a", True, "a", 5.0, None, "a", True, 9.0),
        PickResult("a", True, "b", 4.0, None, "b", False, None, "wrong_commit", "acted on 'b'"),
        PickResult("b", True, None, None, "b", "b", False, None, "assist_failed", "carry"),
        PickResult("b", False, failure="infeasible_grasp", detail="out of reach"),
    ]
    m = metrics(picks)
    assert m["accuracy"] == 0.5
    assert m["commit_rate"] == 0.5
    assert m["wrong_commit_rate"] == 0.25
    assert m["confirmed_rate"] == 0.25
    assert m["completion_rate"] == 0.25
    assert m["completion_committed"] == pytest.approx(1 / 3)
    assert m["failures"] == {"infeasible_grasp": 1, "wrong_commit": 1, "assist_failed": 1}
    assert m["t_infer_mean"] == 4.5


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
        "no_commit_rate", "confirmed_rate", "completion_rate", "completion_committed",
        "failures",
    }  # fmt: skip
    text = (tmp_path / "eval.md").read_text()
    assert "| accuracy |" in text and "| completed |" in text and "Failures:" in text


def test_eval_rejects_bad_layout_specs(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["eval", "--scene", "desk", "--layouts", "random:zero", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "random:N" in err
    assert run(["eval", "--scene", "nope", "--quiet"]) == 2


def test_an_operator_steers_the_stand_in_picks_as_its_model_says(tmp_path: Path) -> None:
    """``legws eval --operator``: the simulated user of the picks is the file's fitted
    operator — an axis-steering one moves the EE along one axis at a time."""
    from legws_daemon.core.operator import OperatorModel
    from legws_daemon.formats.operator_file import OperatorFile

    keyboard = OperatorModel(1.0, 0.001, 0.0, 0.0, "axes")
    sc = load_scene("kitchen_prep")
    ev = Evaluator(sc, operator=keyboard)
    ev.check(sc.default_layout())
    ev.controller.load(sc, sc.default_layout(), scene_graph(sc))
    seen: list[np.ndarray] = []
    tick = ev.controller.tick

    def spy(inp):  # type: ignore[no-untyped-def]
        if inp is not None and np.any(inp.axes != 0):
            seen.append(np.abs(inp.axes))
        return tick(inp)

    ev.controller.tick = spy  # type: ignore[method-assign]
    pick = ev.pick("red_apple", np.random.default_rng(0))
    assert pick.completed and seen
    on_axis = [s.max() / max(np.linalg.norm(s), 1e-12) > 0.99 for s in seen]
    assert np.mean(on_axis) > 0.95
    person = tmp_path / "bob.json"
    intervals = {
        k: (getattr(keyboard, k), getattr(keyboard, k))
        for k in ("speed", "sigma", "rho", "bias_deg")
    }
    OperatorFile("bob", keyboard, keyboard, intervals, 3, 100).write(person)
    out = tmp_path / "run"
    args = ["--layouts", "random:1", "--episodes-per-goal", "1", "--operator", str(person)]
    code = run(["eval", "--scene", "kitchen_prep", *args, "--out", str(out), "--quiet",
                "--workers", "1"])  # fmt: skip
    assert code == 0
    report = json.loads((out / "eval.json").read_text())
    assert report["operator"] == keyboard.as_dict() and report["user"] == "operator"
    assert "simulated operator" in (out / "eval.md").read_text()


@pytest.mark.parametrize("assist", ["commit", "blend", "hindsight", "none"])
def test_a_hesitation_before_the_first_push_delays_the_pick_by_exactly_itself(
    assist: str,
) -> None:
    # nothing moves while the stick is held still (no help acts on a zero deflection), so a
    # user who waits 2 s before the first push does the same pick 2 s later: the times from
    # the pick's start grow by the wait, the commit time (from the first push) does not
    sc = load_scene("breakfast_easy")
    ev = Evaluator(sc, assist=assist)  # type: ignore[arg-type]
    ev.prepare(sc.default_layout())
    now = ev.pick("banana", np.random.default_rng(3))
    later = ev.pick("banana", np.random.default_rng(3), onset=2.0)
    assert now.completed and later.completed
    assert now.grasp_time is not None and later.grasp_time is not None
    assert later.grasp_time == pytest.approx(now.grasp_time + 2.0, abs=1e-9)
    assert later.complete_time == pytest.approx(now.complete_time + 2.0, abs=1e-9)  # type: ignore[operator]
    assert later.commit_time == now.commit_time
    assert later.effort == pytest.approx(now.effort)
