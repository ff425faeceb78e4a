"""Plan files: round trip, look-ups, and one clear line per malformed field."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose
from legws_daemon.task.plan import Plan, PlannedDecision, image_name
from legws_daemon.task.plan_file import dump_plan, load_plan, plan_to_data


def feeding_plan() -> Plan:
    layout = {
        "strawberry": ObjectPose(0.7, 0.1, 0.0),
        "grape": ObjectPose(0.62, -0.05, 0.5),
        "brownie": ObjectPose(0.7, -0.2, -1.0),
    }
    moved = {**layout, "grape": ObjectPose(0.4, 0.2, 0.25)}
    food = ("strawberry", "grape", "brownie")
    return Plan(
        taskgraph="feeding",
        scene="feeding",
        key="0123456789abcdef0123",
        settings={"method": "cma-me", "iterations": 10, "seed": 0, "version": "0.1.0"},
        decisions=(
            PlannedDecision("choose_food", ("choose_food",), food, dict.fromkeys(food, "pick"),
                            True, food, moved, 2.5, 0.3, True, "choose_food.png", "optimised",
                            0.72, 3, 0.81),
            PlannedDecision("dip|feed", ("dip", "feed"),
                            ("chocolate_bowl", "sprinkles_bowl", "mouth"),
                            {"chocolate_bowl": "dip", "sprinkles_bowl": "dip", "mouth": "feed"},
                            True, (), moved, 1.2, 1.2, True, None, "certified, not optimised"),
            PlannedDecision("feed", ("feed",), ("mouth",), {"mouth": "feed"}, False, (), moved,
                            None, None, False, "feed.png", "no inference needed; out of reach"),
        ),
        seconds=1.5,
    )  # fmt: skip


def write(tmp_path: Path, data: Any) -> Path:
    path = tmp_path / "plan.json"
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def test_round_trip(tmp_path: Path) -> None:
    plan = feeding_plan()
    path = tmp_path / "plan.json"
    path.write_bytes(dump_plan(plan))
    loaded = load_plan(path, load_scene("feeding"))
    assert loaded == plan
    assert loaded.directory == tmp_path
    assert json.loads(path.read_text())["schema"] == 1


def test_look_ups() -> None:
    plan = feeding_plan()
    assert plan.labels == ("choose_food", "dip|feed", "feed")
    assert plan.decision("feed|dip") is plan.decision("dip|feed")
    layout = plan.layout_for("choose_food")
    assert layout["grape"] == ObjectPose(0.4, 0.2, 0.25)
    layout["grape"] = ObjectPose(0.0, 0.0, 0.0)  # a copy: the plan is unchanged
    assert plan.layout_for("choose_food")["grape"] == ObjectPose(0.4, 0.2, 0.25)
    assert plan.image_path("feed") is None  # no folder yet
    assert image_name("dip|feed") == "dip+feed.png"
    with pytest.raises(InputError, match=r"decisions: choose_food, dip\|feed, feed"):
        plan.layout_for("serve")


def test_plans_without_the_commit_fields_still_load(tmp_path: Path) -> None:
    data = plan_to_data(feeding_plan())
    for d in data["decisions"]:
        del d["commit_objective"], d["commit_certified"], d["commit_rate_estimate"]
    loaded = load_plan(write(tmp_path, data))
    assert all(d.commit_objective is None for d in loaded.decisions)
    assert feeding_plan().decisions[0].commit_objective == 0.72


def _set(data: dict[str, Any], path: tuple[Any, ...], value: Any) -> None:
    for key in path[:-1]:
        data = data[key]
    if value is KeyError:
        del data[path[-1]]
    else:
        data[path[-1]] = value


@pytest.mark.parametrize(
    ("path", "value", "field", "message"),
    [
        (("schema",), 2, "schema", "1"),
        (("decisions", 0, "layout", "grape", "x"), "far", "decisions[0].layout.grape.x",
         "valid number"),
        (("decisions", 0, "layout", "grape", "yaw"), KeyError, "decisions[0].layout.grape.yaw",
         "Field required"),
        (("decisions", 1, "certificate"), None, "decisions[1].certificate", "expected a number"),
        (("decisions", 2, "certificate"), 1.0, "decisions[2].certificate", "null (no inference)"),
        (("decisions", 1, "label"), "feed|dip", "decisions[1].label", "expected 'dip|feed'"),
        (("decisions", 2, "label"), "dip|feed", "decisions[2].label", "expected 'feed'"),
        (("decisions", 0, "image"), "food.png", "decisions[0].image", "'choose_food.png'"),
        (("decisions", 0, "feasible"), "yes", "decisions[0].feasible", "valid boolean"),
        (("decisions", 0, "optimised"), ["mouth"], "decisions[0].optimised[0]",
         "not a candidate"),
        (("decisions", 0, "actions", "grape"), "eat", "decisions[0].actions.grape", "'pick'"),
        (("decisions", 0, "colour"), "red", "decisions[0].colour", "Extra inputs"),
        (("decisions",), [], "decisions", "at least 1"),
        (("key",), "not hex", "key", "pattern"),
        (("decisions", 2, "commit_objective"), 0.5, "decisions[2].commit_objective",
         "null (no inference)"),
        (("decisions", 0, "commit_certified"), 4, "decisions[0].commit_certified",
         "at most one per candidate"),
        (("decisions", 0, "commit_certified"), -1, "decisions[0].commit_certified",
         "greater than or equal"),
        (("decisions", 0, "commit_rate_estimate"), 1.5, "decisions[0].commit_rate_estimate",
         "less than or equal to 1"),
        (("decisions", 2, "commit_rate_estimate"), 0.5, "decisions[2].commit_rate_estimate",
         "null (no inference)"),
    ],
)  # fmt: skip
def test_malformed_plan_names_file_and_field(
    tmp_path: Path, path: tuple[Any, ...], value: Any, field: str, message: str
) -> None:
    data = copy.deepcopy(plan_to_data(feeding_plan()))
    _set(data, path, value)
    p = write(tmp_path, data)
    with pytest.raises(InputError) as info:
        load_plan(p)
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"{p}:1: {field}: "), text  # one line of JSON: every field on line 1
    assert message in text


def test_duplicate_labels_and_scene_mismatch(tmp_path: Path) -> None:
    data = plan_to_data(feeding_plan())
    data["decisions"].append(copy.deepcopy(data["decisions"][2]))
    with pytest.raises(InputError, match=r"decisions\[3\]\.label: 'feed' appears twice"):
        load_plan(write(tmp_path, data))
    data = plan_to_data(feeding_plan())
    with pytest.raises(InputError, match="scene: expected scene 'tea', got 'feeding'"):
        load_plan(write(tmp_path, data), load_scene("tea"))
    data["decisions"][0]["layout"]["mouth"] = {"x": 0.4, "y": 0.6, "yaw": 0.0}
    with pytest.raises(InputError, match=r"decisions\[0\]\.layout\.mouth: 'mouth' is not a mov"):
        load_plan(write(tmp_path, data), load_scene("feeding"))
    with pytest.raises(InputError, match="invalid JSON at line 1"):
        load_plan(write(tmp_path, "{"))
    with pytest.raises(InputError, match="no such file"):
        load_plan(tmp_path / "missing.json")


def test_check_plan_against_graph_and_scene_names_file_field_and_stage() -> None:
    """The checks of loading (``check_plan``; real plans: tests/design/test_plan_validation.py)."""
    from dataclasses import replace

    from legws_daemon.core.params import Params
    from legws_daemon.task.plan_file import check_plan, plan_params
    from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

    graph, scene = load_taskgraph(resolve_taskgraph("feeding"))
    plan = feeding_plan()  # made up: no bowls in its layouts, invented certificates
    with pytest.raises(InputError) as info:
        check_plan(plan, graph, scene, "p/plan.json")
    assert str(info.value) == (
        "p/plan.json: decisions[0].layout: stage 'choose_food': no pose of the movable "
        "object(s) chocolate_bowl, sprinkles_bowl"
    )
    tea, tea_scene = load_taskgraph(resolve_taskgraph("tea"))
    with pytest.raises(InputError, match="taskgraph: the plan is for task graph 'feeding'"):
        check_plan(plan, tea, tea_scene, "p/plan.json")
    assert plan_params(plan, "p") == Params()  # no settings.params: the method's defaults
    odd = replace(plan, settings={"params": {"alpha": 2.0}})
    with pytest.raises(InputError, match=r"^p: settings\.params\.alpha: expected a number in"):
        plan_params(odd, "p")
    with pytest.raises(InputError, match=r"^p: settings\.params\.gamma: Extra inputs"):
        plan_params(replace(plan, settings={"params": {"gamma": 1}}), "p")
