"""Nothing lost (issue 7 §6): the plan and reachability caches.

Each cache is written atomically (a temporary file or folder, then a rename), so an
interrupted write — an exception, or the process killed — leaves the previous entry
intact. On load, every kind of damage (garbage, truncation, an empty file, valid JSON or
npz of another schema, another key, missing or broken pictures, a folder in the way) is
detected, logged as a warning, and the entry rebuilt: never used, never a traceback.
"""

from __future__ import annotations

import io
import json
import logging
import os
import shutil
import signal
import struct
import subprocess
import sys
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from legws_daemon.design import stage_plan
from legws_daemon.design.plan_cache import PLAN_FILE, load_cached, publish
from legws_daemon.design.search import SearchResult, search
from legws_daemon.design.stage_plan import plan_taskgraph
from legws_daemon.errors import InputError
from legws_daemon.robot import reachability
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.reachability import ReachabilityGrid, ReachabilityMap, build, load_or_build
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan, image_name
from legws_daemon.task.plan_file import dump_plan, load_plan
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

REPO = Path(__file__).parents[2]
#: A 3 x 3 cell patch in front of the robot, 4 yaws, one height: builds in ~0.2 s.
TINY = ReachabilityGrid(
    x_range=(0.6, 0.7),
    y_range=(-0.05, 0.05),
    step=0.05,
    yaw_bins=4,
    top_heights=(0.1,),
    side_heights=(0.1,),
)
ITERATIONS = 3


# --- reachability map ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def desk() -> tuple[World, np.ndarray]:
    sc = load_scene("desk")
    w = World(sc)
    return w, home_configuration(w, sc.home.position, sc.home.rotation).q


@pytest.fixture(scope="module")
def reference(desk: tuple[World, np.ndarray]) -> ReachabilityMap:
    return build(*desk, TINY)


def _npz(**arrays: Any) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def _good_arrays(ref: ReachabilityMap, meta: dict[str, Any]) -> dict[str, Any]:
    return {
        "meta": np.array(json.dumps(meta)),
        "top": ref.top,
        "side": ref.side,
        "side_flipped": ref.side_flipped,
    }


def _folder_instead(path: Path) -> None:
    path.unlink()
    path.mkdir()


def _meta(ref: ReachabilityMap, key: str, **changes: Any) -> dict[str, Any]:
    meta = {
        "format": reachability.FORMAT_VERSION,
        "key": key,
        "grid": TINY.to_json(),
        "table_height": ref.table_height,
        "build_seconds": 0.1,
    }
    return {**meta, **changes}


#: name -> writes a damaged cache entry at the path (given the reference map and the key).
MAP_DAMAGE: dict[str, Callable[[Path, ReachabilityMap, str], object]] = {
    "garbage": lambda p, ref, key: p.write_bytes(b"\x00\xffnot an npz" * 40),
    "empty": lambda p, ref, key: p.write_bytes(b""),
    "truncated": lambda p, ref, key: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]),
    "a .npy, not an .npz": lambda p, ref, key: np.save(p.open("wb"), ref.top),
    "meta not JSON": lambda p, ref, key: p.write_bytes(
        _npz(**{**_good_arrays(ref, {}), "meta": np.array("{not json")})
    ),
    "meta not an object": lambda p, ref, key: p.write_bytes(
        _npz(**{**_good_arrays(ref, {}), "meta": np.array("[1, 2]")})
    ),
    "another format": lambda p, ref, key: p.write_bytes(
        _npz(**_good_arrays(ref, _meta(ref, key, format=99)))
    ),
    "another key": lambda p, ref, key: p.write_bytes(
        _npz(**_good_arrays(ref, _meta(ref, "0" * 20)))
    ),
    "another grid": lambda p, ref, key: p.write_bytes(
        _npz(**_good_arrays(ref, _meta(ref, key, grid=json.dumps({"step": 1}))))
    ),
    "NaN table height": lambda p, ref, key: p.write_bytes(
        _npz(**_good_arrays(ref, _meta(ref, key, table_height=float("nan"))))
    ),
    "an array missing": lambda p, ref, key: p.write_bytes(
        _npz(meta=np.array(json.dumps(_meta(ref, key))), top=ref.top, side=ref.side)
    ),
    "floats, not booleans": lambda p, ref, key: p.write_bytes(
        _npz(**{**_good_arrays(ref, _meta(ref, key)), "top": ref.top.astype(np.float64)})
    ),
    "wrong shape": lambda p, ref, key: p.write_bytes(
        _npz(**{**_good_arrays(ref, _meta(ref, key)), "side": ref.side[:, :2]})
    ),
    "a folder in the way": lambda p, ref, key: _folder_instead(p),
}


