"""RerunLog writes a complete, verifiable recording with the documented entities."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

from legws_daemon.errors import InputError
from legws_daemon.telemetry.recording import entity_paths, read_ee_path, read_stages
from legws_daemon.telemetry.rerun_log import (
    PLOT_WINDOW,
    RerunLog,
    _fast,
    commit_text,
    parse_target,
    parse_targets,
)
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.telemetry.helpers import (
    Episode,
    arm_visual,
    log_episode,
    record,
    setup,
    straight_episode,
    tick_kwargs,
    verify,
)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def episode() -> Episode:
    return straight_episode("breakfast_easy", "banana")


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory, episode: Episode) -> Path:
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    record(path, episode)
    return path


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("save:/tmp/x.rrd", ("save", "/tmp/x.rrd")),
        ("save:rel/x:y.rrd", ("save", "rel/x:y.rrd")),
        ("spawn", ("spawn", None)),
        ("connect", ("connect", None)),
        (
            "connect:rerun+http://127.0.0.1:9876/proxy",
            ("connect", "rerun+http://127.0.0.1:9876/proxy"),
        ),
        ("web", ("web", None)),
        ("web:9190", ("web", "9190")),
        ("web:127.0.0.1:9190", ("web", "127.0.0.1:9190")),
    ],
)
def test_parse_target(text: str, expected: tuple[str, str | None]) -> None:
    assert parse_target(text) == expected


@pytest.mark.parametrize(
    "text",
    ["", "save", "save:", "spawn:x", "connect:", "file:x.rrd", "x", "web:", "web:0",
     "web:65535", "web:host.example:9090", "web:9090x"],
)  # fmt: skip
def test_parse_target_rejects(text: str) -> None:
    with pytest.raises(InputError, match="--rerun") as err:
        parse_target(text)
    assert "\n" not in str(err.value)
    assert "save:PATH" in str(err.value) or "web" in str(err.value)


def test_several_targets_each_kind_once(tmp_path: Path) -> None:
    save = f"save:{tmp_path / 'a.rrd'}"
    assert parse_targets([save, "web:9190"]) == [("save", str(tmp_path / "a.rrd")),
                                                 ("web", "9190")]  # fmt: skip
    with pytest.raises(InputError, match="save given 2 times"):
        parse_targets([save, f"save:{tmp_path / 'b.rrd'}"])
    with pytest.raises(InputError, match="--rerun"):
        parse_targets([])


def test_save_needs_an_existing_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        RerunLog(f"save:{tmp_path / 'missing' / 'x.rrd'}", robot="r")
    with pytest.raises(InputError, match="is a folder"):
        RerunLog(f"save:{tmp_path}", robot="r")


def test_recording_has_the_documented_entities(recording: Path, episode: Episode) -> None:
    paths = entity_paths(recording)
    scene, goals = episode.scene, episode.goals
    expected = {
        "world/table",
        "world/ee",
        "world/ee_trail",
        "world/robot/right_l0",
        "world/robot/right_l0/mesh",
        "world/robot/right_hand/fingers",
        "world/robot/right_hand/gripper_base",
        "world/joystick",
        "world/command",
        "world/committed",
        "plots/threshold",
        "plots/commits",
        "plots/slack",
        "plots/timing/tick_ms",
        "plots/timing/budget_ms",
        "status",
        "status/mode",
        "log",
        "meta/goals",
        "meta/params",
        "meta/robot",
    }
    expected |= {f"world/objects/{name}" for name in scene.objects}
    expected |= {f"world/planned/{name}" for name in scene.default_layout()}
    expected |= {f"world/grasps/{g}" for g in goals.names}
    expected |= {f"plots/posterior/{g}" for g in goals.names}
    assert expected <= paths, expected - paths


def test_recording_verifies(recording: Path) -> None:
    result = verify(recording)
    assert result.returncode == 0, result.stderr


def test_blueprint_is_in_the_file(recording: Path) -> None:
    assert len(RrdReader(recording).blueprints()) == 1
    assert [s.application_id for s in RrdReader(recording).recordings()] == ["legws"]


def _rows(path: Path, entity: str, component: str) -> list[tuple[int | None, Any]]:
    """``(tick or None if static, value)`` of one component of one entity, in logging order.

    Chunks are not stored in logging order (a static chunk may come first): row ids are.
    """
    rows = []
    for chunk in RrdReader(path).stream().filter(content=f"/{entity}").to_chunks():
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        ticks = batch.column("tick").to_pylist() if "tick" in batch.schema.names else None
        row_ids = batch.column("rerun.controls.RowId").to_pylist()
        for i, value in enumerate(batch.column(component).to_pylist()):
            rows.append((row_ids[i], None if ticks is None else ticks[i], value))
    return [(tick, value) for _, tick, value in sorted(rows, key=lambda r: r[0])]


def test_joystick_is_cleared_when_released(recording: Path, episode: Episode) -> None:
    clears = _rows(recording, "world/joystick", "Clear:is_recursive")
    last_moving = int(np.argmax(np.all(episode.positions == episode.positions[-1], axis=1))) - 1
    assert [tick for tick, _ in clears] == [last_moving + 1]


def test_objects_have_their_shape_colour_and_one_label(recording: Path, episode: Episode) -> None:
    colours = [c[0] for _, c in _rows(recording, "world/objects/banana", "Boxes3D:colors") if c]
    labels = [x[0] for _, x in _rows(recording, "world/objects/banana", "Boxes3D:labels") if x]
    r, g, b = (round(c * 255) for c in episode.scene.object("banana").color)
    assert set(colours) == {(r << 24) | (g << 16) | (b << 8) | 0xFF}  # its own colour
    assert labels[0] == "banana 0.50"  # two goals, uniform prior
    assert float(labels[-1].split()[-1]) >= 0.9
    # the bowl is a cylinder, and no candidate: no label (sent once)
    bowl = _rows(recording, "world/objects/bowl", "Cylinders3D:labels")
    assert [x for _, x in bowl] == [[]]
    assert not _rows(recording, "world/objects/bowl", "Boxes3D:labels")
    # the planned poses and grasps carry no labels
    for entity in ("world/planned/banana", "world/grasps/banana"):
        for kind in ("Boxes3D", "Arrows3D"):
            assert not _rows(recording, entity, f"{kind}:labels")


def test_the_committed_object_is_outlined(recording: Path) -> None:
    (commit,) = [t for t, x in _rows(recording, "log", "TextLog:text") if x[0].startswith("commit")]
    outline = _rows(recording, "world/committed", "Boxes3D:centers")
    assert outline[0][0] == commit
    points = _rows(recording, "plots/commits", "Scalars:scalars")
    assert [t for t, _ in points] == [commit]
    assert points[0][1][0] >= 0.9


def test_the_arm_is_drawn_with_its_meshes_from_the_first_tick(recording: Path) -> None:
    visual = arm_visual()
    assert visual.vertex_count > 100_000  # the Sawyer's own meshes, not primitives
    total = 0
    for mesh in visual.meshes:
        (row,) = _rows(recording, f"world/robot/{mesh.name}/mesh", "Mesh3D:vertex_positions")
        assert row[0] is None  # static
        total += len(row[1])
        assert len(row[1]) == len(mesh.vertices)
    assert total == visual.vertex_count
    for i in visual.drawn_links:
        ticks = [t for t, _ in _rows(recording, f"world/robot/{visual.links[i]}",
                                     "Transform3D:translation")]  # fmt: skip
        assert ticks[0] == 0, visual.links[i]


def test_the_fingers_follow_the_opening(tmp_path: Path, episode: Episode) -> None:
    path = tmp_path / "fingers.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        log.log_robot(arm_visual())
        setup(log, episode)
        for tick, gap in enumerate([0.042, 0.042, 0.0421, 0.02, 0.004]):
            log.log_tick(TickSnapshot(tick, tick * 0.05, **{**tick_kwargs(episode, 0, None),
                                               "gripper_half_gap": gap}))  # fmt: skip
    rows = _rows(path, "world/robot/right_hand/fingers", "Boxes3D:centers")
    assert [t for t, _ in rows] == [0, 3, 4]  # sent when the opening changed
    fingers = arm_visual().fingers
    assert fingers is not None
    for (_, centers), gap in zip(rows, [0.042, 0.02, 0.004], strict=True):
        y = [c[1] for c in centers]
        assert y == pytest.approx([gap + fingers.half_size[1], -gap - fingers.half_size[1]])


def test_without_inference_objects_show_their_names_only(tmp_path: Path, episode: Episode) -> None:
    path = tmp_path / "stopped.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, episode)
        kwargs = tick_kwargs(episode, 0, None)
        log.log_tick(TickSnapshot(0, 0.0, **{**kwargs, "mode": "stopped"}))
    labels = _rows(path, "world/objects/banana", "Boxes3D:labels")
    assert [x for _, x in labels] == [["banana"]]
    assert not _rows(path, "plots/posterior/banana", "Scalars:scalars")


def test_status_panel_and_timing(tmp_path: Path, episode: Episode) -> None:
    path = tmp_path / "status.rrd"
    with RerunLog(f"save:{path}", robot="r", tick_period=0.05) as log:
        setup(log, episode, stage="pick")
        base = tick_kwargs(episode, 0, None)
        log.log_tick(TickSnapshot(0, 0.0, **base))
        log.log_tick(TickSnapshot(1, 0.05, **{**base, "tick_seconds": 0.08}))  # an overrun
        log.log_tick(TickSnapshot(2, 0.10, **base))  # nothing changed: no new panel
        log.log_tick(TickSnapshot(3, 0.15, **{**base, "mode": "stopped", "fault": "bridge | lost"}))
    docs = _rows(path, "status", "TextDocument:text")
    assert [t for t, _ in docs] == [0, 3]
    assert "**mode** teleop · **phase** infer · **stage** pick" in docs[0][1][0]
    assert "**operator** sim\\_user" in docs[0][1][0]
    assert "**fault** none" in docs[0][1][0]
    assert "**fault** :warning: bridge \\| lost" in docs[1][1][0]
    assert [t for t, _ in _rows(path, "plots/timing/overruns", "Scalars:scalars")] == [1]
    assert _rows(path, "plots/timing/budget_ms", "Scalars:scalars")[0][1] == [50.0]
    with pytest.raises(InputError, match="tick_period"):
        RerunLog(f"save:{tmp_path / 'y.rrd'}", robot="r", tick_period=0.0)


def test_placement_guidance_is_in_the_panel_and_drawn_as_arrows(
    tmp_path: Path, episode: Episode
) -> None:
    path = tmp_path / "placement.rrd"
    lines = ("placement NOT certified: J -0.09", "banana: 6 cm right")
    at, to = np.array([0.6, 0.2, 0.02]), np.array([0.6, 0.14, 0.02])
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, episode, stage="pick")
        base = tick_kwargs(episode, 0, None)
        log.log_tick(TickSnapshot(0, 0.0, **base))  # no tracker yet
        log.log_tick(
            TickSnapshot(1, 0.05, **base, placement=lines, corrections={"banana": (at, to)})
        )
        log.log_tick(
            TickSnapshot(2, 0.10, **base, placement=lines, corrections={"banana": (at, to)})
        )
        log.log_tick(
            TickSnapshot(
                3, 0.15, **base, placement=("placement certified: J +0.05",), corrections={}
            )
        )
    docs = _rows(path, "status", "TextDocument:text")
    assert [t for t, _ in docs] == [0, 1, 3]  # re-sent only when the lines change
    assert "banana: 6 cm right" in docs[1][1][0]
    assert "placement certified" in docs[2][1][0]
    arrows = _rows(path, "world/placement", "Arrows3D:vectors")
    assert [t for t, _ in arrows] == [1]
    np.testing.assert_allclose(arrows[0][1][0], to - at, atol=1e-6)
    assert _rows(path, "world/placement", "Arrows3D:labels")[0][1] == ["banana"]
    assert 3 in [t for t, _ in _rows(path, "world/placement", "Clear:is_recursive")]


def test_fast_batches_match_the_archetypes() -> None:
    """The Arrow arrays built without the archetype converters are the archetypes' own."""
    fast = _fast()
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    q_xyzw = [0.1, 0.2, 0.3, 0.9]
    pts = np.arange(12.0).reshape(4, 3)
    cases = [
        (fast.fixed("Transform3D:mat3x3", R.T), rr.Transform3D(mat3x3=R)),
        (fast.fixed("Transform3D:translation", [1, 2, 3]), rr.Transform3D(translation=[1, 2, 3])),
        (
            fast.fixed("Transform3D:quaternion", q_xyzw),
            rr.Transform3D(quaternion=rr.Quaternion(xyzw=q_xyzw)),
        ),
        (fast.strips("LineStrips3D:strips", pts), rr.LineStrips3D([pts])),
        (fast.plain("Scalars:scalars", [0.25]), rr.Scalars(0.25)),
        (
            fast.constant("Boxes3D:fill_mode", 3),
            rr.Boxes3D(half_sizes=[1, 1, 1], fill_mode="solid"),
        ),
        (
            fast.plain("Boxes3D:colors", [0x11223344]),
            rr.Boxes3D(half_sizes=[1, 1, 1], colors=[0x11223344]),
        ),
    ]
    for batch, archetype in cases:
        name = str(batch.component_descriptor())
        (want,) = [
            b for b in archetype.as_component_batches() if str(b.component_descriptor()) == name
        ]
        assert batch.as_arrow_array().equals(want.as_arrow_array()), name


