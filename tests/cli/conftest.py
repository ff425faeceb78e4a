"""Fixtures of the CLI tests: the example goal set, file writers and the in-process runner."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from legws_daemon.cli.main import run
from tests.cli.helpers import EXAMPLE_GOALSET, Result


@pytest.fixture
def example() -> dict[str, Any]:
    """A fresh deep copy of the example goal set, free to mutate."""
    return copy.deepcopy(EXAMPLE_GOALSET)


@pytest.fixture
def write_json(tmp_path: Path) -> Callable[[str, Any], Path]:
    """Write ``data`` as JSON (NaN and Infinity written as Python's json does) or raw text."""

    def write(name: str, data: Any) -> Path:
        path = tmp_path / name
        text = data if isinstance(data, str) else json.dumps(data, allow_nan=True, indent=1)
        path.write_text(text, encoding="utf-8")
        return path

    return write


@pytest.fixture
def goals_file(write_json: Callable[[str, Any], Path]) -> Path:
    """The example goal set written to ``tmp_path/goals.json``."""
    return write_json("goals.json", EXAMPLE_GOALSET)


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., Result]:
    """Run ``legws ARGV`` in-process; returns exit code, stdout and stderr."""

    def call(*argv: str | Path) -> Result:
        capsys.readouterr()
        code = run([str(a) for a in argv])
        captured = capsys.readouterr()
        return Result(code, captured.out, captured.err)

    return call