@pytest.fixture
def counted_build(monkeypatch: pytest.MonkeyPatch, reference: ReachabilityMap) -> list[int]:
    """Counts builds; each build is the real one (on the tiny grid)."""
    calls: list[int] = []
    real = reachability.build

    def counted(*args: Any, **kwargs: Any) -> ReachabilityMap:
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(reachability, "build", counted)
    return calls


def _same_map(a: ReachabilityMap, b: ReachabilityMap) -> bool:
    return all(
        np.array_equal(getattr(a, k), getattr(b, k)) for k in ("top", "side", "side_flipped")
    )


@pytest.mark.parametrize("damage", list(MAP_DAMAGE))
def test_a_damaged_reachability_cache_is_detected_and_rebuilt(
    damage: str,
    desk: tuple[World, np.ndarray],
    reference: ReachabilityMap,
    counted_build: list[int],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    w, q_home = desk
    first = load_or_build(w, q_home, TINY, directory=tmp_path)
    assert len(counted_build) == 1
    path = tmp_path / f"{first.key}.npz"
    assert load_or_build(w, q_home, TINY, directory=tmp_path).key == first.key
    assert len(counted_build) == 1  # a good cache is used

    MAP_DAMAGE[damage](path, reference, first.key)
    with caplog.at_level(logging.WARNING, logger="legws.reachability"):
        rebuilt = load_or_build(w, q_home, TINY, directory=tmp_path)
    assert len(counted_build) == 2, "the damaged cache was used"
    assert _same_map(rebuilt, reference)
    assert rebuilt.key == first.key
    warnings = [r.getMessage() for r in caplog.records if r.name == "legws.reachability"]
    if damage == "a folder in the way":  # cannot be replaced: used, but not cached
        assert any("not cached" in m for m in warnings), warnings
        return
    assert any("replacing the reachability map" in m for m in warnings), warnings
    # the replacement is a valid cache entry again, and no temporary file is left
    assert _same_map(ReachabilityMap.load(path, TINY, first.key), reference)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_an_interrupted_map_write_leaves_the_old_file(
    reference: ReachabilityMap, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "map.npz"
    reference.save(path)
    before = path.read_bytes()
    other = replace(reference, top=~reference.top, build_seconds=9.0)

    def fail_rename(src: object, dst: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail_rename)
    with pytest.raises(InputError, match="No space left"):
        other.save(path)

    def interrupted(src: object, dst: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        other.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert _same_map(ReachabilityMap.load(path, TINY), reference)
    assert [p.name for p in tmp_path.iterdir()] == ["map.npz"]  # no temporary file left


_KILLED_WRITER = """
import os, sys, time
import numpy as np
from legws_daemon.formats import files
path = sys.argv[1]
real_replace = os.replace
def stuck(src, dst):  # the data is written, the rename has not happened: be killed here
    print("written", flush=True)
    time.sleep(60)
os.replace = stuck
files.write_atomic(__import__("pathlib").Path(path), os.urandom(4 << 20))
"""


def test_a_writer_killed_before_its_rename_leaves_the_old_file(
    reference: ReachabilityMap, tmp_path: Path
) -> None:
    path = tmp_path / "map.npz"
    reference.save(path)
    before = path.read_bytes()
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(path)], stdout=subprocess.PIPE, cwd=REPO
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == b"written"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    assert path.read_bytes() == before
    assert _same_map(ReachabilityMap.load(path, TINY), reference)
    leftovers = [p for p in tmp_path.iterdir() if p.name != "map.npz"]
    assert len(leftovers) == 1 and leftovers[0].name.startswith(".map.npz.")  # hidden temp


# --- stage plans -------------------------------------------------------------------------


def _png() -> bytes:
    """A valid 1 x 1 grey PNG."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(b"\x00\x80"))
        + chunk(b"IEND", b"")
    )


def _graph() -> tuple[TaskGraph, Scene]:
    return load_taskgraph(resolve_taskgraph("feeding"))


@pytest.fixture
def plan_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Plan, list[int]]:
    """A cached feeding plan, with a picture per decision; yields it and a search counter."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    calls: list[int] = []

    def counted(*args: Any, **kwargs: Any) -> SearchResult:
        calls.append(1)
        return search(*args, **kwargs)

    monkeypatch.setattr(stage_plan, "search", counted)
    plan = plan_taskgraph(*_graph(), iterations=ITERATIONS, render=False)
    folder = plan.directory
    assert folder is not None and calls
    # pictures, as a run with OpenGL would have drawn them (no GL needed here)
    decisions = tuple(replace(d, image=image_name(d.label)) for d in plan.decisions)
    for d in decisions:
        (folder / image_name(d.label)).write_bytes(_png())
    (folder / PLAN_FILE).write_bytes(dump_plan(replace(plan, decisions=decisions)))
    cached = load_cached(folder)
    assert cached is not None and cached.cached
    return cached, calls


def _replace_by_link(path: Path, target: str) -> None:
    path.unlink()
    path.symlink_to(target)


def _replace_by_fifo(path: Path) -> None:
    path.unlink()
    os.mkfifo(path)


def _other_plan_json(plan: Plan) -> bytes:
    return dump_plan(replace(plan, key="0123456789abcdef0123"))


#: name -> damages the cached plan folder.
PLAN_DAMAGE: dict[str, Callable[[Path, Plan], object]] = {
    "garbage bytes": lambda d, p: (d / PLAN_FILE).write_bytes(b"\xff\xfe\x00garbage"),
    "truncated JSON": lambda d, p: (d / PLAN_FILE).write_bytes(dump_plan(p)[:200]),
    "empty plan.json": lambda d, p: (d / PLAN_FILE).write_bytes(b""),
    "another schema": lambda d, p: (d / PLAN_FILE).write_text(
        json.dumps({**json.loads(dump_plan(p)), "schema": 2})
    ),
    "a JSON list": lambda d, p: (d / PLAN_FILE).write_text("[]"),
    "a field of the wrong type": lambda d, p: (d / PLAN_FILE).write_text(
        dump_plan(p).decode().replace('"feasible": true', '"feasible": "yes"', 1)
    ),
    "another key": lambda d, p: (d / PLAN_FILE).write_bytes(_other_plan_json(p)),
    "plan.json missing": lambda d, p: (d / PLAN_FILE).unlink(),
    "plan.json is a folder": lambda d, p: _folder_instead(d / PLAN_FILE),
    # issue 16: a plan.json linked to /dev/zero grew the daemon to 24 GB; a FIFO hung it
    "plan.json links to /dev/zero": lambda d, p: _replace_by_link(d / PLAN_FILE, "/dev/zero"),
    "plan.json is a FIFO": lambda d, p: _replace_by_fifo(d / PLAN_FILE),
    "a picture missing": lambda d, p: (d / image_name(p.decisions[0].label)).unlink(),
    "a picture truncated": lambda d, p: (d / image_name(p.decisions[-1].label)).write_bytes(
        _png()[:30]
    ),
    "a picture of garbage": lambda d, p: (d / image_name(p.decisions[1].label)).write_bytes(
        os.urandom(64)
    ),
}


@pytest.mark.parametrize("damage", list(PLAN_DAMAGE))
def test_a_damaged_plan_cache_is_detected_and_planned_again(
    damage: str,
    plan_cache: tuple[Plan, list[int]],
    caplog: pytest.LogCaptureFixture,
) -> None:
    cached, calls = plan_cache
    folder = cached.directory
    assert folder is not None
    searches = len(calls)
    again = plan_taskgraph(*_graph(), iterations=ITERATIONS, render=False)
    assert again.cached and len(calls) == searches  # the intact cache is used

    PLAN_DAMAGE[damage](folder, cached)
    with caplog.at_level(logging.WARNING, logger="legws.plan"):
        assert load_cached(folder) is None
        replanned = plan_taskgraph(*_graph(), iterations=ITERATIONS, render=False)
    assert len(calls) > searches, "the damaged cache was used"
    assert not replanned.cached
    warnings = [r.getMessage() for r in caplog.records if r.name == "legws.plan"]
    assert any("not usable" in m and str(folder) in m for m in warnings), warnings
    # the same plan, planned again (seeded), and a valid cache entry in the same place
    assert [d.layout for d in replanned.decisions] == [d.layout for d in cached.decisions]
    assert [d.certificate for d in replanned.decisions] == [d.certificate for d in cached.decisions]
    assert replanned.directory == folder
    assert load_plan(folder / PLAN_FILE) == replanned
    reloaded = load_cached(folder)
    assert reloaded is not None and reloaded.key == cached.key
    assert not [p for p in folder.parent.iterdir() if p.name.startswith(".")]  # no leftovers


def test_publish_replaces_a_stale_folder_by_renames_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "abc"
    folder.mkdir()
    (folder / PLAN_FILE).write_text("old")
    staging = tmp_path / ".abc.new"
    staging.mkdir()
    (staging / PLAN_FILE).write_text("new")
    removed: list[str] = []
    real_rmtree = shutil.rmtree

    def watched(path: Any, *args: Any, **kwargs: Any) -> None:
        # whatever is deleted is no longer under the published name
        assert Path(path) != folder
        removed.append(Path(path).name)
        real_rmtree(path, *args, **kwargs)

    monkeypatch.setattr(shutil, "rmtree", watched)
    publish(staging, folder)
    assert (folder / PLAN_FILE).read_text() == "new"
    assert removed and removed[0].startswith(".abc.stale.")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["abc"]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_an_interrupted_plan_write_leaves_the_cache_as_it_was(
    plan_cache: tuple[Plan, list[int]], monkeypatch: pytest.MonkeyPatch
) -> None:
    cached, _ = plan_cache
    folder = cached.directory
    assert folder is not None
    (folder / PLAN_FILE).write_text("{")  # damaged: the next run plans again and replaces it
    before = _snapshot(folder)
    real = os.replace

    def no_space(src: Any, dst: Any) -> None:
        if Path(dst).name == PLAN_FILE:
            raise OSError(28, "No space left on device")
        real(src, dst)

    def interrupted(src: Any, dst: Any) -> None:
        if Path(dst).name == PLAN_FILE:
            raise KeyboardInterrupt
        real(src, dst)

    # the write of the new plan.json fails, or the run is interrupted while writing it
    for failure, raised in ((no_space, InputError), (interrupted, KeyboardInterrupt)):
        monkeypatch.setattr(os, "replace", failure)
        with pytest.raises(raised):
            plan_taskgraph(*_graph(), iterations=ITERATIONS, render=False)
        monkeypatch.setattr(os, "replace", real)
        assert _snapshot(folder) == before  # nothing published
        assert not [p for p in folder.parent.iterdir() if p.name.startswith(".")]

    # the new folder is complete but its rename fails: the old entry is back in place
    real_rename = os.rename

    def rename_fails(src: Any, dst: Any) -> None:
        name = Path(src).name
        if Path(dst) == folder and name.startswith(f".{folder.name}.") and "stale" not in name:
            raise OSError(5, "Input/output error")  # the new folder, not the old one back
        real_rename(src, dst)

    monkeypatch.setattr(os, "rename", rename_fails)
    plan_taskgraph(*_graph(), iterations=ITERATIONS, render=False)
    monkeypatch.undo()
    assert _snapshot(folder) == before
    assert not [p for p in folder.parent.iterdir() if p.name.startswith(".")]


def test_readers_never_see_a_partial_folder_while_it_is_replaced(
    plan_cache: tuple[Plan, list[int]], caplog: pytest.LogCaptureFixture
) -> None:
    """Readers polling while the folder is replaced again and again see the old plan, none,
    or the new one — never a partial folder (which they would log as unusable)."""
    cached, _ = plan_cache
    folder = cached.directory
    assert folder is not None
    seen: list[bool] = []
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            seen.append(load_cached(folder) is not None)

    t = threading.Thread(target=reader)
    with caplog.at_level(logging.WARNING, logger="legws.plan"):
        t.start()
        try:
            end = time.monotonic() + 1.0
            k = 0
            while time.monotonic() < end:
                k += 1
                staging = folder.with_name(f".{folder.name}.{k}")
                staging.mkdir()
                for p in folder.iterdir():
                    (staging / p.name).write_bytes(p.read_bytes())
                publish(staging, folder)
        finally:
            stop.set()
            t.join(10)
    assert k > 5 and len(seen) > 5 and any(seen)
    assert not [r.getMessage() for r in caplog.records if r.name == "legws.plan"]
    assert load_cached(folder) is not None