def test_log_tick_never_raises(tmp_path: Path, episode: Episode) -> None:
    path = tmp_path / "bad.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, episode)
        good = tick_kwargs(episode, 0, None)
        log.log_tick(TickSnapshot(0, 0.0, **good))
        log.log_tick(TickSnapshot(1, 0.05, **{**good, "ee_position": np.zeros(2)}))
        log.log_tick(TickSnapshot(2, 0.10, **{**good, "link_positions": "not an array"}))
        log.log_tick(TickSnapshot(3, 0.15, **{**good, "objects": {"bowl": (np.zeros(3), None)}}))
        log.log_tick(TickSnapshot(4, 0.20, **good))
        assert log.dropped == 3
        log.log_text(5, 0.25, "INFO", None)  # type: ignore[arg-type]
    assert verify(path).returncode == 0
    # a tick that fails part-way keeps what was logged before the failure (tick 3's EE)
    assert read_ee_path(path).ticks.tolist() == [0, 3, 4]


def test_close_is_idempotent_and_later_calls_are_ignored(tmp_path: Path, episode: Episode) -> None:
    path = tmp_path / "closed.rrd"
    log = RerunLog(f"save:{path}", robot="r")
    setup(log, episode)
    log.log_tick(TickSnapshot(0, 0.0, **tick_kwargs(episode, 0, None)))
    log.close()
    log.close()
    log.log_tick(TickSnapshot(1, 0.05, **tick_kwargs(episode, 1, None)))
    log.log_text(1, 0.05, "INFO", "ignored")
    log.flush()
    assert log.closed and log.dropped == 0
    assert verify(path).returncode == 0
    assert read_ee_path(path).ticks.tolist() == [0]


