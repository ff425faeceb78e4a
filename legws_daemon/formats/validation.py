"""Shared validation pieces: constrained field types and one-line error messages."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import AllowInfNan, BaseModel, Field, Strict, ValidationError

from legws_daemon.errors import InputError

#: A finite real number; strings, booleans, NaN and infinities are rejected.
Finite = Annotated[float, Strict(), AllowInfNan(False)]
Positive = Annotated[float, Strict(), AllowInfNan(False), Field(gt=0)]
NonNegative = Annotated[float, Strict(), AllowInfNan(False), Field(ge=0)]
Vec3 = tuple[Finite, Finite, Finite]
Quat = tuple[Finite, Finite, Finite, Finite]
Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=64)]

M = TypeVar("M", bound=BaseModel)


def nonzero_quaternion(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Field validator: a quaternion must have a non-zero norm (it is normalised later)."""
    if math.sqrt(sum(c * c for c in q)) < 1e-9:
        raise ValueError("quaternion must have a non-zero norm")
    return q


def field_path(loc: tuple[int | str, ...]) -> str:
    """``("goals", 1, "position")`` -> ``goals[1].position``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out or "(top level)"


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def one_line(err: ValidationError, source: str) -> InputError:
    """The first validation error as an :class:`InputError` naming file and field."""
    errors = err.errors(include_url=False)
    first = errors[0]
    loc = tuple(p for p in first["loc"] if not (isinstance(p, str) and p.startswith("function-")))
    msg = str(first["msg"])
    msg = msg.removeprefix("Value error, ")
    if first["type"] not in ("missing",) and "input" in first:
        msg = f"{msg} (got {_describe(first['input'])})"
    more = len(errors) - 1
    if more:
        msg += f" [and {more} more error{'s' if more > 1 else ''}]"
    return InputError(msg, source=source, field=field_path(loc))


def validate(model: type[M], data: Any, source: str) -> M:
    """Validate ``data`` against ``model``; errors become one-line :class:`InputError`."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise one_line(err, source) from None


def _reject_constant(token: str) -> float:
    raise ValueError(f"{token} is not a number")


def read_json(path: Path) -> Any:
    """Parse a JSON file; NaN and Infinity are rejected, errors name file and line."""
    text = read_text(path)
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as err:
        raise InputError(
            f"invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}", source=str(path)
        ) from None
    except ValueError as err:
        raise InputError(f"invalid JSON: {err}", source=str(path)) from None


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; errors name the file and the position."""
    text = read_text(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"invalid TOML: {err}", source=str(path)) from None
    _reject_non_finite(data, str(path), ())
    return data


def _reject_non_finite(value: Any, source: str, loc: tuple[int | str, ...]) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(
            f"expected a finite number, got {value}", source=source, field=field_path(loc)
        )
    if isinstance(value, dict):
        for k, v in value.items():
            _reject_non_finite(v, source, (*loc, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _reject_non_finite(v, source, (*loc, i))


def read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("no such file", source=str(path)) from None
    except IsADirectoryError:
        raise InputError("is a directory, expected a file", source=str(path)) from None
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", source=str(path)) from None
    except OSError as err:
        raise InputError(f"cannot read: {err.strerror}", source=str(path)) from None
