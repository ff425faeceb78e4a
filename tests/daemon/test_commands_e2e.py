"""Commands cannot stall control (the daemon in its own process, a zenoh client on loopback).

- A burst of concurrent ``load_scene`` queries: every query is answered — carried out, or
  ``busy`` with nothing done — and status keeps its rate while the loads are prepared off
  the loop.
- A ``stop`` cancels the loads queued before it: they answer with the reason, and the arm
  stays stopped (a load must not undo a stop).
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.daemon.procs import Monitor, monitor, ready, start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer_sim"
SCENES = ["breakfast_easy", "desk", "kitchen_prep", "breakfast"]
pytestmark = pytest.mark.slow


def ask_all(m: Monitor, bodies: list[dict[str, Any]]) -> list[tuple[bool, dict[str, Any]]]:
    """Send the queries at once, each from its own thread; the replies in order."""
    replies: list[tuple[bool, dict[str, Any]] | None] = [None] * len(bodies)

    def ask(i: int) -> None:
        for reply in m.session.get(
            m.keys["command"], payload=json.dumps(bodies[i]).encode(), timeout=90.0
        ):
            if reply.ok is not None:
                replies[i] = (True, json.loads(reply.ok.payload.to_bytes()))
            else:
                replies[i] = (False, json.loads(reply.err.payload.to_bytes()))
            break

    threads = [threading.Thread(target=ask, args=(i,)) for i in range(len(bodies))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert all(r is not None for r in replies), "a query got no reply"
    return [r for r in replies if r is not None]


def load(scene: str) -> dict[str, Any]:
    return {"schema": 1, "command": "load_scene", "argument": scene}


def test_a_burst_of_loads_is_answered_and_status_keeps_its_rate(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    trace = tmp_path / "trace.jsonl"
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120",
         "--trace", str(trace)],
        tmp_path / "daemon.log",
    )  # fmt: skip
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            t0 = time.monotonic()
            replies = ask_all(m, [load(SCENES[i % len(SCENES)]) for i in range(24)])
            t1 = time.monotonic()
            times = np.array([t for t, _ in m.status if t0 <= t <= t1])
            loaded = [r for ok, r in replies if ok]
            busy = [r for ok, r in replies if not ok]
            assert loaded and busy  # some carried out, the excess refused
            assert all(r["error"].startswith("busy") for r in busy), busy
            assert all(r["command"] == "load_scene" and r["scene"] in SCENES for r in loaded)
            # a reply and its event are two keys: the event may arrive after the reply
            assert m.wait_for(lambda m: m.kinds().count("loaded") == len(loaded), 5)
            assert m.kinds().count("loaded") == len(loaded)
            # the last load carried out is the scene in use
            last = max((e for e in m.events if e["kind"] == "loaded"), key=lambda e: e["seq"])[
                "detail"
            ]["scene"]
            ok, status = m.command("status")
            assert ok and set(status["targets"]) <= set(status["posterior"]) | {""}
            assert last in SCENES
    finally:
        code, _ = stop(daemon)
    assert code == 0
    # status never paused (10 Hz nominal): no gap of more than a few periods
    assert len(times) > 5 and float(np.max(np.diff(times))) < 0.5


def test_a_stop_cancels_the_loads_before_it_and_the_arm_stays_stopped(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120"],
        tmp_path / "daemon.log",
    )
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            bodies = [load(s) for s in ("breakfast", "kitchen_prep", "breakfast_easy")]
            result: list[list[tuple[bool, dict[str, Any]]]] = []
            loads = threading.Thread(target=lambda: result.append(ask_all(m, bodies)))
            loads.start()
            time.sleep(0.05)  # the loads are queued (and one is being prepared)
            ok, reply = m.command("stop")
            assert ok and reply["mode"] == "stopped"
            loads.join(120)
            replies = result[0]
            cancelled = [r for ok, r in replies if not ok and "stop" in r["error"]]
            assert cancelled, replies  # at least the ones still waiting
            time.sleep(1.0)
            s = m.latest()
            assert s is not None and s["mode"] == "stopped"
            # a load carried out before the stop arrived came before it: the stop is last
            kinds = [k for k in m.kinds() if k in ("loaded", "stop")]
            assert kinds[-1] == "stop", kinds
    finally:
        code, _ = stop(daemon)
    assert code == 0