@pytest.mark.parametrize(
    ("setting", "value"),
    [("trail_length", 1), ("trail_every", 0), ("command_scale", 0.0), ("link_frames_every", -1)],
)
def test_settings_are_checked(tmp_path: Path, setting: str, value: float) -> None:
    settings: dict[str, Any] = {setting: value}
    with pytest.raises(InputError, match=setting):
        RerunLog(f"save:{tmp_path / 'x.rrd'}", robot="r", **settings)


@pytest.mark.parametrize(
    ("every", "sent"), [(0, [0]), (1, [0, 1, 2, 3]), (2, [0, 2, 4]), (3, [0, 3])]
)
def test_link_frames_every(tmp_path: Path, episode: Episode, every: int, sent: list[int]) -> None:
    """Link poses every ``every`` ticks (0: the first only), and only when they moved (the
    arm stops at tick 3); the base never moves, so it is sent once."""
    path = tmp_path / "links.rrd"
    with RerunLog(f"save:{path}", robot="r", link_frames_every=every) as log:
        log.log_robot(arm_visual())
        setup(log, episode)
        for tick in range(6):
            kwargs = tick_kwargs(episode, min(tick, 3), None)
            log.log_tick(TickSnapshot(tick, tick * 0.05, **kwargs))
    assert [t for t, _ in _rows(path, "world/robot/right_l6", "Transform3D:translation")] == sent
    base = _rows(path, "world/robot/right_arm_base_link", "Transform3D:translation")
    assert [t for t, _ in base] == [0]
    assert "world/robot/links" not in entity_paths(path)  # meshes, not the stick figure


