"""The cache of stage-specific plans: ``$XDG_CACHE_HOME/legws/plan/<key>/``.

A folder holds ``plan.json`` and the pictures it names. It is written complete under a
temporary name in the cache folder, then renamed (:func:`publish`), so a reader sees a
whole plan or none; a corrupt or incomplete folder counts as missing and is replaced.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

from legws_daemon.design.plan import Plan
from legws_daemon.errors import InputError
from legws_daemon.formats.files import write_atomic
from legws_daemon.formats.plan_file import load_plan
from legws_daemon.scene.scene import Scene
from legws_daemon.sim.assets import sawyer_dir
from legws_daemon.sim.world import FINGER_GAP, TCP_OFFSET
from legws_daemon.task.graph import TaskGraph

PLAN_FILE = "plan.json"


def plan_cache_dir() -> Path:
    """Where plans are cached (``$XDG_CACHE_HOME``, default ``~/.cache``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "legws" / "plan"


def plan_key(graph: TaskGraph, scene: Scene, settings: dict[str, Any]) -> str:
    """Hash of the task-graph file, the scene file, the robot model and the settings."""
    h = hashlib.sha256()
    source = Path(graph.source)
    h.update(source.read_bytes() if source.is_file() else repr(graph).encode())
    h.update(b"\0" + Path(scene.source).read_bytes() + b"\0")
    h.update((sawyer_dir() / "robot.xml").read_bytes())
    extra = {"tcp": TCP_OFFSET, "gap": FINGER_GAP}
    h.update(json.dumps({**settings, **extra}, sort_keys=True).encode())
    return h.hexdigest()[:20]


def load_cached(folder: Path) -> Plan | None:
    """The plan cached in ``folder``, or ``None`` when missing, corrupt or incomplete."""
    path = folder / PLAN_FILE
    if not path.is_file():
        return None
    try:
        plan = load_plan(path)
    except InputError:
        return None  # corrupt: planned again and replaced
    if any(d.image and not (folder / d.image).is_file() for d in plan.decisions):
        return None
    return replace(plan, cached=True)


def publish(staging: Path, folder: Path) -> None:
    """Rename the finished ``staging`` folder to ``folder`` (replacing a stale one)."""
    if folder.exists():
        shutil.rmtree(folder, ignore_errors=True)
    try:
        os.rename(staging, folder)
    except OSError:  # another run published the same key first: same content
        shutil.rmtree(staging, ignore_errors=True)


def copy_out(plan: Plan, out_dir: Path) -> Plan:
    """Copy ``plan.json`` and the pictures of ``plan`` (from its folder) into ``out_dir``."""
    assert plan.directory is not None
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        what = "a file is in the way" if isinstance(err, FileExistsError) else err.strerror
        raise InputError(f"cannot create the folder: {what}", source=str(out_dir)) from None
    for name in [PLAN_FILE, *(d.image for d in plan.decisions if d.image)]:
        write_atomic(out_dir / name, (plan.directory / name).read_bytes())
    return replace(plan, directory=out_dir)
