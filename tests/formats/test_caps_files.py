"""Caps of the files: the number of goals of a goal set (and of a scene), positions and
object sizes within a Sawyer cell, and endpoints with a port in 1..65535. Each refusal is
one ``InputError`` line naming the file and the field."""

from __future__ import annotations

import copy
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.core.goals import MAX_GOALS
from legws_daemon.errors import InputError
from legws_daemon.formats.goalset import goalset_from_data, load_goalset
from legws_daemon.formats.profile import endpoint_problem, load_profile
from legws_daemon.formats.scene_file import (
    CELL_XY,
    CELL_Z,
    MAX_EXTENT,
    MAX_OBJECTS,
    MIN_EXTENT,
    load_scene_spec,
)
from legws_daemon.scene.catalog import load_scene, scene_names
from legws_daemon.scene.grasps import extents

WriteScene = Callable[..., Path]
REPO = Path(__file__).parents[2]

GOALSET: dict[str, Any] = {
    "x0": {"position": [0.55, 0.0, 0.30], "quaternion": [0, 1, 0, 0]},
    "goals": [
        {"name": "mug", "position": [0.62, 0.21, 0.07], "quaternion": [0, 1, 0, 0]},
        {"name": "stapler", "position": [0.70, -0.18, 0.04], "quaternion": [0, 1, 0, 0]},
    ],
}