def test_without_meshes_the_arm_is_a_line(tmp_path: Path, episode: Episode) -> None:
    path = tmp_path / "line.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, episode)
        for tick in range(3):
            log.log_tick(TickSnapshot(tick, tick * 0.05, **tick_kwargs(episode, tick, None)))
    assert [t for t, _ in _rows(path, "world/robot/links", "LineStrips3D:strips")] == [0, 1, 2]


def test_setup_rejects_unknown_names(tmp_path: Path, episode: Episode) -> None:
    with RerunLog(f"save:{tmp_path / 'x.rrd'}", robot="r") as log:
        base: dict[str, Any] = {
            "scene": episode.scene,
            "goals": episode.goals,
            "goal_objects": {"banana": "banana"},
            "planned": {},
            "p_thresh": 0.9,
            "params_json": "{}",
        }
        with pytest.raises(InputError, match="unknown goal 'nope'"):
            log.log_setup(**{**base, "goal_objects": {"nope": "banana"}})
        with pytest.raises(InputError, match="unknown object 'nope'"):
            log.log_setup(**{**base, "goal_objects": {"banana": "nope"}})
        with pytest.raises(InputError, match="p_thresh"):
            log.log_setup(**{**base, "p_thresh": 1.0})
        with pytest.raises(InputError, match="params_json"):
            log.log_setup(**{**base, "params_json": '{"betta": 1}'})


