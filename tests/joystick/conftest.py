"""Fixtures of the joystick tests: the fake kernel's input folder (the only fake is the
device; its events are real ``evdev.InputEvent`` objects)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.joystick.fake_evdev import FakeInputDir


@pytest.fixture
def devices(tmp_path: Path) -> Iterator[FakeInputDir]:
    folder = tmp_path / "input"
    folder.mkdir()
    fake = FakeInputDir(folder)
    try:
        yield fake
    finally:
        fake.close_all()
