"""``legws daemon --operator``: every certificate the controller computes is the person's
(``certify_with`` of their file, with the robot's clip), and without one nothing changes."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np
import pytest

from legws_daemon.autonomy.decision import commit_for, decision_goals, slack_for
from legws_daemon.autonomy.events import Commit, PlaceObjects
from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import certify_commit
from legws_daemon.core.geometry import Pose
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from tests.autonomy.operators import Bench
from tests.autonomy.rig import Rig, operator_command, stand_in_profile
from tests.task.test_plan_file import feeding_plan

#: A slower, correlated, biased person: certificates well below section 2's user's.
ALICE = OperatorModel(0.8, 0.035, 0.8, -12.0, "free")


def person(goals: GoalSet, params: Params) -> float:
    return certify(goals, params, ALICE, ALICE.motion(params, clip=True)).objective


def test_without_an_operator_the_certificates_are_section_2s() -> None:
    b = Bench()
    goals = b.c.stage.goals_home
    assert goals is not None
    assert b.c.stage.certificate == certify(goals, b.params).objective
    assert slack_for(goals, b.params) == certify(goals, b.params).objective
    assert commit_for(goals, b.params).objective == certify_commit(goals, b.params).objective


def test_the_decision_live_slack_commit_event_and_placed_layout_are_the_operators() -> None:
    b = Bench(operator=ALICE)
    c, params = b.c, b.params
    goals = c.stage.goals_home
    assert goals is not None
    assert c.stage.certificate == pytest.approx(person(goals, params), abs=1e-12)
    assert c.stage.certificate != pytest.approx(certify(goals, params).objective, abs=0.05)
    # the live slack, from where the EE stands
    b.tick(None, {})
    state = c.last_state
    assert state is not None
    live = dataclasses.replace(goals, x0=Pose(state.ee_position, state.ee_quaternion))
    assert c.live_slack() == pytest.approx(person(live, params), abs=1e-9)
    # a tracker's report: J and K of the placed layout under the operator
    name = c.stage.goal_names[0]
    pose = c.layout[name]
    c.observe({name: dataclasses.replace(pose, x=pose.x + 0.03)})
    report = c.placement
    assert report is not None and report.certificate is not None
    placed = decision_goals(c.task, c.layout, c.scene)  # seen from home, as placed
    assert report.certificate == pytest.approx(person(placed, params), abs=1e-12)
    k = certify_commit(placed, params, ALICE.motion(params, clip=True), operator=ALICE)
    assert report.commit_certificate == pytest.approx(k.objective, abs=1e-12)
    assert report.planned_certificate == c.stage.certificate
    # the commit event carries the decision's certificate: the operator's
    b.pick(name, None, np.random.default_rng(0))
    commits = [e for e in b.events if isinstance(e, Commit)]
    assert commits
    assert commits[-1].certificate == pytest.approx(person(placed, params), abs=1e-12)


@pytest.fixture
def feeding() -> Iterator[Rig]:
    graph, scene = load_taskgraph(resolve_taskgraph("feeding"))
    r = Rig(stand_in_profile(), scene, graph)
    r.c.operator = ALICE
    yield r
    r.c.shutdown()


def test_a_dropped_plan_and_a_placement_request_name_the_operators_certificates(
    feeding: Rig,
) -> None:
    c = feeding.c

    def load(plan: str | None) -> None:
        body: dict[str, object] = {"schema": 1, "command": "load_taskgraph",
                                   "argument": "feeding"}  # fmt: skip
        if plan is not None:
            body["plan"] = plan
        operator_command(c, CommandRequest.model_validate(body), lambda g, s: feeding_plan())

    load("auto")
    planned = feeding_plan().layout_for("choose_food")
    expected_planned = c._decision_certificate(planned)
    assert c.stage.certificate == pytest.approx(expected_planned, abs=1e-12)
    load("none")
    (dropped,) = [d for k, d in feeding.events if k == "warning" and "plan" in d]
    assert dropped["planned_certificate"] == pytest.approx(expected_planned, abs=1e-12)
    assert dropped["planned_certificate"] != 2.5  # not the plan's own (section 2's) number
    assert dropped["certificate"] == pytest.approx(c.stage.certificate)
    # a robot that cannot move objects is asked to, with the operator's certificate
    decision = feeding_plan().decision("choose_food")
    c.layouts.planned.update(planned)
    c._ask_to_place({"grape": planned["grape"]}, decision)
    (ask,) = [e for e in feeding.typed if isinstance(e, PlaceObjects)]
    assert ask.certificate == pytest.approx(expected_planned, abs=1e-12)
