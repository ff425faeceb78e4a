"""The daemon and ``legws track --source sim:…`` over zenoh loopback: a displaced object is
named with its correction until it is put back, then the placed layout is certified again;
an object out of view is reported unseen."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import pytest

from tests.daemon.procs import Monitor, monitor, ready, start, stop, write_profile
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
            assert warning["detail"]["unseen"] == []
            assert m.wait_for(lambda m: _placement(m) is not None, 2)  # the next status
            placement = _placement(m)
            assert placement is not None
            assert placement["certified"] is False
            assert placement["objects"]["green_tea"]["state"] == "misplaced"
            assert placement["objects"]["green_tea"]["move"]["y"] == pytest.approx(-0.06, abs=0.005)
            assert placement["objects"]["black_tea"]["state"] == "placed"
            assert placement["objects"]["cup"]["state"] == "placed"  # fixed objects too
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
    assert "Traceback" not in log and "Traceback" not in (tmp_path / "daemon.log").read_text()
    assert re.search(r"tracked \d+ frames \((\d+\.\d) Hz\)", log)
