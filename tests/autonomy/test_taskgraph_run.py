"""Task graphs run by the controller on the stand-in: stages, choices, actions, repeats."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.modes import Mode
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.scene.grasps import extents
from tests.autonomy.rig import Rig, stand_in_profile


@pytest.fixture(scope="module")
def profile() -> ProfileSpec:
    return stand_in_profile()


def run_graph(
    profile: ProfileSpec, name: str, choices: list[str], limit: int = 20000
) -> tuple[Controller, list[Any]]:
    """Tick until the task is done, going for ``choices`` in order in inference stages
    (at the goal without a commit: confirm, as a person would); hands off in assistance."""
    rig = Rig.of(profile, name)
    c = rig.c
    todo = list(choices)
    for _ in range(limit):
        if c.mode == Mode.IDLE:
            return c, rig.events
        if c.mode == Mode.TELEOP:
            goal = next(g for g in todo if g in c.stage.goal_names)
            d = c.stage.target(goal).position - c.adapter.read_state().ee_position
            n = float(np.linalg.norm(d))
            c.tick(rig.sample(d / n) if n > 0.01 else rig.sample([0, 0, 0], confirm=True))
            if c.mode != Mode.TELEOP:
                todo.remove(goal)
        else:
            c.tick(rig.hands_off())
    raise AssertionError(f"not done: mode {c.mode}, stage {c.stage.name}")


def commits(events: list[Any]) -> list[tuple[str, bool]]:
    """(goal, single-candidate) of every commit."""
    return [(d["goal"], d["single"]) for k, d in events if k == "commit"]


def on_top_of(c: Controller, obj: str, support: str) -> bool:
    assert isinstance(c.adapter, SimAdapter)
    poses = c.adapter.object_poses()
    p, s = poses[obj][0], poses[support][0]
    sx, sy, sz = extents(c.scene.objects[support].shape, tuple(c.scene.objects[support].size))
    return abs(p[0] - s[0]) < sx / 2 and abs(p[1] - s[1]) < sy / 2 and p[2] > s[2] + sz / 2 - 1e-6


def test_tea_picks_places_and_needs_no_inference_for_the_cup(profile: ProfileSpec) -> None:
    c, events = run_graph(profile, "tea", ["green_tea", "cup", "biscotti", "plate"])
    assert commits(events) == [
        ("green_tea", False), ("cup", True), ("biscotti", False), ("plate", True)
    ]  # fmt: skip
    done = [d["stage"] for k, d in events if k == "stage_done"]
    assert done == ["choose_tea", "steep", "choose_snack", "serve"]
    # each stage's own ticks: one begins on the tick the one before it ended, so together
    # they are every tick of the run
    ticks = [d["ticks"] for k, d in events if k == "stage_done"]
    assert all(t > 0 for t in ticks)
    assert sum(ticks) == c.ticks
    assert events[-1][0] == "task_done"
    assert on_top_of(c, "green_tea", "cup")
    assert on_top_of(c, "biscotti", "plate")
    assert c.task.held is None
    np.testing.assert_allclose(
        c.adapter.read_state().ee_position, c.scene.home.position, atol=0.005
    )


@pytest.mark.parametrize(
    ("choices", "stages"),
    [
        (["grape", "sprinkles_bowl", "mouth"], ["choose_food", "dip", "feed"]),
        (["brownie", "mouth"], ["choose_food", "feed"]),
    ],
)
def test_feeding_takes_the_branch_the_user_goes_for(
    profile: ProfileSpec, choices: list[str], stages: list[str]
) -> None:
    c, events = run_graph(profile, "feeding", choices)
    assert [g for g, _ in commits(events)] == choices
    assert [d["stage"] for k, d in events if k == "stage_done"] == stages
    # after the food the user chose between both bowls and the mouth at once
    choice = next(d for k, d in events if k == "commit" and d["goal"] == choices[1])
    assert set(choice["posterior"]) == {"chocolate_bowl", "sprinkles_bowl", "mouth"}
    assert c.task.held is None


def test_lego_repeats_until_every_brick_is_sorted(profile: ProfileSpec) -> None:
    order = ["blue_brick", "bin_b", "red_brick", "bin_a", "green_brick", "bin_d",
             "yellow_brick", "bin_c"]  # fmt: skip
    c, events = run_graph(profile, "lego", order)
    assert [g for g, _ in commits(events)] == order
    assert c.task.rounds == 4
    assert events[-1][0] == "task_done"
    for brick, bin_ in zip(order[::2], order[1::2], strict=True):
        assert on_top_of(c, brick, bin_), brick
    # bricks already sorted are no longer candidates
    picks = [d["posterior"] for k, d in events if k == "commit" and d["action"] == "pick"]
    assert [len(p) for p in picks] == [4, 3, 2, 0]  # the last brick needs no inference
