"""``legws track``: bad input is one line (exit 2); the loop never sends a stale pose."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose
from legws_daemon.tracking.calibration import DEFAULT_BOARD, Calibration, save_calibration
from legws_daemon.tracking.camera import Intrinsics
from legws_daemon.tracking.stream import (
    UNSEEN_AFTER,
    Absence,
    TrackStats,
    parse_sim_source,
    track,
)
from legws_daemon.tracking.tracker import Tracker, TrackFrame
from tests.cli.helpers import assert_bad_input, run_script
from tests.daemon.procs import write_profile
from tests.net import free_port


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["track"], ["--camera N or --source sim:"]),
        (["track", "--camera", "0", "--source", "sim:tea"], ["either"]),
        (["track", "--source", "real:tea"], ["sim:SCENE", "--source"]),
        (["track", "--source", "sim:no_such_scene"], ["no_such_scene"]),
        (["track", "--source", "sim:desk"], ["desk", "markers"]),  # a scene without markers
        (["track", "--source", "sim:tea:{tmp}/missing.json"], ["missing.json"]),
        (["track", "--source", "sim:tea", "--size", "640by480"], ["--size", "WIDTHxHEIGHT"]),
        (["track", "--camera", "0"], ["--scene and --calibration"]),
        (["track", "--camera", "0", "--scene", "tea", "--calibration", "{tmp}/bad.json"],
         ["bad.json"]),
        (["track", "--camera", "0", "--scene", "tea", "--calibration", "{tmp}/cal.json"],
         ["camera 0", "cannot open the camera"]),
        (["track", "--source", "sim:tea", "--rate", "0"], ["--rate"]),
        (["track", "--source", "sim:tea", "--move", "teapot=0,0.06"],
         ["--move", "unknown object 'teapot'"]),
        (["track", "--source", "sim:tea", "--move", "green_tea=0.06"], ["--move", "OBJ=DX,DY"]),
        (["track", "--source", "sim:tea", "--layout-from", "plan"], ["--layout-from"]),
        (["track", "--camera", "0", "--scene", "tea", "--calibration", "{tmp}/cal.json",
          "--move", "cup=0,0.1"], ["--move go with --source sim:"]),
    ],
)  # fmt: skip
def test_bad_input_is_one_line(tmp_path: Path, argv: list[str], needles: list[str]) -> None:
    intrinsics = Intrinsics.pinhole(50.0, 640, 480)
    save_calibration(
        Calibration(intrinsics, 0.2, 10, (0.2,) * 10, DEFAULT_BOARD, "2026-12-02T12:00:00+00:00"),
        tmp_path / "cal.json",
    )
    bad = json.loads((tmp_path / "cal.json").read_text())
    bad["width"] = 0  # one wrong field: one line (a file with several gets one each)
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    if Path("/dev/video0").exists() and "cal.json" in " ".join(args):
        pytest.skip("this machine has a camera 0")
    assert_bad_input(run_script(*args, cwd=tmp_path), *needles)


def test_a_sim_source_names_its_scene_and_layout() -> None:
    spec = parse_sim_source("sim:tea:out/placed.json")
    assert (spec.scene, spec.layout) == ("tea", Path("out/placed.json"))
    assert parse_sim_source("sim:tea").layout is None
    with pytest.raises(InputError, match="sim:SCENE"):
        parse_sim_source("sim:")


def _frame(seen: list[str], unseen: list[str]) -> TrackFrame:
    poses = {n: ObjectPose(0.5, 0.0, 0.0) for n in seen}
    return TrackFrame(poses, tuple(unseen), (), 4, None, None)


def test_an_object_is_unseen_only_after_several_frames_in_a_row() -> None:
    absence = Absence()
    for _ in range(UNSEEN_AFTER - 1):
        assert absence.update(_frame(["a"], ["b"])) == []
    assert absence.update(_frame(["a"], ["b"])) == ["b"]
    assert absence.update(_frame(["a", "b"], [])) == []  # seen again: at once


class _Flaky:
    """A camera that fails every other read (the edge the loop meets: OpenCV's read)."""

    name = "flaky"

    def __init__(self, image: np.ndarray, intrinsics: Intrinsics) -> None:
        self.image, self.intrinsics, self.reads = image, intrinsics, 0

    def read(self) -> np.ndarray | None:
        self.reads += 1
        return self.image if self.reads % 2 else None

    def waiting(self) -> str | None:
        return None

    def close(self) -> None:
        pass


def test_a_frame_that_cannot_be_read_publishes_nothing() -> None:
    scene = load_scene("tea")
    intrinsics = Intrinsics.pinhole(50.0, 320, 240)
    blank = np.full((240, 320, 3), 255, dtype=np.uint8)  # no marker at all
    sent: list[tuple[dict[str, ObjectPose], list[str]]] = []
    warnings: list[str] = []
    stats: TrackStats = track(
        _Flaky(blank, intrinsics), Tracker(scene, intrinsics),
        lambda frame, unseen, stamp: sent.append((frame.poses, unseen)),
        rate=60.0, stop=threading.Event(), duration=0.5, warn=warnings.append,
    )  # fmt: skip
    assert stats.frames >= 6
    assert stats.dropped == stats.frames // 2
    assert len(sent) == stats.frames - stats.dropped  # the failed reads sent nothing
    assert all(poses == {} for poses, _ in sent)  # no table marker: no pose at all
    assert any("could not be read" in w for w in warnings)
    assert any("table marker" in w for w in warnings)
    # after UNSEEN_AFTER frames every object with a marker is reported unseen
    assert set(sent[-1][1]) == {n for n, o in scene.objects.items() if o.marker is not None}


def test_without_a_daemon_the_sim_camera_is_one_line_naming_where_it_looked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MUJOCO_GL", "egl")
    port = free_port()  # nothing listens there
    profile = write_profile(tmp_path, "sim", port)
    result = run_script(
        "track", "--profile", profile, "--source", "sim:tea", "--wait-daemon", "0.5",
        cwd=tmp_path,
    )  # fmt: skip
    assert_bad_input(
        result, "no status from the daemon", "legws/sawyer_sim/status", f"127.0.0.1:{port}",
        "--layout-from scene",
    )  # fmt: skip


class _Waiting(_Flaky):
    """A source with nothing to show yet (the sim camera before the daemon's layout)."""

    def read(self) -> np.ndarray | None:
        return None

    def waiting(self) -> str | None:
        return "no status from the daemon yet"


def test_a_source_with_nothing_to_show_publishes_nothing_and_says_why() -> None:
    scene = load_scene("tea")
    intrinsics = Intrinsics.pinhole(50.0, 320, 240)
    blank = np.full((240, 320, 3), 255, dtype=np.uint8)
    sent: list[object] = []
    warnings: list[str] = []
    stats = track(
        _Waiting(blank, intrinsics), Tracker(scene, intrinsics),
        lambda frame, unseen, stamp: sent.append(frame),
        rate=60.0, stop=threading.Event(), duration=0.3, warn=warnings.append,
    )  # fmt: skip
    assert sent == [] and stats.published == 0
    assert stats.waited >= 5 and stats.frames == stats.dropped == 0  # not unreadable frames
    assert warnings and all(
        "no status from the daemon yet; nothing published" in w for w in warnings
    )
