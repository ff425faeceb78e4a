"""Stage-specific layouts: decision points, the decision's goal model, plans of the shipped
graphs (constraints, which objects move, J), the cache, and honest failure reports."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import certify_commit, commit_rate_estimate
from legws_daemon.core.params import Params
from legws_daemon.design import stage_plan
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.design.search import SearchResult, search
from legws_daemon.design.stage_goals import TargetGoals
from legws_daemon.design.stage_plan import plan_taskgraph
from legws_daemon.errors import InputError
from legws_daemon.robot.feasibility import check_grasps
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.render import RenderUnavailableError
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.task.actions import target
from legws_daemon.task.decisions import decision_points
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.plan_file import check_plan, load_plan
from legws_daemon.task.targets import goal_set
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

GRAPHS = ("tea", "lego", "feeding")
ITERATIONS = 20


def load(name: str) -> tuple[TaskGraph, Scene]:
    return load_taskgraph(resolve_taskgraph(name))


def test_decision_points_of_the_shipped_graphs() -> None:
    labels = {n: [p.label for p in decision_points(load(n)[0])] for n in GRAPHS}
    assert labels == {
        "tea": ["choose_tea", "steep", "choose_snack", "serve"],
        "lego": ["pick_brick", "sort"],  # the repeat offers pick_brick again: same decision
        "feeding": ["choose_food", "dip|feed", "feed"],
    }
    feeding = decision_points(load("feeding")[0])
    assert [p.parent for p in feeding] == [None, 0, 1]
    assert feeding[1].candidates == ("chocolate_bowl", "sprinkles_bowl", "mouth")
    assert feeding[1].actions["mouth"] == "feed"
    assert [p.inference for p in feeding] == [True, True, False]


@pytest.mark.parametrize(("graph", "label"), [("lego", "sort"), ("feeding", "dip|feed")])
def test_batched_goals_are_the_targets_of_the_daemon(graph: str, label: str) -> None:
    g, sc = load(graph)
    point = next(p for p in decision_points(g) if p.label == label)
    placed = tuple(c for c in point.candidates if c in sc.movable)
    base = sc.default_layout()
    goals = TargetGoals(sc, point, placed, base)
    rng = np.random.default_rng(4)
    poses = np.stack(
        [rng.uniform(0.3, 0.8, (5, len(placed))), rng.uniform(-0.4, 0.4, (5, len(placed))),
         rng.uniform(-np.pi, np.pi, (5, len(placed)))], axis=-1,
    )  # fmt: skip
    batch = goals.poses(poses)
    for b in range(5):
        layout = {**base, **{n: ObjectPose(*poses[b, k]) for k, n in enumerate(placed)}}
        for j, name in enumerate(point.candidates):
            t = target(sc, layout, point.stage_of[name], point.actions[name], name)
            np.testing.assert_allclose(batch.positions[b, j], t.position, atol=1e-12)
            np.testing.assert_allclose(batch.rotations[b, j], t.rotation, atol=1e-12)
            assert batch.symmetry[j] == t.symmetry


def test_one_placed_object_with_goals_that_stay_put() -> None:
    # feeding's dip|feed with only the chocolate bowl placed: K = 1, three goals
    g, sc = load("feeding")
    point = decision_points(g)[1]
    base = sc.default_layout()
    goals = TargetGoals(sc, point, ("chocolate_bowl",), base)
    assert goals.anchors.shape == (2, 2)  # the sprinkles bowl's target and the mouth
    problem = LayoutProblem(sc, ["chocolate_bowl"], Params(), goals=goals, base=base)
    poses = problem.constraints.sample(8, np.random.default_rng(0))
    ev = problem.evaluate(problem.encode(poses))
    assert np.all(np.isfinite(ev.measures))
    for i in range(8):
        layout = {**base, "chocolate_bowl": ObjectPose(*poses[i, 0])}
        ts = [target(sc, layout, point.stage_of[c], a, c) for c, a in point.actions.items()]
        j = certify(goal_set(ts, sc.home), Params()).objective
        assert ev.certificate[i] == pytest.approx(j, rel=1e-9)
    with pytest.raises(InputError, match="at least 2 goals"):
        LayoutProblem(sc, ["grape"], goals=TargetGoals(sc, decision_points(g)[2], (), base))


def test_clearance_counts_the_objects_where_the_decision_starts() -> None:
    _, sc = load("tea")
    base = {**sc.default_layout(), "black_tea": ObjectPose(0.5, -0.3, 0.0)}
    snacks = ["cookie", "cracker", "biscotti"]
    problem = LayoutProblem(sc, snacks, base=base)
    i = problem.constraints.fixed_names.index("black_tea")
    np.testing.assert_allclose(problem.constraints.fixed_xy[i], [0.5, -0.3])


@pytest.fixture(scope="module")
def plans(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Plan]:
    out = tmp_path_factory.mktemp("plans")
    return {
        name: plan_taskgraph(*load(name), iterations=ITERATIONS, use_cache=False,
                             out_dir=out / name)
        for name in GRAPHS
    }  # fmt: skip


@pytest.mark.parametrize("name", GRAPHS)
def test_every_decision_has_a_feasible_layout(plans: dict[str, Plan], name: str) -> None:
    graph, sc = load(name)
    plan = plans[name]
    points = decision_points(graph)
    assert plan.labels == tuple(p.label for p in points)
    constraints = LayoutConstraints.of(sc)
    for point, d in zip(points, plan.decisions, strict=True):
        assert set(d.layout) == set(sc.movable)
        assert constraints.problems(sc.poses(d.layout)) == [], d.label
        assert d.feasible, d.note
        before = (
            sc.default_layout() if point.parent is None else plan.decisions[point.parent].layout
        )
        moved = {n for n in d.layout if d.layout[n] != before[n]}
        assert moved <= set(d.optimised), d.label
        for n in d.optimised:
            assert n in point.candidates and n not in graph.fixed


@pytest.mark.parametrize("name", GRAPHS)
def test_plans_pass_the_checks_of_loading(plans: dict[str, Plan], name: str) -> None:
    """What the planner writes is what loading a plan accepts (``check_plan``: the layout
    rule of ``--layout``, moves only of the optimised objects, the recorded certificates):
    a cached plan is never planned again for failing them."""
    graph, sc = load(name)
    plan = plans[name]
    assert plan.directory is not None
    path = plan.directory / "plan.json"
    assert check_plan(load_plan(path, sc), graph, sc, str(path)) == plan


@pytest.mark.parametrize("name", GRAPHS)
def test_certificates_improve_and_single_candidates_need_no_inference(
    plans: dict[str, Plan], name: str
) -> None:
    graph, sc = load(name)
    for point, d in zip(decision_points(graph), plans[name].decisions, strict=True):
        if not d.inference:
            assert d.certificate is None and d.certificate_start is None
            assert d.optimised == ()
            assert "no inference needed" in d.note
            continue
        assert d.certificate is not None and d.certificate_start is not None
        ts = [target(sc, d.layout, point.stage_of[c], a, c) for c, a in point.actions.items()]
        assert certify(goal_set(ts, sc.home), Params()).objective == pytest.approx(d.certificate)
        if d.optimised:
            assert d.certificate > d.certificate_start  # the shipped layouts are far from best
        else:
            assert d.certificate == d.certificate_start


def test_commit_objective_per_decision(plans: dict[str, Plan]) -> None:
    """With --objective commit every optimised decision lowers K (the latest certified
    commit); plan.json records K and the certified count for every inference decision,
    for either objective."""
    graph, sc = load("tea")
    plan = plan_taskgraph(graph, sc, iterations=ITERATIONS, use_cache=False, render=False,
                          objective="commit")  # fmt: skip
    assert plan.settings["objective"] == "commit"
    assert "objective" not in plans["tea"].settings  # slack plans keep their cache key
    for point, d in zip(decision_points(graph), plan.decisions, strict=True):
        if not d.inference:
            assert d.commit_objective is None and d.commit_certified is None
            assert d.commit_rate_estimate is None
            continue
        ts = [target(sc, d.layout, point.stage_of[c], a, c) for c, a in point.actions.items()]
        k = certify_commit(goal_set(ts, sc.home), Params())
        assert d.commit_objective == pytest.approx(k.objective)
        assert d.commit_certified == k.certified
        assert d.commit_rate_estimate == commit_rate_estimate(goal_set(ts, sc.home), Params())
        assert d.feasible, d.note
        if d.optimised:
            start = plans["tea"].decision(d.label)
            assert start.commit_objective is not None
            assert "K " in d.note
            # every tea choice gets certified commits (the exact-sum K the design minimises)
            exact = certify_commit(goal_set(ts, sc.home), Params(), form="sum")
            assert d.commit_objective is not None
            assert exact.objective <= 1.0 and exact.objective <= d.commit_objective


def test_what_is_optimised_where(plans: dict[str, Plan]) -> None:
    feeding = plans["feeding"]
    assert feeding.decision("choose_food").optimised == ("strawberry", "grape", "brownie")
    # the bowls are fixed by the graph and the mouth is a place: certified, not optimised
    assert feeding.decision("feed|dip").optimised == ()
    assert "not optimised" in feeding.decision("dip|feed").note
    assert plans["lego"].decision("sort").optimised == ("bin_a", "bin_b", "bin_c", "bin_d")
    # the snacks are placed around the teas where the first decision put them
    tea = plans["tea"]
    teas = ("black_tea", "green_tea", "chamomile_tea")
    for n in teas:
        assert tea.layout_for("choose_snack")[n] == tea.layout_for("choose_tea")[n]


def test_pick_grasps_pass_the_full_check_independently(plans: dict[str, Plan]) -> None:
    _, sc = load("lego")
    layout = plans["lego"].layout_for("pick_brick")
    world = World(sc)
    q = home_configuration(world, sc.home.position, sc.home.rotation).q
    bricks = ["red_brick", "blue_brick", "yellow_brick", "green_brick"]
    checks = check_grasps(world, sc.goal_set(layout, bricks), q, sc.poses(layout))
    assert all(c.feasible for c in checks.values())


def test_pictures_and_plan_file_are_written(plans: dict[str, Plan]) -> None:
    plan = plans["feeding"]
    assert plan.directory is not None and not plan.cached
    assert load_plan(plan.directory / "plan.json") == plan
    path = plan.image_path("dip|feed")
    assert path is not None and path.name == "dip+feed.png"
    with Image.open(path) as img:
        assert img.size == (800, 600)
        assert img.format == "PNG"


def counting_search(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls: list[int] = []

    def counted(*args: Any, **kwargs: Any) -> SearchResult:
        calls.append(1)
        return search(*args, **kwargs)

    monkeypatch.setattr(stage_plan, "search", counted)
    return calls


def test_cache_is_reused_and_follows_the_graph_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    calls = counting_search(monkeypatch)
    graph, sc = load("feeding")
    first = plan_taskgraph(graph, sc, iterations=5, render=False)
    assert (len(calls), first.cached) == (1, False)
    assert first.directory == tmp_path / "cache" / "legws" / "plan" / first.key
    again = plan_taskgraph(graph, sc, iterations=5, render=False)
    assert (len(calls), again.cached) == (1, True)
    assert again == first
    other_seed = plan_taskgraph(graph, sc, iterations=5, seed=1, render=False)
    assert len(calls) == 2 and other_seed.key != first.key
    copy = tmp_path / "feeding.toml"
    copy.write_text(Path(graph.source).read_text() + "\n# edited\n")
    edited, _ = load_taskgraph(copy, sc)
    changed = plan_taskgraph(edited, sc, iterations=5, render=False)
    assert len(calls) == 3 and not changed.cached and changed.key != first.key
    fresh = plan_taskgraph(graph, sc, iterations=5, render=False, use_cache=False)
    assert len(calls) == 4 and fresh.directory is None


def test_corrupt_cache_is_planned_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    calls = counting_search(monkeypatch)
    graph, sc = load("feeding")
    first = plan_taskgraph(graph, sc, iterations=5, render=False)
    assert first.directory is not None
    (first.directory / "plan.json").write_text("{")
    again = plan_taskgraph(graph, sc, iterations=5, render=False)
    assert len(calls) == 2 and not again.cached
    assert again.directory == first.directory
    assert load_plan(first.directory / "plan.json") == again


def test_no_gl_means_no_pictures_and_a_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from legws_daemon.design import plan_render

    def no_gl(*_: object, **__: object) -> bytes:
        raise RenderUnavailableError("cannot create an OpenGL context")

    monkeypatch.setattr(plan_render, "decision_picture", no_gl)
    with caplog.at_level(logging.WARNING, logger="legws.plan"):
        plan = plan_taskgraph(*load("feeding"), iterations=3, use_cache=False, out_dir=tmp_path)
    assert all(d.image is None for d in plan.decisions)
    assert "OpenGL" in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.json"]


@pytest.mark.slow  # plans a scene whose target no layout reaches: ~4 s
def test_unreachable_target_is_reported_not_hidden(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the feeding scene with the mouth 1.6 m away, and the bowls free to move
    text = (Path(load_scene("feeding").source)).read_text()
    scene_file = tmp_path / "feeding.toml"
    scene_file.write_text(
        text.replace("position = [0.40, 0.62, 0.40]", "position = [1.6, 0.0, 0.4]")
    )
    sc = load_scene(str(scene_file))
    graph_text = Path(resolve_taskgraph("feeding")).read_text()
    graph_file = tmp_path / "graphs" / "feeding.toml"
    graph_file.parent.mkdir()
    graph_file.write_text(graph_text.replace('fixed = ["chocolate_bowl", "sprinkles_bowl"]', ""))
    graph, _ = load_taskgraph(graph_file, sc)
    checks: list[str] = []
    check = stage_plan._Planner.check

    def counted(self: Any, point: Any, layout: Any, moving: Any = ()) -> Any:
        checks.append(point.label)
        return check(self, point, layout, moving)

    monkeypatch.setattr(stage_plan._Planner, "check", counted)
    plan = plan_taskgraph(graph, sc, iterations=3, use_cache=False, render=False)
    # the mouth does not move: once it is out of reach no other elite is tried
    assert checks.count("dip|feed") <= 2, checks
    choice = plan.decision("dip|feed")
    assert choice.optimised == ("chocolate_bowl", "sprinkles_bowl")
    assert not choice.feasible
    assert "mouth (feed): out of reach" in choice.note
    assert not plan.decision("feed").feasible
    assert plan.decision("choose_food").feasible


def test_bad_settings_are_input_errors() -> None:
    graph, sc = load("feeding")
    with pytest.raises(InputError, match="known: cma-me"):
        plan_taskgraph(graph, sc, method="random")
    with pytest.raises(InputError, match="at least 1 iteration"):
        plan_taskgraph(graph, sc, iterations=0)
    with pytest.raises(InputError, match="known: slack, commit"):
        plan_taskgraph(graph, sc, objective="fast")
    plan = Plan("g", "s", "0" * 20, {}, ())
    with pytest.raises(InputError, match="no decision 'x'"):
        plan.decision("x")
