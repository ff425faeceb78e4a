"""Layout files: ``{object: {"x", "y", "yaw"}}`` for the movable objects of a scene."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.scene.layout_file import (
    dump_json,
    layout_from_data,
    layout_to_data,
    load_layout,
)
from legws_daemon.scene.scene import ObjectPose, Scene


def write(tmp_path: Path, data: Any) -> Path:
    path = tmp_path / "layout.json"
    path.write_text(data if isinstance(data, str) else json.dumps(data), encoding="utf-8")
    return path


def test_valid_layout(desk: Scene, tmp_path: Path) -> None:
    path = write(
        tmp_path,
        {"white_mug": {"x": 0.45, "y": -0.35, "yaw": 0.3}, "black_stapler": {"x": 0.7, "y": 0}},
    )
    layout = load_layout(path, desk)
    assert layout == {
        "white_mug": ObjectPose(0.45, -0.35, 0.3),
        "black_stapler": ObjectPose(0.7, 0.0, 0.0),  # yaw defaults to 0; int y is fine
    }
    poses = desk.poses(layout)
    assert poses["white_mug"] == ObjectPose(0.45, -0.35, 0.3)
    # objects the layout does not name keep the scene file's poses
    assert poses["maroon_pen_cup"] == desk.default_layout()["maroon_pen_cup"]
    tape = desk.objects["tape_dispenser"]
    assert poses["tape_dispenser"] == ObjectPose(tape.x, tape.y, tape.yaw)


def test_empty_layout_is_the_default(desk: Scene, tmp_path: Path) -> None:
    layout = load_layout(write(tmp_path, {}), desk)
    assert layout == {}
    assert desk.poses(layout) == desk.poses()


@settings(max_examples=30, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["white_mug", "black_stapler", "maroon_pen_cup"]),
        st.tuples(st.floats(0.3, 0.85), st.floats(-0.45, 0.45), st.floats(-math.pi, math.pi)).map(
            lambda t: ObjectPose(*t)
        ),
    )
)
def test_round_trip(desk: Scene, layout: dict[str, ObjectPose]) -> None:
    data = json.loads(dump_json(layout_to_data(layout)))
    assert layout_from_data(data, desk, "mem") == layout


def _error(desk: Scene, tmp_path: Path, data: Any, line: int | None = 1) -> tuple[Path, str]:
    """The error of loading ``data`` (one line of JSON: every field on line 1; ``line``
    ``None``: an error of the whole file, without a line)."""
    path = write(tmp_path, data)
    with pytest.raises(InputError) as info:
        load_layout(path, desk)
    message = str(info.value)
    where = str(path) if line is None else f"{path}:{line}"
    assert info.value.source == where
    assert message.startswith(f"{where}: ")
    assert "\n" not in message
    return path, message


def test_unknown_name(desk: Scene, tmp_path: Path) -> None:
    _, message = _error(desk, tmp_path, {"banana": {"x": 0.6, "y": 0.2}})
    assert "'banana'" in message
    assert "white_mug" in message  # lists the scene's objects


def test_fixed_name(desk: Scene, tmp_path: Path) -> None:
    _, message = _error(desk, tmp_path, {"tape_dispenser": {"x": 0.6, "y": 0.2}})
    assert "'tape_dispenser'" in message
    assert "fixed" in message


def test_missing_x(desk: Scene, tmp_path: Path) -> None:
    _, message = _error(desk, tmp_path, {"white_mug": {"y": 0.2}})
    assert "white_mug.x" in message


@pytest.mark.parametrize(
    ("entry", "field"),
    [
        pytest.param({"x": "0.6", "y": 0.2}, "white_mug.x", id="x-string"),
        pytest.param({"x": True, "y": 0.2}, "white_mug.x", id="x-bool"),
        pytest.param({"x": 0.6, "y": None}, "white_mug.y", id="y-null"),
        pytest.param({"x": 0.6, "y": 0.2, "yaw": "0"}, "white_mug.yaw", id="yaw-string"),
        pytest.param({"x": 0.6, "y": 0.2, "z": 0.0}, "white_mug.z", id="unknown-key"),
        pytest.param({"x": 1e400, "y": 0.2}, "white_mug.x", id="x-overflows-to-inf"),
    ],
)
def test_bad_field(desk: Scene, tmp_path: Path, entry: dict[str, Any], field: str) -> None:
    text = json.dumps({"white_mug": entry}).replace("Infinity", "1e400")
    _, message = _error(desk, tmp_path, text)
    assert field in message


def test_not_an_object(desk: Scene, tmp_path: Path) -> None:
    _, message = _error(desk, tmp_path, [{"white_mug": {"x": 0.6, "y": 0.2}}], line=None)
    assert "(top level)" in message


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_nan(desk: Scene, tmp_path: Path, constant: str) -> None:
    _, message = _error(desk, tmp_path, f'{{"white_mug": {{"x": {constant}, "y": 0.2}}}}')
    assert "white_mug.x" in message
    assert "finite" in message


def test_nan_names_the_field(desk: Scene, tmp_path: Path) -> None:
    _, message = _error(desk, tmp_path, '{"white_mug": {"x": NaN, "y": 0.2}}')
    assert "white_mug.x" in message


def test_missing_file(desk: Scene, tmp_path: Path) -> None:
    path = tmp_path / "nope.json"
    with pytest.raises(InputError, match="no such file") as info:
        load_layout(path, desk)
    assert info.value.source == str(path)


def test_dump_json_rejects_nan() -> None:
    with pytest.raises(ValueError, match="JSON"):
        dump_json({"x": float("nan")})
