"""The tea graph's plan as `legws plan tea` makes it (the default settings), planned once per
test session and shared by its pytest-xdist workers (~20 s of CPU each time it is planned):
the placement tests draw its mats, the demo's end-to-end test starts from it."""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from legws_daemon.design.plan_cache import plan_cache_dir
from legws_daemon.design.stage_plan import plan_taskgraph
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

#: the marker of a finished plan in the session's cache folder
_DONE = "planned"


def _session_folder(factory: pytest.TempPathFactory) -> Path:
    """A folder of this test session's: the workers' common parent under pytest-xdist."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextmanager
def _cache_home(cache: Path) -> Iterator[None]:
    before = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = str(cache)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("XDG_CACHE_HOME", None)
        else:
            os.environ["XDG_CACHE_HOME"] = before


def tea_plan_cache(factory: pytest.TempPathFactory) -> Path:
    """An ``XDG_CACHE_HOME`` whose plan cache holds the tea graph's default plan, made by the
    first worker that asks (the others wait on the lock and then read it). Read it only:
    :func:`seed_cache` copies it for a process that writes its own cache."""
    root = _session_folder(factory)
    cache = root / "tea-plan-cache"
    with (root / "tea-plan.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # (released when the file closes)
        if not (cache / _DONE).is_file():
            with _cache_home(cache):
                plan_taskgraph(*load_taskgraph(resolve_taskgraph("tea")))
            (cache / _DONE).touch()
    return cache


def tea_plan_folder(factory: pytest.TempPathFactory) -> Path:
    """The folder of the shared tea plan (``plan.json`` and its pictures, as ``legws plan tea
    --out`` writes them)."""
    with _cache_home(tea_plan_cache(factory)):
        (folder,) = plan_cache_dir().iterdir()
    return folder


def seed_cache(factory: pytest.TempPathFactory, cache: Path) -> Path:
    """``cache`` (an ``XDG_CACHE_HOME``) holding a copy of the shared tea plan."""
    shutil.copytree(tea_plan_cache(factory) / "legws", cache / "legws", dirs_exist_ok=True)
    return cache
