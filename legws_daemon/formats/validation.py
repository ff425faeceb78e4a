"""Shared validation pieces: constrained field types and one-line error messages."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import AllowInfNan, BaseModel, Field, Strict, ValidationError

from legws_daemon.errors import InputError

#: Largest magnitude accepted for any coordinate or size, metres: far beyond any robot cell,
#: small enough that nothing downstream can overflow.
MAX_COORDINATE = 100.0

#: A finite real number; strings, booleans, NaN and infinities are rejected.
Finite = Annotated[float, Strict(), AllowInfNan(False)]
#: A coordinate in metres, |value| <= MAX_COORDINATE.
Coordinate = Annotated[
    float, Strict(), AllowInfNan(False), Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE)
]
#: An angle in radians, |value| <= 100 (any yaw, unwrapped or not).
Angle = Annotated[float, Strict(), AllowInfNan(False), Field(ge=-100.0, le=100.0)]
Positive = Annotated[float, Strict(), AllowInfNan(False), Field(gt=0, le=MAX_COORDINATE)]
NonNegative = Annotated[float, Strict(), AllowInfNan(False), Field(ge=0, le=MAX_COORDINATE)]
Vec3 = tuple[Coordinate, Coordinate, Coordinate]
Quat = tuple[Finite, Finite, Finite, Finite]
Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=64)]

M = TypeVar("M", bound=BaseModel)


#: Largest quaternion norm accepted: normalising it later (sums of squares) cannot overflow.
MAX_QUATERNION_NORM = 1e150


def nonzero_quaternion(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Field validator: a quaternion must have a non-zero norm (it is normalised later)."""
    norm = math.hypot(*q)  # no overflow in the squares
    if norm < 1e-9:
        raise ValueError("quaternion must have a non-zero norm")
    if norm > MAX_QUATERNION_NORM:
        raise ValueError(f"quaternion norm must be at most {MAX_QUATERNION_NORM:g}, got {norm:.3g}")
    return q


def printable(text: str) -> str:
    """``text`` with every character that is not printable (a line break in a name from a
    file) escaped as Python writes it: a message quoting user input stays one line."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def field_path(loc: tuple[int | str, ...]) -> str:
    """``("goals", 1, "position")`` -> ``goals[1].position``.

    A key that is empty or not printable (a user's typo may hold a line break) is quoted
    as Python would write it, so the path stays on one line.
    """
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            text = str(part) if str(part) and str(part).isprintable() else repr(str(part))
            out += f".{text}" if out else text
    return out or "(top level)"


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def field_error(loc: tuple[int | str, ...], message: str) -> ValueError:
    """An error for a model validator that points at a field below the model.

    Raise it from a ``model_validator``; :func:`one_line` puts ``loc`` into the field path.
    """
    return ValueError(f"{_FIELD_MARK}{json.dumps(list(loc))}{_FIELD_MARK}{message}")


_FIELD_MARK = "\x1f"


def one_line(err: ValidationError, source: str) -> InputError:
    """The first validation error as an :class:`InputError` naming file and field."""
    errors = err.errors(include_url=False)
    first = errors[0]
    loc = tuple(p for p in first["loc"] if not (isinstance(p, str) and p.startswith("function-")))
    msg = str(first["msg"])
    msg = msg.removeprefix("Value error, ")
    if msg.startswith(_FIELD_MARK):
        _, sub, msg = msg.split(_FIELD_MARK, 2)
        loc = (*loc, *json.loads(sub))
    elif first["type"] not in ("missing",) and "input" in first:
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


def read_json(path: Path) -> Any:
    """Parse a JSON file; syntax errors name file, line and column.

    ``NaN`` and ``Infinity`` literals parse (as Python's json module allows) and are then
    rejected by the schema's finite-number fields, so the message names the field.
    """
    text = read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(
            f"invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}", source=str(path)
        ) from None
    except RecursionError:
        raise InputError("invalid JSON: nested too deeply", source=str(path)) from None
    except ValueError as err:  # e.g. an integer of more than 4300 digits
        raise InputError(f"invalid JSON: {err}", source=str(path)) from None


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; errors name the file and the position."""
    text = read_text(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"invalid TOML: {err}", source=str(path)) from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise InputError("invalid TOML: nested too deeply", source=str(path)) from None
    except ValueError as err:  # e.g. an integer of more than 4300 digits
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
