"""Actions as objects: each name has exactly one, and what an action allows and changes in a
task run is decided by the object (no string dispatch, no fallback for an unknown name)."""

from __future__ import annotations

from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.task.actions import Dip, Feed, Pick, Place, Return, action
from legws_daemon.task.graph import ACTIONS
from legws_daemon.task.runner import TaskRun
from legws_daemon.task.taskgraph_file import load_taskgraph

ROOT = Path(__file__).resolve().parents[2]


def test_every_action_name_has_its_own_object() -> None:
    kinds = {n: type(action(n)) for n in ACTIONS}
    assert kinds == {"pick": Pick, "place": Place, "dip": Dip, "feed": Feed, "return": Return}
    assert all(action(n).name == n for n in ACTIONS)


def test_an_unknown_action_is_an_error_not_a_feeding_plan() -> None:
    with pytest.raises(InputError, match=r"unknown action 'wave'.*known: pick") as err:
        action("wave")
    assert err.value.field == "action"


def test_what_each_action_needs_and_leaves() -> None:
    assert [action(n).needs_held for n in ACTIONS] == [False, True, True, True, True]
    assert [action(n).holds_after for n in ACTIONS] == [True, False, None, False, False]
    assert [n for n in ACTIONS if action(n).takes_object] == ["pick"]
    assert [n for n in ACTIONS if action(n).at_places] == ["place", "feed"]
    assert [n for n in ACTIONS if not action(n).follows_layout] == ["return"]


def test_a_picked_brick_is_used_up_and_a_placed_one_leaves_the_gripper() -> None:
    graph, scene = load_taskgraph(ROOT / "taskgraphs" / "lego.toml")
    run = TaskRun(graph, scene)
    layout = scene.default_layout()
    bricks = [c for c, _ in run.candidates()]
    assert "red_brick" in bricks
    run.advance("red_brick", layout)
    assert run.held == "red_brick" and run.consumed == {"red_brick"}
    assert run.picked_from["red_brick"] == layout["red_brick"]
    assert {s.action for _, s in run.candidates()} == {"place"}
    run.advance(run.candidates()[0][0], layout)
    assert run.held is None
    # the graph repeats: the used-up brick is no candidate any more
    again = [c for c, _ in run.candidates()]
    assert again == [b for b in bricks if b != "red_brick"]


def test_only_the_held_object_can_be_returned() -> None:
    graph, scene = load_taskgraph(ROOT / "taskgraphs" / "lego.toml")
    run = TaskRun(graph, scene)
    ret = action("return")
    assert not ret.available("red_brick", run)
    run.held = "red_brick"
    assert ret.available("red_brick", run) and not ret.available("blue_brick", run)
    pick = action("pick")
    assert pick.available("red_brick", run)
    run.consumed.add("red_brick")
    assert not pick.available("red_brick", run)
