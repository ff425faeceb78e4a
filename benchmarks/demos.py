"""Task graphs: planning time and certificates, and what the plan does for the user.

1. ``legws plan`` of each shipped graph from an empty cache: wall time, J of every decision
   in the scene's layout and in the planned one.
2. Each graph run in-process (the controller and the simulated user of method.md §2, no
   wall clock) over several seeds, with the scene's default layout throughout and with the
   plan: per decision with inference, the inference time to the commit, how often the user
   had to press *confirm* (reached the goal with p < 0.9), and wrong commits.

Usage:
    python benchmarks/demos.py [--seeds 8] [--out docs/results/demos.json]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
GRAPHS = ("tea", "lego", "feeding")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "results" / "demos.json")
    a = ap.parse_args()
    os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(prefix="legws-bench-cache-")

    from legws_daemon.demo.inprocess import run_inprocess
    from legws_daemon.demo.run import summarise
    from legws_daemon.design.stage_plan import plan_taskgraph
    from legws_daemon.formats.profile import load_profile_named
    from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

    profile = load_profile_named("sim")
    results: dict[str, Any] = {"seeds": a.seeds, "graphs": {}}
    for name in GRAPHS:
        graph, scene = load_taskgraph(resolve_taskgraph(name))
        t0 = time.perf_counter()
        plan = plan_taskgraph(graph, scene, progress=False)
        seconds = time.perf_counter() - t0
        entry: dict[str, Any] = {
            "plan_seconds": seconds,
            "decisions": [
                {
                    "label": d.label,
                    "inference": d.inference,
                    "start": d.certificate_start,
                    "planned": d.certificate,
                }
                for d in plan.decisions
            ],
        }
        for condition, p in (("default", None), ("planned", plan)):
            times, confirms, wrong, total = [], 0, 0, 0
            for seed in range(a.seeds):
                c, events, user = run_inprocess(profile, graph, scene, seed, plan=p)
                if c.mode != "idle":
                    raise SystemExit(f"{name} seed {seed} ({condition}) did not finish")
                for d in summarise(events, user.chosen):
                    if d.single:
                        continue
                    total += 1
                    times.append(d.seconds)
                    confirms += d.confirmed
                    wrong += not d.correct
            entry[condition] = {
                "decisions": total,
                "t_infer_median": float(np.median(times)),
                "t_infer_mean": float(np.mean(times)),
                "confirm_rate": confirms / total,
                "wrong": wrong,
            }
        results["graphs"][name] = entry
        print(name, json.dumps(entry, indent=1), flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
