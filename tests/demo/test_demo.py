"""Demos: every shipped graph completes with the simulated user, every branch is taken across
seeds (in-process, as fast as possible), and ``legws demo`` end to end with real processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rerun.chunk import RrdReader

from legws_daemon.autonomy.controller import Controller
from legws_daemon.core.params import Params
from legws_daemon.demo.inprocess import run_inprocess
from legws_daemon.demo.run import summarise
from legws_daemon.formats.profile import ProfileSpec, load_profile_named
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.joystick.sim_user import SimUser
from legws_daemon.scene.scene import Scene
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph
from legws_daemon.telemetry.recording import read_text_log
from tests.daemon.procs import rerun_exe
from tests.plans import seed_cache


@pytest.fixture(scope="module")
def fast() -> ProfileSpec:
    p = load_profile_named("sim")
    return p.model_copy(update={"sim": p.sim.model_copy(update={"realtime": False})})


def run(profile: ProfileSpec, name: str, seed: int) -> tuple[Controller, list[Any], SimUser]:
    graph, scene = load_taskgraph(resolve_taskgraph(name))
    return run_inprocess(profile, graph, scene, seed)


@pytest.mark.parametrize("name", ["tea", "lego", "feeding"])
def test_every_demo_completes_every_stage(fast: ProfileSpec, name: str) -> None:
    c, events, user = run(fast, name, seed=0)
    assert c.mode == "idle"
    assert events[-1]["kind"] == "task_done"
    decisions = summarise(events, user.chosen)
    assert decisions
    assert all(d.correct for d in decisions)
    stages = [e["detail"]["stage"] for e in events if e["kind"] == "stage_done"]
    graph, _ = load_taskgraph(resolve_taskgraph(name))
    assert set(stages) <= set(graph.stages)
    if name == "lego":
        assert len(stages) == 8  # four bricks, each picked and sorted
    if name == "tea":
        assert stages == ["choose_tea", "steep", "choose_snack", "serve"]


def test_feeding_takes_both_branches_across_seeds(fast: ProfileSpec) -> None:
    branches = set()
    for seed in range(6):
        _, events, _ = run(fast, "feeding", seed)
        stages = tuple(e["detail"]["stage"] for e in events if e["kind"] == "stage_done")
        branches.add(stages)
        if len(branches) == 2:
            break
    assert branches == {("choose_food", "dip", "feed"), ("choose_food", "feed")}


@pytest.mark.slow
def test_legws_demo_runs_the_real_daemon_and_writes_the_summary(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    out = tmp_path / "demo"
    # the tea plan cached (as after a first `legws demo tea` or `legws plan tea`)
    cache = seed_cache(tmp_path_factory, tmp_path / "cache")
    plans = sorted((cache / "legws" / "plan").iterdir())
    run = subprocess.run(
        [sys.executable, "-m", "legws_daemon", "demo", "tea", "--out", str(out), "--seed", "1",
         "--timeout", "300"],
        capture_output=True, text=True, timeout=400, check=False,
        env={**os.environ, "XDG_CACHE_HOME": str(cache)},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    assert sorted((cache / "legws" / "plan").iterdir()) == plans  # the cached plan it ran
    assert "legws: the cached plan of tea for the Rethink Sawyer" in run.stderr
    assert "planning the layout" not in run.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is True
    assert [d["decision"] for d in summary["decisions"]] == [
        "choose_tea", "steep", "choose_snack", "serve"
    ]  # fmt: skip
    assert all(d["correct"] for d in summary["decisions"])
    assert [d["single"] for d in summary["decisions"]] == [False, True, False, True]
    assert "| choose_tea | pick |" in (out / "summary.md").read_text()
    rrd = out / "recording.rrd"
    verify = subprocess.run([rerun_exe(), "rrd", "verify", str(rrd)], capture_output=True,
                            timeout=60, check=False)  # fmt: skip
    assert verify.returncode == 0
    commits = [t for _, _, t in read_text_log(rrd) if t.startswith("commit ")]
    assert len(commits) == 4
    assert sum(t.endswith(" how=single") for t in commits) == 2
    _assert_operator_view(rrd)


def _assert_operator_view(rrd: Path) -> None:
    """Read back with rerun's own API: the arm's link meshes, and the posterior, the slack
    and the timing each in a plot of its own in the file's blueprint."""
    reader = RrdReader(rrd)
    meshes = {
        str(c.entity_path)
        for c in reader.stream().filter(components="Mesh3D:vertex_positions").to_chunks()
    }
    assert {"/world/robot/right_l0/mesh", "/world/robot/right_l6/mesh"} <= meshes
    assert len(meshes) >= 8
    views: dict[str, tuple[str, list[str]]] = {}
    contents: dict[str, list[str]] = {}
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch, path = chunk.to_record_batch(), str(chunk.entity_path)
        if "ViewBlueprint:display_name" in batch.schema.names:
            kind = batch.column("ViewBlueprint:class_identifier").to_pylist()[-1][0]
            name = batch.column("ViewBlueprint:display_name").to_pylist()[-1][0]
            views[path] = (kind, name)
        if "ViewContents:query" in batch.schema.names:
            contents[path.removesuffix("/ViewContents")] = batch.column(
                "ViewContents:query"
            ).to_pylist()[-1]
    plots = {name: contents[path] for path, (kind, name) in views.items() if kind == "TimeSeries"}
    assert plots == {
        "posterior": ["/plots/posterior/**", "/plots/threshold", "/plots/commits"],
        "slack": ["/plots/slack"],
        "timing (ms)": ["/plots/timing/**"],
    }
    kinds = sorted(kind for kind, _ in views.values())
    assert kinds == ["3D", "TextDocument", "TextLog", "TimeSeries", "TimeSeries", "TimeSeries"]


def test_a_plan_moves_each_decisions_objects_to_their_planned_poses(fast: ProfileSpec) -> None:
    from legws_daemon.design.stage_plan import plan_taskgraph

    graph, scene = load_taskgraph(resolve_taskgraph("tea"))
    plan = plan_taskgraph(graph, scene, iterations=60, render=False, progress=False)
    events: list[Any] = []

    def make(sc: Scene) -> SimAdapter:
        a = SimAdapter(fast, sc)
        a.connect()
        return a

    c = Controller(
        fast, scene, scene.default_layout(), make, Params(),
        lambda e: events.append((e.kind, e.detail())), graph=graph, plan=plan,
    )  # fmt: skip
    first = plan.decision("choose_tea")
    assert c.stage.certificate == pytest.approx(first.certificate)
    assert isinstance(c.adapter, SimAdapter)
    poses = c.adapter.object_poses()
    for name in first.optimised:
        want = first.layout[name]
        np.testing.assert_allclose(poses[name][0][:2], [want.x, want.y], atol=1e-9)
    # the snacks stay where the scene put them until their decision comes
    default = scene.default_layout()
    np.testing.assert_allclose(poses["cookie"][0][:2], [default["cookie"].x, default["cookie"].y])
