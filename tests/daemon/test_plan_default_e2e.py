"""Task graphs run hands-off by default: the daemon takes the graph's plan (planned before
the loop starts when none is cached, with progress), and warns at start for each decision
whose commit certificate means confirms will be needed (real daemon processes)."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

from legws_daemon.autonomy.confirms import confirm_forecast
from legws_daemon.core.params import Params
from legws_daemon.design.stage_plan import cached_plan
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from tests.daemon.procs import LEGWS, env, write_profile
from tests.net import free_port

pytestmark = pytest.mark.slow
WARNING = re.compile(
    r"legws daemon: confirms needed: decision (\S+) "
    r"\((the plan's layout|the layout without a plan)\): "
    r"(\d) of (\d) goals not commit-certified \(K [0-9.]+\): ([a-z_, ]+) — steered at straight"
)


def daemon(tmp_path: Path, cache: Path, *args: str) -> str:
    """Run the daemon on the lego task for a moment; its log."""
    profile = write_profile(tmp_path, "sim", free_port())
    e = {**env(), "XDG_CACHE_HOME": str(cache)}
    done = subprocess.run(
        [*LEGWS, "daemon", "--profile", str(profile), "--taskgraph", "lego", "--duration", "1",
         *args],
        capture_output=True, text=True, timeout=240, check=False, env=e,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return done.stderr


def forecast(log: str) -> dict[str, tuple[str, list[str], int]]:
    """decision -> (layout, the goals not certified, of how many) from the log's warnings."""
    return {
        m[1]: (m[2], sorted(m[5].split(", ")), int(m[4]))
        for m in (WARNING.search(line) for line in log.splitlines())
        if m is not None
    }


def test_a_task_graph_runs_on_its_plan_unless_told_otherwise(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    # told otherwise: the shipped layout, and every decision will need confirms
    log = daemon(tmp_path, cache, "--plan", "none")
    assert "planning" not in log and "cached plan" not in log
    shipped = forecast(log)
    assert set(shipped) == {"pick_brick", "sort"}, log
    assert all(layout == "the layout without a plan" for layout, _, _ in shipped.values())
    assert shipped["pick_brick"][1:] == (["blue_brick", "green_brick", "red_brick",
                                           "yellow_brick"], 4)  # fmt: skip

    # by default: no cached plan, so it is planned before the loop starts, with progress
    log = daemon(tmp_path, cache)
    assert "legws daemon: no cached plan of lego: planning it now, before the control loop" in log
    assert re.search(r"legws daemon: planned lego in \d+ s", log), log
    assert "it/s" in log or "%|" in log  # the searches' progress bars
    planned = forecast(log)
    os.environ["XDG_CACHE_HOME"], before = str(cache), os.environ["XDG_CACHE_HOME"]
    try:
        graph, scene = load_taskgraph(resolve_taskgraph("lego"))
        plan = cached_plan(graph, scene)
    finally:
        os.environ["XDG_CACHE_HOME"] = before
    assert plan is not None
    expected = {
        d.decision: ("the plan's layout", sorted(d.uncertified), len(d.goals))
        for d in confirm_forecast(graph, scene, scene.default_layout(), plan, Params())
        if d.confirms
    }
    assert planned == expected  # what the log says is the plan's commit certificate
    assert len(planned) < len(shipped) or sum(len(g) for _, g, _ in planned.values()) < 8

    # and the next start takes the cached plan at once
    log = daemon(tmp_path, cache)
    assert "legws daemon: lego runs on its cached plan (" in log
    assert "planning it now" not in log
    assert forecast(log) == planned