def test_a_new_stage_replaces_the_static_data(tmp_path: Path) -> None:
    first = straight_episode("breakfast_easy", "banana", hold=0)
    second = straight_episode("desk", "white_mug", hold=0)
    path = tmp_path / "stages.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        log_episode(log, first, stage="easy")
        tick0 = len(first.positions)
        log_episode(log, second, tick0=tick0, stage="desk")
    assert verify(path).returncode == 0
    assert [(s.index, s.name, s.scene) for s in read_stages(path)] == [
        (0, "easy", "breakfast_easy"),
        (1, "desk", "desk"),
    ]
    # a planned box and a grasp of the first scene only: last static value is empty
    assert _rows(path, "world/planned/banana", "Boxes3D:half_sizes")[-1] == (None, [])
    assert _rows(path, "world/grasps/banana", "Arrows3D:vectors")[-1] == (None, [])
    assert _rows(path, "world/planned/white_mug", "Boxes3D:half_sizes")[-1][1] != []
    # an object of the first scene only is cleared at the first tick of the second stage
    assert [t for t, _ in _rows(path, "world/objects/banana", "Clear:is_recursive")] == [tick0]
    assert not _rows(path, "world/objects/white_mug", "Clear:is_recursive")


_CHILD = textwrap.dedent(
    """
    import signal, sys, time
    from legws_daemon.telemetry.rerun_log import RerunLog
    from legws_daemon.telemetry.snapshot import TickSnapshot
    from tests.telemetry.helpers import setup, straight_episode, tick_kwargs

    ep = straight_episode()
    log = RerunLog("save:" + sys.argv[1], robot="r")

    def stop(signum, frame):
        log.close()
        sys.exit(0)

    signal.signal(signal.SIGTERM, stop)
    setup(log, ep)
    tick = 0
    while True:
        kwargs = tick_kwargs(ep, tick % len(ep.positions), None)
        log.log_tick(TickSnapshot(tick, tick * 0.05, **kwargs))
        tick += 1
        if tick == 30:
            print("ready", flush=True)
        time.sleep(0.002)
    """
)


def test_a_recording_closed_by_a_sigterm_handler_verifies(tmp_path: Path) -> None:
    path = tmp_path / "killed.rrd"
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(path)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=os.environ.copy(),
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready", proc.stderr and proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    result = verify(path)
    assert result.returncode == 0, result.stderr
    ticks = read_ee_path(path).ticks
    assert len(ticks) >= 30
    assert ticks.tolist() == list(range(len(ticks)))


