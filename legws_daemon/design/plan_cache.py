"""The cache of stage-specific plans: ``$XDG_CACHE_HOME/legws/plan/<key>/``.

A folder holds ``plan.json`` and the pictures it names. It is written complete under a
temporary name in the cache folder, then renamed (:func:`publish`), so a reader sees a
whole plan or none: a stale folder is first renamed aside, never deleted in place.

A folder is used only when it validates (:func:`load_cached`): ``plan.json`` parses and
passes the schema, its ``key`` is the folder's name, every picture it names is a complete
PNG, and — given the task graph and the scene — every stage layout passes the checks of a
``--layout`` file and records the certificates it gives
(:func:`~legws_daemon.task.plan_file.check_plan`). Anything else — a truncated or garbage
file, another schema, missing pictures, a folder without ``plan.json``, objects too close
together or off the table, a certificate the layout does not give — is logged as a
warning naming the stage and the failed check, counts as missing, and is planned again
and replaced; it is never used, and never a traceback.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import secrets
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

from legws_daemon.arms import DEFAULT_ARM
from legws_daemon.arms import arm as arm_spec
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_folder, read_limited, write_atomic
from legws_daemon.robot.assets import arm_key
from legws_daemon.robot.gripper import FINGER_GAP, TCP_OFFSET
from legws_daemon.robot.planner import FEASIBILITY
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.plan_file import check_plan, load_plan

PLAN_FILE = "plan.json"
#: A PNG file starts with this signature and ends with an ``IEND`` chunk (and its CRC).
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"

log = logging.getLogger("legws.plan")
#: Reads of a folder that another run keeps replacing, before it counts as unusable.
READ_TRIES = 10


def plan_cache_dir() -> Path:
    """Where plans are cached (``$XDG_CACHE_HOME``, default ``~/.cache``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "legws" / "plan"


def plan_key(graph: TaskGraph, scene: Scene, settings: dict[str, Any]) -> str:
    """Hash of the task-graph file, the scene file, the arm's model and the settings."""
    h = hashlib.sha256()
    source = Path(graph.source)
    h.update(read_limited(source, "task graph") if source.is_file() else repr(graph).encode())
    h.update(b"\0" + read_limited(Path(scene.source), "scene") + b"\0")
    # every file of the arm's model, verified, and its whole description
    h.update(arm_key(arm_spec(settings.get("arm", DEFAULT_ARM))).encode())
    extra = {"tcp": TCP_OFFSET, "gap": FINGER_GAP, "feasibility": FEASIBILITY}
    h.update(json.dumps({**settings, **extra}, sort_keys=True).encode())
    return h.hexdigest()[:20]


def load_cached(
    folder: Path, graph: TaskGraph | None = None, scene: Scene | None = None
) -> Plan | None:
    """The plan cached in ``folder`` (named by its key), or ``None`` when there is none or
    it does not validate (logged as a warning: it is planned again and replaced).

    With ``graph`` and ``scene``, its stage layouts and certificates are checked too
    (:func:`~legws_daemon.task.plan_file.check_plan`).
    """
    plan, problem = read_cached(folder, graph, scene)
    if problem is not None:
        log.warning("legws: warning: the cached plan in %s is not usable (%s); planning "
                    "again", folder, problem)  # fmt: skip
    return plan


def read_cached(
    folder: Path, graph: TaskGraph | None = None, scene: Scene | None = None
) -> tuple[Plan | None, str | None]:
    """The plan cached in ``folder`` and ``None``; ``(None, None)`` when there is none;
    ``(None, what is wrong)`` when it does not validate (as :func:`load_cached`).

    A folder replaced by another run while it is read is read again (up to
    :data:`READ_TRIES` times: a run replacing it in a tight loop can hit a few reads in a row).
    """
    problem = None
    for _ in range(READ_TRIES):
        try:
            before = folder.stat()
        except OSError:
            return None, None  # no entry (or it is being replaced right now)
        plan, problem = _read(folder, graph, scene)
        if plan is not None:
            return plan, None
        try:
            replaced = _identity(folder.stat()) != _identity(before)
        except OSError:
            replaced = True
        if not replaced:
            break
    return None, problem


def _identity(st: os.stat_result) -> tuple[int, int, int]:
    """What tells a folder from the one that replaced it: the inode alone does not (a
    folder removed frees its inode, and the next one made may get it), its change time
    with it does (a rename or a new folder sets it)."""
    return st.st_dev, st.st_ino, st.st_ctime_ns


def _read(
    folder: Path, graph: TaskGraph | None, scene: Scene | None
) -> tuple[Plan | None, str | None]:
    """The validated plan of a cache folder, or what is wrong with it."""
    problem = None
    try:
        plan = load_plan(folder / PLAN_FILE)
        if plan.key != folder.name:
            problem = f"its key is {plan.key}, expected {folder.name}"
        for d in plan.decisions:
            if problem is None and d.image:
                problem = _png_problem(folder / d.image)
        if problem is None and graph is not None and scene is not None:
            check_plan(plan, graph, scene, str(folder / PLAN_FILE))
    except InputError as err:
        problem = str(err)
    except Exception as err:  # anything unreadable is a corrupt cache, never a traceback
        problem = f"{type(err).__name__}: {err}"
    if problem is not None:
        return None, problem
    return replace(plan, cached=True), None


def _png_problem(path: Path) -> str | None:
    """``None`` when ``path`` is a complete PNG file, else what is wrong."""
    try:
        with path.open("rb") as f:
            head = f.read(len(_PNG_SIGNATURE))
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - len(_PNG_END)))
            tail = f.read()
    except OSError as err:
        return f"{path.name}: {err.strerror or err}"
    if head != _PNG_SIGNATURE or tail != _PNG_END:
        return f"{path.name} is not a complete PNG file"
    return None


def publish(staging: Path, folder: Path) -> None:
    """Rename the finished ``staging`` folder to ``folder``, replacing a stale one.

    Each step is a rename, so a reader sees the old folder, no folder, or the new one —
    never a half-deleted or half-written one. When another run published the same key in
    between (same content), its folder stays and ``staging`` is removed.
    """
    aside = None
    if folder.exists():
        aside = folder.with_name(f".{folder.name}.stale.{secrets.token_hex(4)}")
        try:
            os.rename(folder, aside)
        except FileNotFoundError:  # another run moved it first
            aside = None
    try:
        os.rename(staging, folder)
    except OSError:  # another run published the same key first (same content), or failed
        shutil.rmtree(staging, ignore_errors=True)
        if aside is not None and not folder.exists():
            with contextlib.suppress(OSError):
                os.rename(aside, folder)  # nothing new: the old entry stays
                aside = None
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)


def copy_out(plan: Plan, out_dir: Path) -> Plan:
    """Copy ``plan.json`` and the pictures of ``plan`` (from its folder) into ``out_dir``."""
    assert plan.directory is not None
    output_folder(out_dir)
    for name in [PLAN_FILE, *(d.image for d in plan.decisions if d.image)]:
        kind = "plan" if name == PLAN_FILE else "picture"
        write_atomic(out_dir / name, read_limited(plan.directory / name, kind))
    return replace(plan, directory=out_dir)
