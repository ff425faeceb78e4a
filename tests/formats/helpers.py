"""Plain helpers of the file-format tests: a TOML writer for any JSON-like document."""

from __future__ import annotations

import math
import re
from typing import Any

# --- writing TOML (any JSON-like value; what TOML cannot say becomes a wrong type) ------
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _toml_string(text: str) -> str:
    out = []
    for ch in text:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else _toml_string(key)


def _toml_value(value: Any) -> str:
    if value is None:
        return "{}"  # TOML has no null: an empty table, a wrong type anyway
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
        return _toml_string(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return (
            "{"
            + ", ".join(f"{_toml_key(str(k))} = {_toml_value(v)}" for k, v in value.items())
            + "}"
        )
    raise TypeError(type(value).__name__)


def _table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def toml_dumps(doc: Any, prefix: str = "") -> str:
    """A TOML document: tables and arrays of tables as sections, the rest inline."""
    if not isinstance(doc, dict):
        return f"value = {_toml_value(doc)}\n"
    lines = [
        f"{_toml_key(str(k))} = {_toml_value(v)}"
        for k, v in doc.items()
        if not (isinstance(v, dict) and v) and not _table_array(v)
    ]
    for k, v in doc.items():
        full = f"{prefix}.{_toml_key(str(k))}" if prefix else _toml_key(str(k))
        if isinstance(v, dict) and v:
            lines += ["", f"[{full}]", toml_dumps(v, full)]
        elif _table_array(v):
            for item in v:
                lines += ["", f"[[{full}]]", toml_dumps(item, full)]
    return "\n".join(lines) + "\n"
