"""Layout files: JSON ``{object name: {"x": m, "y": m, "yaw": rad}}`` (interfaces.md).

A layout names some or all of a scene's movable objects; the others keep the scene
file's poses. Fixed objects and unknown names are rejected.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, RootModel

from legws_daemon.errors import InputError
from legws_daemon.formats.validation import Angle, Coordinate, printable, read_json, validate
from legws_daemon.scene.scene import Layout, ObjectPose, Scene


class _PoseEntry(BaseModel):
    model_config = ConfigDict(extra="forbid")

    x: Coordinate
    y: Coordinate
    yaw: Angle = 0.0


class _LayoutFile(RootModel[dict[str, _PoseEntry]]):
    pass


def layout_from_data(data: Any, scene: Scene, source: str) -> Layout:
    doc = validate(_LayoutFile, data, source)
    try:
        scene.check_names(list(doc.root))
    except InputError as err:
        raise InputError(printable(str(err)), source=source) from None
    return {n: ObjectPose(e.x, e.y, e.yaw) for n, e in doc.root.items()}


def load_layout(path: Path, scene: Scene) -> Layout:
    """Read a layout file for ``scene``; errors name the file, the object and the field."""
    return layout_from_data(read_json(path, "layout"), scene, str(path))


def layout_to_data(layout: Layout) -> dict[str, dict[str, float]]:
    return {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in layout.items()}


def dump_json(data: Any) -> str:
    return json.dumps(data, indent=2, allow_nan=False) + "\n"
