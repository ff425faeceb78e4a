"""Speed of the core: certificate over many layouts, observer update per tick, Monte Carlo.

Targets (issue "Foundation"): certificate of 10,000 layouts with M = 8 in <= 1 s; observer
update for M = 8 in <= 20 µs per tick. Reports medians over repeats (machines are shared
and noisy); never asserted in tests.

Usage:
    python benchmarks/speed.py [--repeats 7] [--out docs/results/speed.json]
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path
from typing import Any

import numpy as np
from timing import median_seconds

from legws_daemon.core.certificate import certify_batch
from legws_daemon.core.montecarlo import monte_carlo
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import Params
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--layouts", type=int, default=10_000)
    ap.add_argument("--out", type=Path, default=Path("docs/results/speed.json"))
    args = ap.parse_args()

    params = Params()
    out: dict[str, Any] = {
        "machine": {"python": platform.python_version(), "processor": platform.machine()},
        "numpy": np.__version__,
    }
    # Picks on the MuJoCo stand-in: the deployed controller, the simulated user, simulated
    # time (legws eval's loop), one process, meal_assembly's default layout. Measured first:
    # after the large BLAS calls below, OpenBLAS threads keep spinning for a while and slow
    # the many small solves of a tick by half.
    from legws_daemon.sim.protocol import Evaluator

    meal = load_scene("meal_assembly")
    ev = Evaluator(meal, params)
    ev.check(meal.default_layout())
    ev.controller.load(meal, meal.default_layout(), None)
    ep_rng = np.random.default_rng(2)
    durations: list[float] = []

    def picks() -> None:
        for name in meal.goal_names * 2:
            durations.append(ev.pick(name, ep_rng).duration)

    ep_t, _ = median_seconds(picks, max(3, args.repeats // 2))
    n_ep = len(meal.goal_names) * 2
    mean_ticks = float(np.mean(durations)) / params.dt
    out["episodes"] = {
        "scene": "meal_assembly",
        "loop": "the deployed controller, whole picks (commit, approach, grasp, lift, home)",
        "picks_per_second_one_process": n_ep / ep_t,
        "ms_per_pick": ep_t / n_ep * 1e3,
        "mean_ticks_per_pick": mean_ticks,
        "us_per_tick": ep_t / n_ep / mean_ticks * 1e6,
    }

    sc = load_scene("cluttered")  # M = 8
    names = sc.goal_names
    cons = LayoutConstraints.of(sc, names)
    poses = cons.sample(args.layouts, np.random.default_rng(0))

    pos, rot, sym = sc.grasp_batch(names, poses)
    cert_t, cert_all = median_seconds(
        lambda: certify_batch(sc.home.position, sc.home.rotation, pos, rot, sym, params),
        args.repeats,
    )
    full_t, _ = median_seconds(
        lambda: certify_batch(
            sc.home.position, sc.home.rotation, *sc.grasp_batch(names, poses), params
        ),
        args.repeats,
    )
    out["certificate"] = {
        "layouts": args.layouts,
        "m": len(names),
        "median_s": cert_t,
        "median_s_including_grasp_poses": full_t,
        "per_layout_us": cert_t / args.layouts * 1e6,
        "all_s": cert_all,
    }

    goals = sc.goal_set()
    obs = IntentObserver(goals, params)
    rng = np.random.default_rng(1)
    path = goals.x0.position + np.cumsum(rng.normal(scale=0.002, size=(20_000, 3)), axis=0)
    quat = goals.x0.quaternion

    def ticks() -> None:
        obs.reset()
        for p in path:
            obs.update(p, quat)

    tick_t, tick_all = median_seconds(ticks, args.repeats)
    out["observer"] = {
        "m": goals.m,
        "ticks": len(path),
        "median_us_per_tick": tick_t / len(path) * 1e6,
        "all_us_per_tick": [t / len(path) * 1e6 for t in tick_all],
    }

    mc_t, _ = median_seconds(lambda: monte_carlo(goals, params, 2000, 0), max(3, args.repeats // 2))
    out["monte_carlo"] = {"m": goals.m, "trials_per_goal": 2000, "median_s": mc_t}

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    c, o = out["certificate"], out["observer"]
    print(
        f"certificate: {c['layouts']} layouts, M = {c['m']}: median {c['median_s'] * 1e3:.0f} ms "
        f"({c['median_s_including_grasp_poses'] * 1e3:.0f} ms with grasp poses), "
        f"{c['per_layout_us']:.1f} µs per layout"
    )
    print(f"observer: M = {o['m']}: median {o['median_us_per_tick']:.1f} µs per tick")
    print(f"monte carlo: M = 8, 2000 trials per goal: median {mc_t * 1e3:.0f} ms")
    e = out["episodes"]
    print(
        f"picks (stand-in, meal_assembly): {e['picks_per_second_one_process']:.1f} per "
        f"second in one process, {e['ms_per_pick']:.0f} ms each, "
        f"{e['mean_ticks_per_pick']:.0f} ticks, {e['us_per_tick']:.0f} µs per tick"
    )
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