def test_a_curve_ends_when_inference_stops(tmp_path: Path, episode: Episode) -> None:
    """No line is drawn across a stretch without inference (no posterior, or an empty one:
    a stage of one candidate): a NaN ends each curve."""
    path = tmp_path / "gap.rrd"
    post = {"cereal_box": 0.4, "banana": 0.6}
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, episode)
        for tick, p in enumerate([post, {**post, "banana": 0.7}, {}, None, post]):
            log.log_tick(TickSnapshot(tick, tick * 0.05, **{**tick_kwargs(episode, 0, p),
                                               "slack": 0.2 if tick != 1 else None}))  # fmt: skip
    rows = _rows(path, "plots/posterior/banana", "Scalars:scalars")
    assert [t for t, _ in rows] == [0, 1, 2, 4]
    assert np.isnan(rows[2][1][0]) and rows[3][1] == [0.6]
    slack = _rows(path, "plots/slack", "Scalars:scalars")
    # a tick without a slack value does not end its line; the end of inference does
    assert [t for t, v in slack if np.isnan(v[0])] == [2]


def _curve(path: Path, goal: str) -> list[tuple[int, float]]:
    return [(t, v[0]) for t, v in _rows(path, f"plots/posterior/{goal}", "Scalars:scalars") if v]


def test_a_curve_ends_where_its_goal_is_no_candidate(tmp_path: Path) -> None:
    """Two decisions on the breakfast table with another on the desk between them (its
    posterior logged from its first tick, as the daemon does): the banana's curve ends at
    the desk's set-up and has no value until the banana is a candidate again."""
    table = straight_episode("breakfast_easy", "banana", hold=0)
    desk = straight_episode("desk", "white_mug", hold=0)
    path = tmp_path / "stages.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        log_episode(log, table, stage="first")
        log_episode(log, desk, tick0=len(table.positions), stage="desk")
        log_episode(log, table, tick0=len(table.positions) + len(desk.positions), stage="again")
    a, b = len(table.positions), len(table.positions) + len(desk.positions)
    banana = _curve(path, "banana")
    ends = [t for t, v in banana if np.isnan(v)]
    assert ends == [a - 1]  # at the desk's set-up, after the banana's last value
    assert not [t for t, v in banana if a <= t < b and np.isfinite(v)]
    assert [t for t, v in banana if np.isfinite(v)] == [*range(a), *range(b, b + a)]
    mug = _curve(path, "white_mug")  # the desk's goal ends at the next set-up
    assert [t for t, v in mug if np.isnan(v)] == [b - 1]


def test_a_goal_dropped_from_the_posterior_ends_its_curve(tmp_path: Path, episode: Episode) -> None:
    path = tmp_path / "dropped.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, episode)
        for tick, p in enumerate([{"cereal_box": 0.4, "banana": 0.6}, {"cereal_box": 1.0}]):
            log.log_tick(TickSnapshot(tick, tick * 0.05, **tick_kwargs(episode, 0, p)))
    assert _curve(path, "banana")[0] == (0, 0.6)
    assert np.isnan(_curve(path, "banana")[1][1]) and _curve(path, "banana")[1][0] == 1
    assert _curve(path, "cereal_box") == [(0, 0.4), (1, 1.0)]


def test_a_single_candidate_stage_is_set_up_by_its_name(tmp_path: Path) -> None:
    """The stage of a decision without inference: its own document (no goal set), its
    lines and EE samples carry its index, the previous stage's grasps are cleared, and
    only its candidate is labelled."""
    ep = straight_episode("breakfast_easy", "banana", hold=0)
    path = tmp_path / "single.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        log_episode(log, ep, stage="choose")
        tick = len(ep.positions)
        log.log_setup(
            scene=ep.scene,
            goals=["bowl"],
            goal_objects={"bowl": "bowl"},
            planned=ep.scene.default_layout(),
            p_thresh=0.9,
            params_json=json.dumps(ep.params.as_dict()),
            stage="into",
        )
        log.log_text(tick, tick * 0.05, "INFO", commit_text("bowl", 1.0, how="single"))
        log.log_tick(TickSnapshot(tick, tick * 0.05, **tick_kwargs(ep, 0, None)))
    docs = [json.loads(x[0]) for _, x in _rows(path, "meta/stages", "TextDocument:text")]
    assert [(d["stage"], d["inference"], d["candidates"]) for d in docs] == [
        ("choose", True, list(ep.goals.names)),
        ("into", False, ["bowl"]),
    ]
    assert "goals" not in docs[1] and docs[1]["params"] == ep.params.as_dict()
    assert [(s.index, s.name, s.goals is None) for s in read_stages(path)] == [
        (0, "choose", False),
        (1, "into", True),
    ]
    assert read_ee_path(path, 1).ticks.tolist() == [tick]
    assert _rows(path, "log", "legws.Stage:stage")[-1] == (tick, [1])  # the commit's line
    assert _rows(path, "world/grasps/banana", "Arrows3D:vectors")[-1] == (None, [])
    bowl = _rows(path, "world/objects/bowl", "Cylinders3D:labels")
    banana = _rows(path, "world/objects/banana", "Boxes3D:labels")
    assert bowl[-1] == (tick, ["bowl"]) and banana[-1] == (tick, [])
    assert not _rows(path, "plots/posterior/bowl", "Scalars:scalars")


