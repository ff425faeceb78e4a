"""``--rerun spawn`` finds the viewer installed next to Python (the venv's, even when the
venv is not on PATH), or says in one line what to install."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.telemetry.rerun_log import viewer_executable


def test_the_viewer_next_to_python_is_found_without_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", "")
    found = viewer_executable()
    assert found == Path(sys.executable).parent / "rerun"
    assert found.is_file()


def test_the_viewer_on_path_is_the_fallback(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    viewer = bin_dir / "rerun"
    viewer.write_text("#!/bin/sh\n")
    viewer.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    monkeypatch.setenv("PATH", str(bin_dir))
    assert viewer_executable() == viewer


def test_no_viewer_is_one_line_naming_what_to_install(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(InputError) as info:
        viewer_executable()
    text = str(info.value)
    assert "\n" not in text
    assert "--rerun" in text and "pip install rerun-sdk" in text and "save:PATH" in text
