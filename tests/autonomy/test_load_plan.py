"""``load_taskgraph`` over the command key: with ``plan: "auto"`` the graph's plan is used
(its decisions' objects go to their planned poses); a load that drops a plan in use says so
in a warning naming the certificate now and the plan's."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.validation import validate
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from tests.autonomy.rig import Rig, operator_command, stand_in_profile
from tests.task.test_plan_file import feeding_plan


@pytest.fixture
def rig() -> Iterator[Rig]:
    graph, scene = load_taskgraph(resolve_taskgraph("feeding"))
    r = Rig(stand_in_profile(), scene, graph)
    yield r
    r.c.shutdown()


def load(rig: Rig, plan: str | None, plans: object = None) -> dict[str, object]:
    body: dict[str, object] = {"schema": 1, "command": "load_taskgraph", "argument": "feeding"}
    if plan is not None:
        body["plan"] = plan
    loader = plans if plans is not None else (lambda g, s: feeding_plan())
    return operator_command(rig.c, CommandRequest.model_validate(body), loader)  # type: ignore[arg-type]


def test_auto_uses_the_plan_and_plan_none_drops_it_with_a_warning(rig: Rig) -> None:
    asked: list[tuple[TaskGraph, Scene]] = []

    def plans(graph: TaskGraph, scene: Scene) -> Plan:
        asked.append((graph, scene))
        return feeding_plan()

    load(rig, "auto", plans)
    assert [g.name for g, _ in asked] == ["feeding"]
    assert rig.c.layouts.plan is not None
    # choose_food's optimised objects stand where the plan put them (the stand-in moves them)
    grape = rig.adapter.object_poses()["grape"][0]
    np.testing.assert_allclose(grape[:2], [0.4, 0.2], atol=1e-6)
    assert not [d for k, d in rig.events if k == "warning" and "plan" in d]

    load(rig, "none")
    assert rig.c.layouts.plan is None
    dropped = [d for k, d in rig.events if k == "warning" and "plan" in d]
    assert len(dropped) == 1
    warning = dropped[0]
    assert warning["plan"] == "feeding" and warning["stage"] == "choose_food"
    assert warning["planned_certificate"] == 2.5
    assert warning["certificate"] == pytest.approx(rig.c.stage.certificate)


def test_a_load_without_a_plan_in_use_warns_nothing(rig: Rig) -> None:
    load(rig, "none")
    assert not [d for k, d in rig.events if k == "warning" and "plan" in d]


def test_a_plain_load_takes_the_cached_plan_and_says_when_there_is_none(rig: Rig) -> None:
    load(rig, None)  # hands-off by default: the cached plan
    assert rig.c.layouts.plan is not None
    assert not [d for k, d in rig.events if k == "warning"]

    def none(graph: TaskGraph, scene: Scene) -> Plan:
        raise InputError(f"no cached plan of task graph '{graph.name}'; make it with "
                         f"`legws plan {graph.name}`", field="plan")  # fmt: skip

    load(rig, None, none)
    assert rig.c.layouts.plan is None
    warnings = [d for k, d in rig.events if k == "warning"]
    assert warnings[-1] == {
        "no_plan": "feeding",
        "reason": "plan: no cached plan of task graph 'feeding'; make it with `legws plan feeding`",
    }


def test_plan_is_only_for_load_taskgraph_and_needs_a_loader(rig: Rig) -> None:
    with pytest.raises(InputError, match="plan: only with 'load_taskgraph'"):
        validate(CommandRequest, {"schema": 1, "command": "load_scene", "argument": "desk",
                                  "plan": "auto"}, "command")  # fmt: skip
    with pytest.raises(InputError, match="plan"):  # no paths over the network
        validate(CommandRequest, {"schema": 1, "command": "load_taskgraph",
                                  "argument": "feeding", "plan": "/tmp/x"}, "command")  # fmt: skip
    body = {"schema": 1, "command": "load_taskgraph", "argument": "feeding", "plan": "auto"}
    with pytest.raises(InputError, match="no plans"):
        operator_command(rig.c, CommandRequest.model_validate(body))
    assert load_scene("feeding").name == "feeding"
