"""Fixtures of the scene tests."""

from __future__ import annotations

import pytest

from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene


@pytest.fixture(scope="session")
def desk() -> Scene:
    return load_scene("desk")
