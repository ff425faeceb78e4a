"""The daemon and ``legws track --source sim:…`` over zenoh loopback: the tracker renders
the layout the daemon runs (a plan's, then the scene file's after a load) and its poses
match it; a displaced object is named with its correction whatever J says, until it is put
back; the verdict's words follow J's sign; an object out of view is reported unseen."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.task.plan_file import load_plan
from tests.daemon.procs import LEGWS, Monitor, env, monitor, ready, start, stop, write_profile
from tests.net import free_port

os.environ.setdefault("MUJOCO_GL", "egl")  # the tracker renders the stand-in's camera
ROBOT = "sawyer_sim"
pytestmark = pytest.mark.slow


def _placement(m: Monitor) -> dict[str, Any] | None:
    s = m.latest()
    return None if s is None else s.get("placement")


def _write(path: Path, layout: dict[str, dict[str, float]]) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(layout))
    tmp.replace(path)  # the tracker never reads half a file


def test_a_displaced_object_is_named_with_its_correction_until_it_is_put_back(
    tmp_path: Path,
) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    layout = tmp_path / "placed.json"
    # green tea 6 cm to the robot's left of its place: next to the black tea, J < 0
    _write(layout, {"green_tea": {"x": 0.72, "y": 0.20, "yaw": 0.0}})
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "tea", "--duration", "150"],
        tmp_path / "daemon.log",
    )
    tracker = None
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            assert _placement(m) is None  # no tracker yet
            tracker = start(
                ["track", "--profile", str(profile), "--source", f"sim:tea:{layout}",
                 "--duration", "120"],
                tmp_path / "track.log",
            )  # fmt: skip

            def warned(m: Monitor) -> bool:
                return any("corrections" in e["detail"] for e in m.events)

            assert m.wait_for(warned, 60), (tmp_path / "track.log").read_text()
            warning = next(e for e in m.events if "corrections" in e["detail"])
            assert warning["kind"] == "warning"
            (text,) = warning["detail"]["corrections"]
            found = re.fullmatch(r"green_tea: (\d+) cm right", text)
            assert found is not None, text
            assert int(found[1]) == 6
            assert warning["detail"]["certificate"] <= 0
            assert warning["detail"]["certified"] is False
            assert warning["detail"]["unseen"] == []
            assert m.wait_for(lambda m: _placement(m) is not None, 2)  # the next status
            placement = _placement(m)
            assert placement is not None
            assert placement["certified"] is False
            assert placement["objects"]["green_tea"]["state"] == "misplaced"
            assert placement["objects"]["green_tea"]["move"]["y"] == pytest.approx(-0.06, abs=0.005)
            assert placement["objects"]["black_tea"]["state"] == "placed"
            assert placement["objects"]["cup"]["state"] == "placed"  # fixed objects too
            assert placement["misplaced"] == ["green_tea"]
            assert m.latest()["certificate"] <= 0  # type: ignore[index]

            # put back where the layout says: the tracker sees it, the daemon certifies it
            _write(layout, {})
            assert m.wait_for(lambda m: "placed" in m.kinds(), 30)
            placed = next(e for e in m.events if e["kind"] == "placed")
            assert placed["detail"]["certificate"] > 0
            assert m.wait_for(lambda m: (_placement(m) or {}).get("certified") is True, 5)
            assert m.latest()["certificate"] > 0  # type: ignore[index]

            # the cookie taken off the table: reported unseen, never moved
            _write(layout, {"cookie": {"x": 2.5, "y": 2.5, "yaw": 0.0}})

            def cookie_unseen(m: Monitor) -> bool:
                p = _placement(m)
                return p is not None and p["objects"]["cookie"]["state"] == "unseen"

            assert m.wait_for(cookie_unseen, 30)
            assert _placement(m)["certified"] is True  # type: ignore[index]  # not a candidate
    finally:
        if tracker is not None:
            code, seconds = stop(tracker)
            assert code == 0 and seconds < 5.0, (tmp_path / "track.log").read_text()
        code, _ = stop(daemon)
    assert code == 0
    log = (tmp_path / "track.log").read_text()
    daemon_log = (tmp_path / "daemon.log").read_text()
    assert "Traceback" not in log and "Traceback" not in daemon_log
    assert re.search(r"tracked \d+ frames \((\d+\.\d) Hz\)", log)
    assert "rendering the layout the daemon runs (stage pick, decision 1" in log
    # J < 0: the words say so
    assert re.search(r"placement of pick NOT certified \(J -\d\.\d\d.*green_tea: 6 cm", daemon_log)


@pytest.fixture(scope="module")
def plan_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A plan of the tea graph made by ``legws plan`` (quickly: a few map-elites iterations;
    its layouts differ from the scene file's as any plan's do)."""
    out = tmp_path_factory.mktemp("plan") / "tea"
    proc = subprocess.run(
        [*LEGWS, "plan", "tea", "--method", "map-elites", "--iterations", "3", "--no-cache",
         "--out", str(out), "--quiet"],
        env=env(), capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return out


def _warnings(m: Monitor, since: int = 0) -> list[dict[str, Any]]:
    """The placement warnings among the events from ``since`` on."""
    return [e["detail"] for e in m.events[since:] if "corrections" in e["detail"]]


def _clear_move(scene: Scene, layout: Layout, name: str) -> tuple[float, float, str]:
    """A 6 cm shift of ``name`` along x or y that leaves it farthest from every other object
    (on the table, in the camera's view): ``dx``, ``dy`` and the correction's direction."""
    ws = scene.workspace
    (cx, cy), (sx, sy) = ws.table_center, ws.table_size
    p = layout[name]
    best: tuple[float, tuple[float, float, str]] | None = None
    for dx, dy, words in [
        (0.06, 0.0, "towards the robot"),
        (-0.06, 0.0, "away from the robot"),
        (0.0, 0.06, "right"),
        (0.0, -0.06, "left"),
    ]:
        x, y = p.x + dx, p.y + dy
        if abs(x - cx) > sx / 2 - 0.05 or abs(y - cy) > sy / 2 - 0.05:
            continue
        clear = min(math.hypot(x - o.x, y - o.y) for n, o in layout.items() if n != name)
        if best is None or clear > best[0]:
            best = (clear, (dx, dy, words))
    assert best is not None
    return best[1]


def _objects_placed(m: Monitor, but: tuple[str, ...] = ()) -> bool:
    """Every object of the latest status's placement is placed (``but`` misplaced)."""
    p = _placement(m)
    if p is None or len(p["objects"]) != 8:
        return False
    want = {n: "misplaced" if n in but else "placed" for n in p["objects"]}
    return {n: o["state"] for n, o in p["objects"].items()} == want


def test_the_tracker_renders_the_plan_the_daemon_runs_and_any_object_off_it_is_warned(
    tmp_path: Path, plan_dir: Path
) -> None:
    scene = load_scene("tea")
    plan = load_plan(plan_dir / "plan.json", scene)
    planned = {**scene.poses(), **plan.layout_for("choose_tea")}
    shipped = scene.poses()
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon_log = tmp_path / "daemon.log"
    daemon = start(
        ["daemon", "--profile", str(profile), "--taskgraph", "tea", "--plan", str(plan_dir),
         "--duration", "240"],
        daemon_log,
    )  # fmt: skip
    tracker = None

    def track(name: str, *extra: str) -> subprocess.Popen[bytes]:
        return start(
            ["track", "--profile", str(profile), "--source", "sim:tea", "--duration", "120",
             *extra],
            tmp_path / f"{name}.log",
        )  # fmt: skip

    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), daemon_log.read_text()
            status = m.latest()
            assert status is not None
            # the daemon runs the plan: its status says where every object should stand
            assert status["layout"]["scene"] == "tea"
            for n, p in planned.items():
                got = status["layout"]["objects"][n]
                assert (got["x"], got["y"], got["yaw"]) == pytest.approx((p.x, p.y, p.yaw)), n
            # ... and it is not the scene file's: a tracker of the shipped layout would fail
            assert (
                max(
                    math.hypot(planned[n].x - shipped[n].x, planned[n].y - shipped[n].y)
                    for n in ("black_tea", "green_tea", "chamomile_tea")
                )
                > 0.1
            )
            planned_j = status["certificate"]
            assert planned_j > 0

            # 1. the tracker renders the plan: every object where it should stand, the placed
            #    layout certified as the plan says, and no warning
            tracker = track("track1")
            assert m.wait_for(_objects_placed, 60), (tmp_path / "track1.log").read_text()
            placement = _placement(m)
            assert placement is not None
            assert placement["certified"] is True and placement["misplaced"] == []
            assert placement["certificate"] == pytest.approx(planned_j, rel=0.05)
            assert placement["planned_certificate"] == pytest.approx(planned_j, abs=1e-3)
            time.sleep(3.0)
            assert _objects_placed(m)
            assert _warnings(m) == []
            code, _ = stop(tracker)
            tracker = None
            assert code == 0

            # 2. the tracker gone: the candidates turn unseen; J (of the poses last seen)
            #    stays positive, so the words are not "NOT certified"
            assert m.wait_for(lambda m: bool(_warnings(m)), 15), daemon_log.read_text()
            gone = _warnings(m)[0]
            assert gone["certificate"] > 0 and gone["certified"] is False
            assert gone["corrections"] == [] and "green_tea" in gone["unseen"]
            since = len(m.events)

            # 3. green tea 6 cm off its planned place, where J stays positive: it is
            #    warned about with its correction all the same
            dx, dy, words = _clear_move(scene, planned, "green_tea")
            tracker = track("track2", "--move", f"green_tea={dx:g},{dy:g}")
            expected = f"green_tea: 6 cm {words}"

            def moved(m: Monitor) -> bool:
                return any(w["corrections"] for w in _warnings(m, since))

            assert m.wait_for(moved, 60), (tmp_path / "track2.log").read_text()
            warning = next(w for w in _warnings(m, since) if w["corrections"])
            assert warning["corrections"] == [expected]
            assert warning["certificate"] > 0 and warning["certified"] is True
            assert warning["unseen"] == []
            assert m.wait_for(lambda m: _objects_placed(m, but=("green_tea",)), 5)
            placement = _placement(m)
            assert placement is not None
            assert placement["certified"] is True and placement["misplaced"] == ["green_tea"]
            move = placement["objects"]["green_tea"]["move"]
            assert (move["x"], move["y"]) == pytest.approx((-dx, -dy), abs=0.005)

            # 4. the plan dropped (load_taskgraph with plan none): the daemon runs the scene
            #    file's layout now, and the tracker renders that one (green tea still moved)
            since = len(m.events)
            ok, reply = m.command("load_taskgraph", "tea", plan="none")
            assert ok, reply

            def reloaded(m: Monitor) -> bool:
                s = m.latest()
                return s is not None and s["decision"] > status["decision"]

            assert m.wait_for(reloaded, 10)
            assert m.wait_for(lambda m: _objects_placed(m, but=("green_tea",)), 30)
            latest = m.latest()
            assert latest is not None
            for n, p in shipped.items():
                got = latest["layout"]["objects"][n]
                assert (got["x"], got["y"], got["yaw"]) == pytest.approx((p.x, p.y, p.yaw)), n

            def warned_again(m: Monitor) -> bool:
                return any(w["corrections"] == [expected] for w in _warnings(m, since))

            assert m.wait_for(warned_again, 15), daemon_log.read_text()
            again = next(w for w in _warnings(m, since) if w["corrections"] == [expected])
            assert again["certified"] is (again["certificate"] > 0)
    finally:
        if tracker is not None:
            code, seconds = stop(tracker)
            assert code == 0 and seconds < 5.0
        code, _ = stop(daemon)
    assert code == 0
    text = daemon_log.read_text()
    assert "Traceback" not in text
    lines = [line for line in text.splitlines() if "warning placement of" in line]
    for line in lines:  # the verdict follows J's sign, every time
        j = float(re.search(r"\(J ([+-]\d+\.\d\d)", line)[1])  # type: ignore[index]
        assert ("NOT certified" in line) == (j <= 0), line
    assert any("unconfirmed, a candidate unseen (J +" in line for line in lines)
    assert any(
        "off the plan, certified all the same (J +" in line and expected in line for line in lines
    )
    log2 = (tmp_path / "track2.log").read_text()
    assert "Traceback" not in log2
    assert len(re.findall(r"rendering the layout the daemon runs", log2)) >= 2  # again on load
