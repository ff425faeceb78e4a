"""Each arm runs the task-graph demos: the controller and the simulated user in-process on
the stand-in of that arm, every decision completed and correct (``legws demo tea --robot
ARM`` runs the same through the daemon process)."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.arms import arm as spec
from legws_daemon.arms import arm_names
from legws_daemon.demo.inprocess import run_inprocess
from legws_daemon.demo.run import summarise
from legws_daemon.formats.profile import load_profile_named, with_arm
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph


@pytest.mark.parametrize("arm", [a for a in arm_names() if a != "sawyer"])
@pytest.mark.parametrize("graph_name", ["tea", "lego", "feeding"])
def test_every_decision_of_the_demo_completes_on_the_arm(arm: str, graph_name: str) -> None:
    graph, scene = load_taskgraph(resolve_taskgraph(graph_name))
    profile = with_arm(load_profile_named("sim"), arm)
    controller, events, user = run_inprocess(profile, graph, scene, seed=0)
    # the stand-in was that arm: its home configuration has the arm's joints, its speed
    # limits are the arm's
    adapter = controller.adapter
    assert isinstance(adapter, SimAdapter) and adapter.q_home is not None
    assert len(adapter.q_home) == spec(arm).dof
    assert np.all(adapter.speed_limits <= np.array(spec(arm).speed_limits))
    assert controller.mode == "idle", [e for e in events if e["kind"] in ("fault", "warning")]
    decisions = summarise(events, user.chosen)
    assert decisions and all(d.correct for d in decisions), decisions
    assert any(e["kind"] == "task_done" for e in events)
