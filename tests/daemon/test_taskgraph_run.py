"""Task graphs run by the controller on the stand-in: stages, choices, actions, repeats."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.core.params import Params
from legws_daemon.daemon.controller import Controller
from legws_daemon.daemon.inbox import JoystickInbox, Sample
from legws_daemon.formats.profile import ProfileSpec, load_profile
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import Scene
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sim.toml"


@pytest.fixture(scope="module")
def profile() -> ProfileSpec:
    p = load_profile(PROFILE)
    return p.model_copy(update={"sim": p.sim.model_copy(update={"realtime": False})})


class User:
    """Drives toward the chosen goal of each stage, hands off during assistance."""

    def __init__(self, controller: Controller) -> None:
        self.c = controller
        self.inbox = JoystickInbox()
        self.seq = 0

    def sample(self, axes: Any, confirm: bool = False) -> Sample:
        self.seq += 1
        msg = {"schema": 1, "seq": self.seq, "stamp": 0.0, "axes": [float(a) for a in axes],
               "buttons": {"confirm": confirm}}  # fmt: skip
        s = self.inbox.offer(json.dumps(msg).encode(), float(self.seq))
        assert s is not None
        return s

    def run(self, choices: list[str], limit: int = 20000) -> None:
        """Ticks until the task is done, going for ``choices`` in order in inference stages."""
        todo = list(choices)
        for _ in range(limit):
            c = self.c
            if c.mode == "idle":
                return
            if c.mode == "teleop":
                goal = next(g for g in todo if g in c.stage.goal_names)
                p = c.adapter.read_state().ee_position
                d = c.stage.target(goal).position - p
                n = float(np.linalg.norm(d))
                # at the goal without a commit (an ambiguous layout): confirm, as a person would
                c.tick(self.sample(d / n, False) if n > 0.01 else self.sample([0, 0, 0], True))
                if c.mode != "teleop":
                    todo.remove(goal)
            else:
                c.tick(self.sample([0.0, 0.0, 0.0]))
        raise AssertionError(f"not done: mode {self.c.mode}, stage {self.c.stage.name}")


def run_graph(profile: ProfileSpec, name: str, choices: list[str]) -> tuple[Controller, list[Any]]:
    graph, scene = load_taskgraph(resolve_taskgraph(name))
    events: list[tuple[str, dict[str, Any]]] = []

    def make(sc: Scene) -> SimAdapter:
        a = SimAdapter(profile, sc)
        a.connect()
        return a

    c = Controller(
        profile, scene, scene.default_layout(), make, Params(), lambda k, d: events.append((k, d)),
        graph=graph,
    )  # fmt: skip
    User(c).run(choices)
    return c, events


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