def goals_doc(m: int) -> dict[str, Any]:
    doc = copy.deepcopy(GOALSET)
    doc["goals"] = [
        {
            "name": f"g{i}",
            "position": [0.3 + 0.005 * (i % 100), -0.4 + 0.008 * (i // 100 % 100), 0.02],
            "quaternion": [0, 1, 0, 0],
        }
        for i in range(m)
    ]
    return doc


def one_line(info: pytest.ExceptionInfo[InputError], *needles: str) -> str:
    text = str(info.value)
    assert "\n" not in text
    for needle in needles:
        assert needle in text, f"{needle!r} not in {text!r}"
    return text


# --- goal sets -----------------------------------------------------------------------------


@pytest.mark.parametrize("m", [MAX_GOALS + 1, 2_000, 20_000])
def test_goal_sets_beyond_the_cap_are_refused_at_once(m: int) -> None:
    doc = goals_doc(m)
    start = time.perf_counter()
    with pytest.raises(InputError) as info:
        goalset_from_data(doc, "many.json")
    assert time.perf_counter() - start < 0.5  # before validating any goal
    one_line(info, "many.json: goals:", f"at most {MAX_GOALS} goals, got {m}")


def test_a_goal_set_at_the_cap_loads(tmp_path: Path) -> None:
    path = tmp_path / "goals.json"
    path.write_text(json.dumps(goals_doc(MAX_GOALS)))
    goals, _ = load_goalset(path)
    assert goals.m == MAX_GOALS


@pytest.mark.parametrize(
    ("where", "value", "field"),
    [
        (("goals", 1, "position"), [100.0, 0.0, 0.04], "goals[1].position[0]"),
        (("goals", 0, "position"), [0.6, -3.5, 0.04], "goals[0].position[1]"),
        (("goals", 0, "position"), [0.6, 0.0, -1.5], "goals[0].position[2]"),
        (("goals", 0, "position"), [0.6, 0.0, 3.01], "goals[0].position[2]"),
        (("x0", "position"), [0.55, 0.0, 50.0], "x0.position[2]"),
    ],
)
def test_goal_set_positions_outside_the_cell_are_refused(
    where: tuple[str | int, ...], value: list[float], field: str
) -> None:
    doc = copy.deepcopy(GOALSET)
    target: Any = doc
    for key in where[:-1]:
        target = target[key]
    target[where[-1]] = value
    with pytest.raises(InputError) as info:
        goalset_from_data(doc, "g.json")
    one_line(info, "g.json", field)


# --- scenes --------------------------------------------------------------------------------


@pytest.mark.parametrize("name", scene_names())
def test_shipped_scenes_are_within_the_bounds(name: str) -> None:
    scene = load_scene(name)
    for o in scene.objects.values():
        assert all(MIN_EXTENT <= e <= MAX_EXTENT for e in extents(o.shape, tuple(o.size)))
        assert abs(o.x) <= CELL_XY and abs(o.y) <= CELL_XY
    assert len(scene.goal_names) <= MAX_GOALS


def _obj(i: int, **changes: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: d["objects"][i].update(changes)


def _ws(**changes: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: d["workspace"].update(changes)


def _many(n: int, movable: bool = True) -> Callable[[dict[str, Any]], None]:
    def mutate(d: dict[str, Any]) -> None:
        base = d["objects"][2]
        d["objects"] = [
            {**base, "name": f"o{i}", "movable": movable or i < 2, "x": 0.3 + 0.01 * (i % 50)}
            for i in range(n)
        ]

    return mutate


BAD_SCENES = [
    pytest.param(_obj(1, size=[100.0, 0.04, 0.05]), ["objects[1].size[0]", "100"], id="100m-box"),
    pytest.param(_obj(1, size=[0.6, 0.04, 0.05]), ["objects[1].size[0]", "0.5 m"], id="0.6m-box"),
    pytest.param(_obj(1, size=[0.16, 0.0005, 0.05]), ["objects[1].size[1]"], id="0.5mm-box"),
    pytest.param(_obj(0, size=[0.3, 0.095]), ["objects[0].size[0]", "diameter"], id="wide-cyl"),
    pytest.param(_obj(0, size=[0.04, 0.6]), ["objects[0].size[1]", "height"], id="tall-cyl"),
    pytest.param(
        _obj(0, shape="sphere", size=[0.0004]), ["objects[0].size[0]", "diameter"], id="tiny-ball"
    ),
    pytest.param(_obj(1, x=100.0), ["objects[1].x"], id="x-100m"),
    pytest.param(_obj(1, y=-3.5), ["objects[1].y"], id="y-beyond-cell"),
    pytest.param(_ws(table_height=-2.0), ["workspace.table_height"], id="table-below-floor"),
    pytest.param(_ws(table_size=[0.75, 100.0]), ["workspace.table_size[1]"], id="table-100m"),
    pytest.param(
        _ws(table_center=[2.8, 0.0], x_range=[2.5, 3.0]),
        ["workspace.table_size", "within"],
        id="table-out-of-cell",
    ),
    pytest.param(_ws(min_clearance=50.0), ["workspace.min_clearance"], id="clearance-50m"),
    pytest.param(
        lambda d: d["workspace"]["ee_home"].update(position=[0.55, 0.0, 10.0]),
        ["workspace.ee_home.position[2]"],
        id="home-10m-up",
    ),
    pytest.param(
        lambda d: d.update(
            places=[{"name": "mouth", "position": [40.0, 0.0, 0.4], "quaternion": [1, 0, 0, 0]}]
        ),
        ["places[0].position[0]"],
        id="place-40m-away",
    ),
    pytest.param(_many(MAX_GOALS + 1), ["objects", f"at most {MAX_GOALS} candidate goals"]),
    pytest.param(_many(MAX_OBJECTS + 1, movable=False), ["objects", f"at most {MAX_OBJECTS}"]),
]


@pytest.mark.parametrize(("mutation", "needles"), BAD_SCENES)
def test_scene_values_outside_the_cell_are_refused(
    desk_data: dict[str, Any],
    write_scene: WriteScene,
    mutation: Callable[[dict[str, Any]], None],
    needles: list[str],
) -> None:
    mutation(desk_data)
    path = write_scene(desk_data)
    with pytest.raises(InputError) as info:
        load_scene_spec(path)
    one_line(info, str(path), *needles)


def test_the_bounds_themselves_are_accepted(
    desk_data: dict[str, Any], write_scene: WriteScene
) -> None:
    desk_data["objects"][1].update(size=[MAX_EXTENT, MIN_EXTENT, 0.05])
    desk_data["objects"][4].update(x=CELL_XY, y=-CELL_XY)  # fixed clutter, off the table
    desk_data["places"] = [
        {"name": "shelf", "position": [0.0, CELL_XY, CELL_Z[1]], "quaternion": [1, 0, 0, 0]}
    ]
    load_scene_spec(write_scene(desk_data))


# --- endpoints -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("endpoint", "why"),
    [
        ("tcp/127.0.0.1:99999", "port 99999 is not in 1..65535"),
        ("tls/robot.local:65536", "port 65536 is not in 1..65535"),
        ("tcp/127.0.0.1:1234567", "port 1234567 is not in 1..65535"),
        ("tcp/127.0.0.1:0", "port 0 is not in 1..65535"),
        ("tcp/127.0.0.1:7447\n", "expected PROTOCOL/HOST:PORT"),  # "$" matched before a "\n"
        ("tcp/127.0.0.1:\u0667\u0664\u0664\u0667", "expected PROTOCOL/HOST:PORT"),  # not ASCII
        ("tcp/:7447", "expected PROTOCOL/HOST:PORT"),
        ("tcp/ robot:7447", "expected PROTOCOL/HOST:PORT"),
        ("tcp/ro\x00bot:7447", "is not a host name"),
        ("tcp/ro\x7fbot:7447", "is not a host name"),
        ("tls/" + "a" * 300 + ":7447", "is not a host name"),
    ],
)
def test_bad_endpoints_are_one_line(tmp_path: Path, endpoint: str, why: str) -> None:
    problem = endpoint_problem(endpoint)
    assert problem is not None and why in problem
    assert "\n" not in problem and len(problem) < 400
    text = (REPO / "hw_profiles" / "sim.toml").read_text(encoding="utf-8")
    path = tmp_path / "p.toml"
    path.write_text(
        text.replace('listen = ["tcp/127.0.0.1:7447"]', f"listen = [{json.dumps(endpoint)}]"),
        encoding="utf-8",
    )
    with pytest.raises(InputError) as info:
        load_profile(path)
    # (a control character is refused by the TOML reader first, with its own reason)
    one_line(info, str(path), "transport.listen[0]")


@pytest.mark.parametrize("port", [1, 7447, 65535])
def test_every_port_in_range_is_accepted(port: int) -> None:
    assert endpoint_problem(f"tcp/127.0.0.1:{port}") is None
    assert endpoint_problem(f"tls/[::1]:{port}") is None
