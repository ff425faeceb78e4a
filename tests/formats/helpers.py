"""Plain helpers of the file-format tests: a minimal TOML writer for scene files."""

from __future__ import annotations

import json
import math
from typing import Any


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as a TOML value")


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def toml_dumps(doc: dict[str, Any], prefix: str = "") -> str:
    """Enough of TOML for scene files: scalars, arrays, tables and arrays of tables."""
    lines = [
        f"{key} = {_toml_value(value)}"
        for key, value in doc.items()
        if not isinstance(value, dict) and not _is_table_array(value)
    ]
    for key, value in doc.items():
        full = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            lines += ["", f"[{full}]", toml_dumps(value, full)]
        elif _is_table_array(value):
            for item in value:
                lines += ["", f"[[{full}]]", toml_dumps(item, full)]
    return "\n".join(lines) + "\n"