def test_the_plots_show_the_time_up_to_the_cursor_with_the_legend_after_it(
    recording: Path,
) -> None:
    """The blueprint in the file: each plot queries the last seconds up to the cursor and
    shows room after it, where its legend stands (at 800x500 a legend over the curves hid
    them)."""
    reader = RrdReader(recording)
    props: dict[str, dict[str, Any]] = {}
    names: dict[str, str] = {}
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch, entity = chunk.to_record_batch(), str(chunk.entity_path)
        for column in batch.schema.names:
            value = batch.column(column).to_pylist()[-1]
            if column == "ViewBlueprint:display_name":
                names[entity] = value[0]
            elif column.split(":")[0] in ("PlotLegend", "VisibleTimeRanges", "TimeAxis"):
                props.setdefault(entity.rsplit("/", 1)[0], {})[column] = value
    plots = {names[view]: found for view, found in props.items()}
    before, after = (round(s * 1e9) for s in PLOT_WINDOW)
    right_top = rrb.components.Corner2D.RightTop.value
    window = {
        "PlotLegend:corner": [right_top],
        "TimeAxis:view_range": [{"start": -before, "end": after}],
        "VisibleTimeRanges:ranges": [{"timeline": "time", "range": {"start": -before, "end": 0}}],
    }
    assert plots == {"posterior": window, "slack": window, "timing (ms)": window}


def test_a_calibration_target_is_drawn_labelled_and_cleared_and_the_panel_says_whose(
    tmp_path: Path, episode: Episode
) -> None:
    """``legws operator calibrate``'s marker and panel line, and the operator model's lines
    of ``legws daemon --operator`` in the status panel."""
    path = tmp_path / "calibration.rrd"
    target = (0.61, -0.12, 0.25)
    who = ("operator model alice: s 0.90, sigma 0.033 m/s, rho 0.86, bias -6.0°, free",
           "watch: operator alice: rho 0.93 seen, certified for ≤ 0.86")  # fmt: skip
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, episode, stage="calibration")
        base = {**tick_kwargs(episode, 0, None), "mode": "calibrate"}
        log.log_tick(TickSnapshot(0, 0.0, **base))  # no target yet
        log.log_tick(TickSnapshot(1, 0.05, **base, calibration=(target, "target 3 of 20")))
        log.log_tick(TickSnapshot(2, 0.10, **base, calibration=(target, "target 3 of 20")))
        log.log_tick(TickSnapshot(3, 0.15, **base))  # reached: none until the next appears
        log.log_tick(TickSnapshot(4, 0.20, **base, operator_model=who))
    points = _rows(path, "world/calibration/target", "Points3D:positions")
    assert [t for t, _ in points] == [1]  # sent once, when it appears
    np.testing.assert_allclose(points[0][1][0], target, atol=1e-6)
    assert _rows(path, "world/calibration/target", "Points3D:labels")[0][1] == ["target 3 of 20"]
    assert 3 in [t for t, _ in _rows(path, "world/calibration/target", "Clear:is_recursive")]
    docs = _rows(path, "status", "TextDocument:text")
    assert [t for t, _ in docs] == [0, 1, 3, 4]
    distance = 100 * np.linalg.norm(np.array(target) - episode.positions[0])
    assert f"calibration: target 3 of 20, {distance:.0f} cm to go" in docs[1][1][0]
    assert "rho 0.93 seen, certified for ≤ 0.86" in docs[3][1][0]
    assert "**mode** calibrate" in docs[0][1][0]
