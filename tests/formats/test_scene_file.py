"""Scene files: every shipped scene loads; each malformed file is one ``InputError`` line
naming the file and the field."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.scene_file import load_scene_spec
from legws_daemon.scene.catalog import load_scene, scene_names, scenes_dir
from legws_daemon.scene.constraints import LayoutConstraints
from tests.expected import ALL_SCENES
from tests.formats.helpers import toml_dumps

WriteScene = Callable[..., Path]
Mutation = Callable[[dict[str, Any]], None]

SHIPPED = ALL_SCENES


def test_catalog_lists_the_shipped_scenes() -> None:
    assert scene_names() == SHIPPED


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scene_loads(name: str) -> None:
    scene = load_scene(name)
    assert scene.name == name
    assert Path(scene.source) == scenes_dir() / f"{name}.toml"
    assert len(scene.goal_names) >= 2
    assert set(scene.goal_names) <= set(scene.movable)
    assert set(scene.movable) | set(scene.fixed) == set(scene.objects)
    # the shipped default layout meets the scene's own constraints
    assert LayoutConstraints.of(scene).problems(scene.poses()) == []
    # loading by path gives the same scene
    assert load_scene(scenes_dir() / f"{name}.toml").spec == scene.spec


def test_toml_writer_is_faithful(desk_data: dict[str, Any], write_scene: WriteScene) -> None:
    """Guard for the tests below: the unmodified copy reads back equal and loads."""
    assert tomllib.loads(toml_dumps(desk_data)) == desk_data
    scene = load_scene(write_scene(desk_data))
    assert scene.spec == load_scene("desk").spec


def _obj(i: int, **changes: Any) -> Mutation:
    return lambda d: d["objects"][i].update(changes)


def _top(**changes: Any) -> Mutation:
    return lambda d: d.update(changes)


def _ws(**changes: Any) -> Mutation:
    return lambda d: d["workspace"].update(changes)


def _fix_all_but_one(d: dict[str, Any]) -> None:
    for o in d["objects"][1:]:
        o["movable"] = False


def _markers(*objects: tuple[int, dict[str, Any]], **table: Any) -> Mutation:
    """A ``[markers]`` table with one table marker (``table`` changes it), and markers on
    the objects ``(index, marker)``."""

    def mutate(d: dict[str, Any]) -> None:
        d["markers"] = {"table": [{"id": 0, "size": 0.05, "x": 0.3, "y": 0.45, **table}]}
        for i, marker in objects:
            d["objects"][i]["marker"] = marker

    return mutate


BAD_SCENES = [
    pytest.param(
        lambda d: d["objects"][1].update(marker={"id": 3, "size": 0.03}),
        ["objects[1].marker", "[markers]"],
        id="marker-without-markers-table",
    ),
    pytest.param(
        _markers((1, {"id": 0, "size": 0.03})),
        ["objects[1].marker.id", "twice"],
        id="marker-id-twice",
    ),
    pytest.param(
        _markers((1, {"id": 50, "size": 0.03})),
        ["objects[1].marker.id", "0..49"],
        id="marker-id-out",
    ),
    pytest.param(
        _markers((1, {"id": 5, "size": 0.05})),
        ["objects[1].marker.size", "does not fit"],
        id="marker-too-big",
    ),
    pytest.param(
        _markers(x=0.0),
        ["markers.table[0]", "not on the table"],
        id="table-marker-off-table",
    ),
    pytest.param(
        lambda d: d.update(markers={"table": []}), ["markers.table"], id="no-table-marker"
    ),
    pytest.param(
        lambda d: d.update(markers={"dictionary": "3X3_9", "table": []}),
        ["markers.dictionary"],
        id="unknown-dictionary",
    ),
    pytest.param(
        _markers((1, {"id": 5, "size": 0.001})), ["objects[1].marker.size"], id="marker-too-small"
    ),
    pytest.param(_top(schema_version=2), ["schema_version"], id="schema-version-2"),
    pytest.param(_top(schema_version="1"), ["schema_version"], id="schema-version-string"),
    pytest.param(lambda d: d.pop("schema_version"), ["schema_version"], id="no-schema-version"),
    pytest.param(_top(colour="red"), ["colour"], id="unknown-top-level-key"),
    pytest.param(_ws(table_colour="oak"), ["workspace.table_colour"], id="unknown-workspace-key"),
    pytest.param(_obj(1, weight=0.3), ["objects[1].weight"], id="unknown-object-key"),
    pytest.param(_obj(1, size=[0.16, 0.04]), ["objects[1]", "size", "box"], id="box-size-2"),
    pytest.param(_obj(1, size=[0.16]), ["objects[1]", "size", "box"], id="box-size-1"),
    pytest.param(
        _obj(0, size=[0.04, 0.095, 0.1]), ["objects[0]", "size", "cylinder"], id="cylinder-size-3"
    ),
    pytest.param(
        _obj(0, shape="sphere", size=[0.04, 0.04]),
        ["objects[0]", "size", "sphere"],
        id="sphere-size-2",
    ),
    pytest.param(_obj(1, size=[0.16, -0.04, 0.05]), ["objects[1].size[1]"], id="negative-size"),
    pytest.param(_obj(1, size=[0.16, 0.04, 0.0]), ["objects[1].size[2]"], id="zero-size"),
    pytest.param(_obj(1, size=[0.16, "0.04", 0.05]), ["objects[1].size[1]"], id="string-size"),
    pytest.param(_obj(1, shape="cone"), ["objects[1].shape", "cone"], id="unknown-shape"),
    pytest.param(_obj(1, grasp="pinch"), ["objects[1].grasp", "pinch"], id="unknown-grasp"),
    pytest.param(_obj(1, color=[0.1, 1.5, 0.1]), ["objects[1].color[1]"], id="color-above-1"),
    pytest.param(_obj(1, color=[-0.1, 0.1, 0.1]), ["objects[1].color[0]"], id="color-negative"),
    pytest.param(_obj(1, color=[0.1, 0.1]), ["objects[1].color"], id="color-2-components"),
    pytest.param(_obj(1, name="white_mug"), ["white_mug", "twice"], id="duplicate-names"),
    pytest.param(_obj(1, name="Black Stapler"), ["objects[1].name"], id="name-pattern"),
    pytest.param(_obj(1, symmetry=-2), ["objects[1].symmetry"], id="negative-symmetry"),
    pytest.param(_obj(1, x="0.72"), ["objects[1].x"], id="x-string"),
    pytest.param(_obj(1, x=float("nan")), ["objects[1].x", "finite"], id="x-nan"),
    pytest.param(_obj(1, yaw=float("inf")), ["objects[1].yaw", "finite"], id="yaw-inf"),
    pytest.param(lambda d: d["objects"][1].pop("x"), ["objects[1].x"], id="x-missing"),
    pytest.param(
        _top(goals=["white_mug", "tape_dispenser"]),
        ["goal", "tape_dispenser", "movable"],
        id="goal-is-fixed",
    ),
    pytest.param(_top(goals=["white_mug", "printer"]), ["goal", "printer"], id="goal-unknown"),
    pytest.param(_top(goals=["white_mug"]), ["goals", "at least 2"], id="one-goal"),
    pytest.param(_top(goals=[]), ["goals", "at least 2"], id="no-goals"),
    pytest.param(_top(goals=["white_mug", "white_mug"]), ["goals[1]", "twice"], id="goal-repeated"),
    pytest.param(_fix_all_but_one, ["goals", "at least 2"], id="one-movable-object"),
    pytest.param(lambda d: d.update(objects=d["objects"][:1]), ["objects"], id="one-object"),
    pytest.param(lambda d: d.pop("objects"), ["objects"], id="no-objects"),
    pytest.param(_top(name="office"), ["name", "'desk'", "'office'"], id="name-not-stem"),
    pytest.param(_ws(x_range=[0.85, 0.30]), ["workspace", "x_range"], id="x-range-reversed"),
    pytest.param(_ws(y_range=[0.2, 0.2]), ["workspace", "y_range"], id="y-range-empty"),
    pytest.param(_ws(y_range=[-0.6, 0.45]), ["workspace", "y_range", "table"], id="off-table"),
    pytest.param(_ws(x_range=[0.30, 1.2]), ["workspace", "x_range", "table"], id="off-table-x"),
    pytest.param(_ws(table_size=[0.75]), ["workspace.table_size"], id="table-size-1"),
    pytest.param(_ws(table_size=[0.75, -1.1]), ["workspace.table_size[1]"], id="table-size-neg"),
    pytest.param(_ws(min_clearance=-0.1), ["workspace.min_clearance"], id="negative-clearance"),
    pytest.param(
        lambda d: d["workspace"]["ee_home"].update(position=[0.55, 0.0, -0.1]),
        ["workspace", "ee_home"],
        id="home-under-table",
    ),
    pytest.param(
        lambda d: d["workspace"]["ee_home"].update(quaternion=[0.0, 0.0, 0.0, 0.0]),
        ["workspace.ee_home.quaternion"],
        id="home-zero-quaternion",
    ),
]


@pytest.mark.parametrize(("mutation", "needles"), BAD_SCENES)
def test_malformed_scene(
    desk_data: dict[str, Any],
    write_scene: WriteScene,
    mutation: Mutation,
    needles: list[str],
) -> None:
    mutation(desk_data)
    path = write_scene(desk_data)
    with pytest.raises(InputError) as info:
        load_scene(path)
    message = str(info.value)
    assert re.fullmatch(rf"{re.escape(str(path))}(:[0-9]+)?", info.value.source or ""), message
    assert message.startswith(f"{info.value.source}: ")
    assert "\n" not in message
    for needle in needles:
        assert needle in message, f"{needle!r} not in {message!r}"


@pytest.mark.parametrize(
    "text",
    [
        pytest.param("schema_version = 1\nname = \n", id="missing-value"),
        pytest.param('schema_version = 1\nname = "desk"\nname = "desk"\n', id="duplicate-key"),
        pytest.param("[[objects]\n", id="unclosed-bracket"),
    ],
)
def test_invalid_toml(write_scene: WriteScene, text: str) -> None:
    path = write_scene(text)
    with pytest.raises(InputError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.startswith(f"{path}: invalid TOML")
    assert "line" in message
    assert "\n" not in message


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "desk.toml"
    path.write_bytes(b'name = "\xff"\n')
    with pytest.raises(InputError, match="UTF-8") as info:
        load_scene(path)
    assert info.value.source == str(path)


def test_missing_scene_file(tmp_path: Path) -> None:
    path = tmp_path / "desk.toml"
    with pytest.raises(InputError, match="no such file") as info:
        load_scene_spec(path)
    assert info.value.source == str(path)


def test_unknown_scene_name_lists_the_folder(
    desk_data: dict[str, Any], write_scene: WriteScene, tmp_path: Path
) -> None:
    write_scene(desk_data)
    with pytest.raises(InputError) as info:
        load_scene("office", directory=tmp_path)
    assert info.value.field == "scene"
    assert "'office'" in str(info.value)
    assert "known: desk" in str(info.value)


def test_scenes_folder_from_environment(
    desk_data: dict[str, Any],
    write_scene: WriteScene,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    desk_data["tier"] = "Custom"
    write_scene(desk_data)
    monkeypatch.setenv("LEGWS_SCENES", str(tmp_path))
    assert scene_names() == ["desk"]
    assert load_scene("desk").spec.tier == "Custom"


def test_defaults_fill_optional_fields(write_scene: WriteScene) -> None:
    doc = {
        "schema_version": 1,
        "name": "tiny",
        "objects": [
            {"name": "a", "shape": "sphere", "size": [0.03], "x": 0.7, "y": 0.2},
            {"name": "b", "shape": "box", "size": [0.05, 0.05, 0.05], "x": 0.7, "y": -0.2},
        ],
    }
    scene = load_scene(write_scene(doc, "tiny"))
    assert scene.goal_names == ("a", "b")
    assert scene.fixed == ()
    assert scene.grasps["a"].symmetry == 0  # top grasp of a sphere: any turn
    assert scene.grasps["b"].symmetry == 4  # top grasp of a square box: quarter turns
    assert scene.objects["a"].color == (0.6, 0.6, 0.6)
    assert scene.workspace.x_range == (0.30, 0.85)


@pytest.mark.parametrize("value", ["no", "yes", 0])
def test_movable_must_be_a_boolean(
    desk_data: dict[str, Any], write_scene: WriteScene, value: object
) -> None:
    desk_data["objects"][1]["movable"] = value
    with pytest.raises(InputError, match=r"objects\[1\]\.movable"):
        load_scene(write_scene(desk_data))
