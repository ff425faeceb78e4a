"""A study's folder on disk: the plan ``legws study plan`` wrote, read back."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from legws_daemon.errors import InputError
from legws_daemon.formats.validation import read_json


def existing_plan(folder: Path) -> dict[str, Any] | None:
    """The ``plan.json`` in ``folder``, or ``None`` when there is none."""
    path = folder / "plan.json"
    if not path.exists():
        return None
    data = read_json(path, "study schedule")
    if not isinstance(data, dict):
        raise InputError("expected a JSON object (a study plan)", source=str(path))
    return data
