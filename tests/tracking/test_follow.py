"""The stand-in's camera renders the layout the daemon runs (its status ``layout``), again
when it changes, with a layout file's objects and ``--move`` shifts over it; without the
daemon's layout it shows nothing, never the scene file's poses as a guess."""

from __future__ import annotations

import json
import math
import threading
from contextlib import closing
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import StatusMessage, dump
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Layout, ObjectPose
from legws_daemon.tracking.follow import DaemonLayout
from legws_daemon.tracking.stream import SimSource, parse_move
from legws_daemon.tracking.tracker import Tracker

SCENE = load_scene("tea")
KEY = "legws/sawyer_sim/status"
#: a layout unlike the scene file's (the tea bags 10 to 30 cm from their shipped poses)
PLANNED: Layout = {
    "black_tea": ObjectPose(0.78, 0.3, 0.4),
    "green_tea": ObjectPose(0.6, 0.2, -1.2),
    "chamomile_tea": ObjectPose(0.75, 0.05, 2.8),
}


def status(layout: Layout | None, scene: str = "tea", seq: int = 1, **extra: Any) -> bytes:
    data: dict[str, Any] = {
        "schema": 1, "robot": "sawyer_sim", "seq": seq, "stamp": 0.0, "mode": "teleop",
        "adapter": "sim", "stage": "choose_tea", "decision": 1, **extra,
    }  # fmt: skip
    if layout is not None:
        objects = {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in layout.items()}
        data["layout"] = {"scene": scene, "objects": objects}
    return dump(StatusMessage.model_validate(data))


def test_the_layout_is_the_daemons_and_changes_with_it() -> None:
    follow = DaemonLayout(SCENE, KEY)
    assert not follow.update() and follow.layout is None
    assert follow.problem is not None and KEY in follow.problem
    follow.offer(status(PLANNED))
    assert follow.update() and follow.version == 1
    assert follow.layout == {**SCENE.poses(), **PLANNED}  # the others as in the scene file
    assert (follow.stage, follow.decision) == ("choose_tea", 1)
    follow.offer(status(PLANNED, seq=2))
    assert not follow.update()  # the same layout: nothing to render again
    follow.offer(b'{"schema": 1, "robot": "sawyer_sim"}')  # does not validate: ignored
    assert not follow.update() and follow.layout is not None
    moved = {**PLANNED, "cookie": ObjectPose(0.5, -0.1, 0.0)}
    follow.offer(status(moved, seq=3, stage="choose_snack", decision=3))
    assert follow.update() and follow.version == 2
    assert follow.layout["cookie"] == ObjectPose(0.5, -0.1, 0.0)
    assert follow.stage == "choose_snack"


def test_a_daemon_of_another_scene_leaves_nothing_to_render() -> None:
    follow = DaemonLayout(SCENE, KEY)
    follow.offer(status(PLANNED))
    follow.update()
    follow.offer(status({"white_mug": ObjectPose(0.6, 0.2, 0.0)}, scene="desk", seq=2))
    assert follow.update() and follow.layout is None
    assert follow.problem is not None and "'desk'" in follow.problem
    follow.offer(status({"teapot": ObjectPose(0.6, 0.2, 0.0)}, seq=3))  # not a tea object
    assert follow.update() and follow.layout is None
    assert follow.problem is not None and "'teapot'" in follow.problem
    follow.offer(status(None, seq=4))  # a daemon that announces no layout
    assert follow.update() and follow.layout is None
    with pytest.raises(InputError, match="no layout"):
        follow.wait(0.1, ["tcp/127.0.0.1:1"])


def test_no_daemon_is_one_error_naming_where_it_looked() -> None:
    with pytest.raises(InputError) as err:
        DaemonLayout(SCENE, KEY).wait(0.1, ["tcp/127.0.0.1:1"])
    text = str(err.value)
    assert KEY in text and "tcp/127.0.0.1:1" in text and "--layout-from scene" in text


def test_a_long_wait_says_so_once_and_a_stop_ends_it() -> None:
    said: list[str] = []
    with pytest.raises(InputError, match=r"within 2\.3 s"):
        DaemonLayout(SCENE, KEY).wait(2.3, ["tcp/127.0.0.1:1"], note=said.append)
    assert len(said) == 1 and "waiting up to 2.3 s" in said[0] and KEY in said[0]
    stop = threading.Event()
    stop.set()
    assert DaemonLayout(SCENE, KEY).wait(60.0, [], stop) is None  # at once, nothing raised


