"""Fixtures of the file-format tests: the desk scene and scene-file writers."""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.scene.catalog import load_scene, scenes_dir
from legws_daemon.scene.scene import Scene
from tests.formats.helpers import toml_dumps


@pytest.fixture
def desk_data() -> dict[str, Any]:
    """The shipped ``desk`` scene as parsed TOML, free to mutate."""
    return copy.deepcopy(tomllib.loads((scenes_dir() / "desk.toml").read_text(encoding="utf-8")))


@pytest.fixture
def write_scene(tmp_path: Path) -> Callable[[dict[str, Any] | str, str], Path]:
    """Write a scene document (or raw text) to ``tmp_path/STEM.toml``."""

    def write(doc: dict[str, Any] | str, stem: str = "desk") -> Path:
        path = tmp_path / f"{stem}.toml"
        path.write_text(doc if isinstance(doc, str) else toml_dumps(doc), encoding="utf-8")
        return path

    return write


@pytest.fixture(scope="session")
def desk() -> Scene:
    return load_scene("desk")
