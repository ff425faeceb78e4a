"""Layout files: JSON ``{object name: {"x": m, "y": m, "yaw": rad}}`` (interfaces.md).

A layout names some or all of a scene's movable objects; the others keep the scene
file's poses. Fixed objects and unknown names are rejected. Every error of a file is
reported, each at its line (``layout.json:3: white_mug.yw: Extra inputs are not permitted;
did you mean 'yaw'?``); an unknown object close to a movable one says ``did you mean``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, RootModel

from legws_daemon.errors import InputError
from legws_daemon.formats.positions import SourceText
from legws_daemon.formats.validation import (
    Angle,
    Coordinate,
    did_you_mean,
    field_path,
    in_line_order,
    printable,
    read_json_with_lines,
    validate,
)
from legws_daemon.scene.scene import Layout, ObjectPose, Scene


class _PoseEntry(BaseModel):
    model_config = ConfigDict(extra="forbid")

    x: Coordinate
    y: Coordinate
    yaw: Angle = 0.0


class _LayoutFile(RootModel[dict[str, _PoseEntry]]):
    pass


def layout_from_data(
    data: Any, scene: Scene, source: str, where: SourceText | None = None
) -> Layout:
    """Validate the parsed JSON of a layout for ``scene`` (``where``: its text, for the line
    of each error). Every error is reported: the fields that do not validate and the names
    that are not movable objects of the scene, in the order of their lines."""
    names = [n for n in data if isinstance(n, str)] if isinstance(data, dict) else []
    errors = _name_errors(names, scene, source, where)
    try:
        doc = validate(_LayoutFile, data, source, where)
    except InputError as err:
        raise in_line_order([err, *errors]) from None
    if errors:
        raise in_line_order(errors)
    return {n: ObjectPose(e.x, e.y, e.yaw) for n, e in doc.root.items()}


def _name_errors(
    names: list[str], scene: Scene, source: str, where: SourceText | None
) -> list[InputError]:
    """An error for each name that is not a movable object of ``scene``, at its line; an
    unknown one close to a movable object the layout does not name says ``did you mean``."""
    out = []
    free = [m for m in scene.movable if m not in names]
    for n in names:
        if n not in scene.objects:
            guess = did_you_mean(n, free)
            hint = f"; did you mean '{guess}'?" if guess is not None else ";"
            message = (
                f"unknown object '{printable(n)}' in layout{hint} scene '{scene.name}' has: "
                f"{', '.join(scene.objects)}"
            )
        elif n not in scene.movable:
            message = (
                f"object '{n}' is fixed in scene '{scene.name}'; movable: "
                f"{', '.join(scene.movable)}"
            )
        else:
            continue
        src = where.at(source, (n,)) if where is not None else source
        out.append(InputError(message, source=src, field=field_path((n,))))
    return out


def load_layout(path: Path, scene: Scene) -> Layout:
    """Read a layout file for ``scene``; errors name the file, the line, the object and the
    field (every one of them)."""
    data, where = read_json_with_lines(path, "layout")
    return layout_from_data(data, scene, str(path), where)


def layout_to_data(layout: Layout) -> dict[str, dict[str, float]]:
    return {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in layout.items()}


def dump_json(data: Any) -> str:
    return json.dumps(data, indent=2, allow_nan=False) + "\n"
