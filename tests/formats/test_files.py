"""Atomic writes: all or nothing, no temporary files left, one-line errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.files import write_atomic


def test_replaces_whole_and_leaves_nothing_behind(tmp_path: Path) -> None:
    target = tmp_path / "a.json"
    target.write_text("old")
    write_atomic(target, b"new")
    assert target.read_bytes() == b"new"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_missing_folder_is_an_input_error(tmp_path: Path) -> None:
    target = tmp_path / "nope" / "a.json"
    with pytest.raises(InputError, match="cannot write") as info:
        write_atomic(target, b"x")
    assert str(info.value).startswith(str(target))
    assert not (tmp_path / "nope").exists()
