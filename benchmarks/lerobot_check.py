"""A study's LeRobotDataset export, read by LeRobot's own loader.

Run with the python of a separate virtual environment that has ``lerobot`` (not the
project's: LeRobot pulls in torch), on a folder ``legws study export`` wrote:

    python3 -m venv /tmp/lerobot-venv && /tmp/lerobot-venv/bin/pip install lerobot
    /tmp/lerobot-venv/bin/python benchmarks/lerobot_check.py DATASET [--frames 3]

It loads the dataset with ``lerobot.datasets.lerobot_dataset.LeRobotDataset(repo_id,
root=DATASET)`` (no download: the files are all there), prints the metadata LeRobot read
(version, fps, totals, features, tasks), the first frames of the first and last episodes
and the study's columns of each episode's metadata, and checks that every episode's frames
are where its range says. Exit code 0: read and consistent; 1: a mismatch (printed).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

STUDY = ("participant", "condition", "kind", "trial", "layout_source", "slack_j", "commit_k",
         "person_slack_j", "person_commit_k", "completed", "correct")  # fmt: skip


def _frame(item: dict[str, Any]) -> str:
    def text(v: Any) -> str:
        if hasattr(v, "tolist"):
            v = v.tolist()
        if isinstance(v, list):
            return "[" + ", ".join(f"{x:.4f}" for x in v) + "]"
        return f"{v:.4f}" if isinstance(v, float) else str(v)

    keys = ("index", "episode_index", "frame_index", "timestamp", "observation.state", "action",
            "task")  # fmt: skip
    return "  ".join(f"{k}={text(item[k])}" for k in keys)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--repo-id", default="legws/study")
    ap.add_argument("--frames", type=int, default=3, help="Frames printed per episode shown.")
    a = ap.parse_args()
    # nothing leaves the machine, the caches stay out of the home folder
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("HF_HOME", tempfile.mkdtemp(prefix="legws-lerobot-"))

    import lerobot
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset(a.repo_id, root=a.dataset)
    meta = ds.meta
    version = getattr(lerobot, "__version__", None)
    if version is None:
        from importlib.metadata import version as dist_version

        version = dist_version("lerobot")
    print(f"lerobot {version}: {a.dataset}")
    print(f"codebase_version {meta.info['codebase_version']}, fps {ds.fps}, robot "
          f"{meta.robot_type}; {ds.num_episodes} episodes, {ds.num_frames} frames, "
          f"{meta.total_tasks} tasks, {len(ds)} items")  # fmt: skip
    for name, ft in meta.features.items():
        print(f"  feature {name}: {ft['dtype']} {list(ft['shape'])} {ft['names']}")
    for task, row in meta.tasks.iterrows():
        print(f"  task {int(row['task_index'])}: {task}")
    stats = meta.stats or {}
    for name in ("observation.state", "action"):
        s = stats.get(name, {})
        print(f"  stats {name}: min {s.get('min')} max {s.get('max')}")
    problems = 0
    episodes = meta.episodes
    for e in (0, meta.total_episodes - 1):
        ep = episodes[e]
        study = ", ".join(f"{k}={ep[k]}" for k in STUDY if k in ep)
        print(f"episode {e}: frames [{ep['dataset_from_index']}, {ep['dataset_to_index']}), "
              f"tasks {ep['tasks']}; {study}")  # fmt: skip
        for i in range(ep["dataset_from_index"], ep["dataset_from_index"] + a.frames):
            print("  " + _frame(ds[i]))
    for e in range(meta.total_episodes):
        ep = episodes[e]
        first, last = ds[ep["dataset_from_index"]], ds[ep["dataset_to_index"] - 1]
        ok = (
            first["episode_index"].item() == e
            and last["episode_index"].item() == e
            and first["frame_index"].item() == 0
            and last["frame_index"].item() == ep["length"] - 1
            and first["task"] in ep["tasks"]
        )
        if not ok:
            problems += 1
            print(f"MISMATCH episode {e}: {_frame(first)} ... {_frame(last)}")
    print(f"{meta.total_episodes} episodes checked, {problems} mismatches")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