def test_a_move_reads_metres_and_degrees() -> None:
    assert parse_move("green_tea=0,0.06", SCENE) == ("green_tea", (0.0, 0.06, 0.0))
    name, (dx, dy, dyaw) = parse_move("cup=-0.01,0.02,90", SCENE)
    assert (name, dx, dy) == ("cup", -0.01, 0.02) and dyaw == pytest.approx(math.pi / 2)
    for bad, words in [
        ("green_tea", "OBJ=DX,DY"),
        ("green_tea=0.06", "OBJ=DX,DY"),
        ("green_tea=a,b", "OBJ=DX,DY"),
        ("green_tea=nan,0", "finite"),
        ("green_tea=0,20", "at most"),
        ("teapot=0,0.06", "unknown object 'teapot'"),
    ]:
        with pytest.raises(InputError, match=words):
            parse_move(bad, SCENE)


def _near(measured: ObjectPose, truth: ObjectPose) -> bool:
    """Within the tracker's accuracy: 5 mm and 3°."""
    distance = math.hypot(measured.x - truth.x, measured.y - truth.y)
    turn = abs(math.remainder(measured.yaw - truth.yaw, 2 * math.pi))
    return distance < 0.005 and turn < math.radians(3)


def test_the_camera_shows_the_daemons_layout_with_the_file_and_the_moves(tmp_path: Path) -> None:
    follow = DaemonLayout(SCENE, KEY)
    placed = tmp_path / "placed.json"
    placed.write_text("{}")
    said: list[str] = []
    with closing(
        SimSource(
            SCENE, placed, 640, 480, warn=pytest.fail, follow=follow,
            moves={"green_tea": (0.0, 0.06, 0.0)}, say=said.append,
        )
    ) as source:  # fmt: skip
        assert source.read() is None  # no status yet: nothing to show, nothing guessed
        waiting = source.waiting()
        assert waiting is not None and "no status" in waiting
        follow.offer(status(PLANNED))
        image = source.read()
        assert image is not None and source.waiting() is None
        assert said == ["rendering the layout the daemon runs (stage choose_tea, decision 1)"]
        tracker = Tracker(SCENE, source.intrinsics)
        frame = tracker.process(image)
        truth = {**SCENE.poses(), **PLANNED}
        green = truth["green_tea"]
        truth["green_tea"] = ObjectPose(green.x, green.y + 0.06, green.yaw)  # the --move
        assert frame.unseen == ()
        for name, p in frame.poses.items():
            assert _near(p, truth[name]), name
        assert source.read() is image  # nothing changed: the same picture

        # the daemon's next decision moves the cookie: the camera shows it at once
        follow.offer(status({**PLANNED, "cookie": ObjectPose(0.5, -0.1, 0.5)}, seq=2))
        again = source.read()
        assert again is not None and again is not image
        cookie = tracker.process(again).poses["cookie"]
        assert _near(cookie, ObjectPose(0.5, -0.1, 0.5))

        # a layout file's object stands where the file says, the others as the daemon says
        placed.write_text(json.dumps({"black_tea": {"x": 0.55, "y": -0.3, "yaw": 0.0}}))
        image = source.read()
        assert image is not None
        poses = tracker.process(image).poses
        assert _near(poses["black_tea"], ObjectPose(0.55, -0.3, 0.0))
        assert _near(poses["chamomile_tea"], PLANNED["chamomile_tea"])
        assert _near(poses["cookie"], ObjectPose(0.5, -0.1, 0.5))

        # a daemon of another scene: nothing published, however good the last picture was
        follow.offer(status({"white_mug": ObjectPose(0.6, 0.2, 0.0)}, scene="desk", seq=3))
        assert source.read() is None
        waiting = source.waiting()
        assert waiting is not None and "'desk'" in waiting


def test_without_following_the_camera_shows_the_scene_file_and_the_moves() -> None:
    with closing(
        SimSource(SCENE, None, 320, 240, warn=pytest.fail, moves={"cup": (0.0, -0.05, 0.0)})
    ) as source:
        assert source.waiting() is None
        cup = SCENE.poses()["cup"]
        assert source.layout() == {**SCENE.poses(), "cup": ObjectPose(cup.x, cup.y - 0.05, cup.yaw)}
        assert source.read() is not None
