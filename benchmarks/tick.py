"""The control tick: its work time, and how often it reads the robot.

1. The stand-in: the controller (the daemon's and ``legws eval``'s) with the simulated user
   through whole picks of ``desk`` and ``meal_assembly`` in simulated time; wall-clock work
   per tick, p50 and p99, split by what the tick sent (teleoperation, a Cartesian move of
   assistance, a joint-space move of assistance), and ``read_state`` calls per tick.
2. The real arm's adapter (``sawyer``) through the fake bridge over loopback zenoh, in
   real time: per tick the bridge-state reads (``BridgeAdapter._fresh``) and the forward-
   kinematics evaluations of the adapter's model (``World.set_q``), in teleoperation and
   through the assistance of a pick (joint-space moves add the envelope's predictions of
   where a step ends; they read nothing).

Usage:
    python benchmarks/tick.py [--picks 40] [--out docs/results/tick.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.params import Params
from legws_daemon.formats.profile import TransportSpec, load_profile_named
from legws_daemon.hardware.base import RobotState
from legws_daemon.hardware.bridge import BridgeAdapter
from legws_daemon.hardware.fake_bridge import FakeBridge
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.joystick.sim_user import SimUser, UserView
from legws_daemon.robot import world as world_module
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.sim.protocol import SimClock, stand_in_profile
from legws_daemon.transport.session import config_from_spec, open_session


def percentiles(ms: list[float]) -> dict[str, float]:
    a = np.array(ms)
    return {"ticks": len(ms), "p50_ms": float(np.percentile(a, 50)),
            "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max())}  # fmt: skip


def stand_in(scene_name: str, picks: int, seed: int) -> dict[str, Any]:
    """Work per tick of the controller on the stand-in, whole picks, simulated time."""
    params = Params()
    profile = stand_in_profile(params)
    clock = SimClock(params.dt)
    reads = Counter[str]()

    class Counting(SimAdapter):
        def _read_state(self) -> RobotState:
            reads["read_state"] += 1
            return super()._read_state()

    def make(sc: Scene) -> SimAdapter:
        a = Counting(profile, sc, clock=clock)
        a.connect()
        return a

    scene = load_scene(scene_name)
    c = Controller(profile, scene, scene.default_layout(), make, params, lambda e: None,
                   clock=clock)  # fmt: skip
    a = c.adapter
    assert isinstance(a, SimAdapter)
    rng = np.random.default_rng(seed)
    work: dict[str, list[float]] = defaultdict(list)
    per_tick: Counter[int] = Counter()
    for i in range(picks):
        a.reset_arm()
        c.restart_task()
        goal = scene.goal_names[i % len(scene.goal_names)]
        user = SimUser([goal], params.sigma, params.v_max, rng)
        for _ in range(4000):
            if c.mode == Mode.IDLE:
                break
            targets = {t.name: t.position for t in c.stage.targets}
            view = UserView(c.mode.value, c.decisions, c.stage.name,
                            a.kinematics.ee_position(), targets)  # fmt: skip
            act = user.act(view, clock())
            inp = OperatorInput(act.axes, act.confirm, act.cancel, clock())
            before = reads["read_state"]
            t0 = time.perf_counter()
            rec = c.tick(inp)
            dt = (time.perf_counter() - t0) * 1e3
            clock.advance()
            per_tick[reads["read_state"] - before] += 1
            kind = (
                "teleop"
                if rec.mode == Mode.TELEOP
                else ("assist, joint-space" if rec.joints is not None else "assist, Cartesian")
            )
            work[kind].append(dt)
            work["all"].append(dt)
    return {
        "scene": scene_name,
        "picks": picks,
        "work": {k: percentiles(v) for k, v in work.items()},
        "read_state_calls_per_tick": {str(k): v for k, v in sorted(per_tick.items())},
    }


def sawyer(seconds: float) -> dict[str, Any]:
    """Reads per tick of the sawyer adapter through the fake bridge, in real time."""
    scene = load_scene("desk")
    profile = load_profile_named("sawyer")
    params = Params(v_max=profile.control.v_max, dt=1.0 / profile.control.rate_hz)
    counts: Counter[str] = Counter()
    models: list[world_module.World] = []
    real_set_q = world_module.World.set_q
    real_fresh = BridgeAdapter._fresh

    def set_q(self: world_module.World, q: Any) -> None:
        if any(self is m for m in models):
            counts["fk"] += 1
        real_set_q(self, q)

    def fresh(self: BridgeAdapter) -> Any:
        counts["bridge"] += 1
        return real_fresh(self)

    world_module.World.set_q = set_q  # type: ignore[method-assign]
    BridgeAdapter._fresh = fresh  # type: ignore[method-assign]
    port = _free_port()
    listen = TransportSpec(listen=[f"tcp/127.0.0.1:{port}"])
    dial = TransportSpec(listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    by_kind: dict[str, Counter[str]] = defaultdict(Counter)
    try:
        with (
            open_session(config_from_spec(listen)) as daemon,
            open_session(config_from_spec(dial)) as robot,
            FakeBridge(robot, "sawyer", scene, rate_hz=200.0),
        ):

            def make(sc: Scene) -> BridgeAdapter:
                adapter = BridgeAdapter(profile, sc, daemon)
                adapter.connect()
                models.append(adapter.kinematics)
                return adapter

            c = Controller(profile, scene, scene.default_layout(), make, params, lambda e: None)
            user = SimUser(["black_stapler"], params.sigma, params.v_max,
                           np.random.default_rng(0))  # fmt: skip
            end = time.monotonic() + seconds
            try:
                while time.monotonic() < end and c.mode != Mode.IDLE:
                    start = time.monotonic()
                    state = c.last_state or c.adapter.read_state()
                    targets = {t.name: t.position for t in c.stage.targets}
                    view = UserView(c.mode.value, c.decisions, c.stage.name,
                                    state.ee_position, targets)  # fmt: skip
                    act = user.act(view, start)
                    counts.clear()
                    rec = c.tick(OperatorInput(act.axes, act.confirm, act.cancel, start))
                    kind = (
                        "teleop"
                        if rec.mode == Mode.TELEOP
                        else (
                            "assist, joint-space" if rec.joints is not None else "assist, Cartesian"
                        )
                    )
                    by_kind[kind]["ticks"] += 1
                    by_kind[kind]["bridge"] += counts["bridge"]
                    by_kind[kind]["fk"] += counts["fk"]
                    time.sleep(max(0.0, c.dt - (time.monotonic() - start)))
                done = c.mode == Mode.IDLE
            finally:
                c.shutdown()
    finally:
        world_module.World.set_q = real_set_q  # type: ignore[method-assign]
        BridgeAdapter._fresh = real_fresh  # type: ignore[method-assign]
    return {
        "pick_completed": done,
        "per_tick": {
            k: {
                "ticks": v["ticks"],
                "bridge_reads": v["bridge"] / v["ticks"],
                "fk_evaluations": v["fk"] / v["ticks"],
            }
            for k, v in by_kind.items()
        },
    }


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--picks", type=int, default=40)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--out", type=Path, default=Path("docs/results/tick.json"))
    args = ap.parse_args()
    out: dict[str, Any] = {
        "machine": {"python": platform.python_version(), "processor": platform.machine()},
        "stand_in": [stand_in(name, args.picks, 0) for name in ("desk", "meal_assembly")],
        "sawyer_fake_bridge": sawyer(args.seconds),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    for s in out["stand_in"]:
        for kind, w in s["work"].items():
            print(f"{s['scene']} {kind}: {w['ticks']} ticks, p50 {w['p50_ms']:.3f} ms, "
                  f"p99 {w['p99_ms']:.3f} ms, max {w['max_ms']:.1f} ms")  # fmt: skip
        print(f"{s['scene']} read_state calls per tick: {s['read_state_calls_per_tick']}")
    for kind, r in out["sawyer_fake_bridge"]["per_tick"].items():
        print(f"sawyer {kind}: {r['ticks']} ticks, {r['bridge_reads']:.2f} bridge reads, "
              f"{r['fk_evaluations']:.2f} FK evaluations per tick")  # fmt: skip
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
