"""Shared validation pieces: constrained field types and one-line error messages."""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import AllowInfNan, BaseModel, Field, Strict, ValidationError

from legws_daemon.errors import InputError
from legws_daemon.formats.files import read_limited

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


def read_json(path: Path, kind: str = "text") -> Any:
    """Parse a JSON file of ``kind`` (its size limit: :data:`~legws_daemon.formats.files.LIMITS`).

    Syntax errors name file, line and column; a key given twice in one object and text
    with control or bidirectional characters (:func:`check_text`) are refused. ``NaN``
    and ``Infinity`` literals parse (as Python's json module allows) and are then rejected
    by the schema's finite-number fields, so the message names the field.
    """
    text = read_text(path, kind)
    try:
        data = json.loads(text, object_pairs_hook=unique_keys)
    except DuplicateKeyError as dup:
        raise InputError(
            f"the key {printable(dup.key)!r} appears twice in one object", source=str(path)
        ) from None
    except json.JSONDecodeError as err:
        raise InputError(
            f"invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}", source=str(path)
        ) from None
    except RecursionError:
        raise InputError("invalid JSON: nested too deeply", source=str(path)) from None
    except ValueError as err:  # e.g. an integer of more than 4300 digits
        raise InputError(f"invalid JSON: {err}", source=str(path)) from None
    check_text(data, str(path))
    return data


class DuplicateKeyError(ValueError):
    """A JSON object names a key twice (raised by :func:`unique_keys`)."""

    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` of :func:`json.loads`: a key given twice is an error (the
    json module would keep the last one silently)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKeyError(key)
        out[key] = value
    return out


def read_toml(path: Path, kind: str = "text") -> dict[str, Any]:
    """Parse a TOML file of ``kind``; errors name the file and the position.

    TOML itself forbids a key given twice; text with control or bidirectional characters
    (:func:`check_text`) and non-finite numbers are refused.
    """
    return parse_toml(read_text(path, kind), str(path))


def parse_toml(text: str, source: str) -> dict[str, Any]:
    """:func:`read_toml` of text already read from ``source``."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"invalid TOML: {err}", source=source) from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise InputError("invalid TOML: nested too deeply", source=source) from None
    except ValueError as err:  # e.g. an integer of more than 4300 digits
        raise InputError(f"invalid TOML: {err}", source=source) from None
    _reject_non_finite(data, source, ())
    check_text(data, source)
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


#: Characters no text from a file may hold: C0/C1 controls other than tab and line feed
#: (ESC starts terminal escapes, CR overwrites a line, NUL cuts strings), the line and
#: paragraph separators, and the bidirectional controls that reorder what a terminal
#: shows (the "Trojan Source" characters).
_BIDI = "\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069"
_FORBIDDEN = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028\u2029" + _BIDI + "]")


def unsafe_character(text: str) -> str | None:
    """The first character of ``text`` that must not reach a terminal, or ``None``."""
    found = _FORBIDDEN.search(text)
    return found.group() if found else None


def check_text(value: Any, source: str, loc: tuple[int | str, ...] = ()) -> None:
    """Refuse control and bidirectional characters in every key and string of ``value``.

    Names, labels, prompts and descriptions are printed on terminals and in tables: a
    character that moves the cursor, clears the screen or reorders text is refused at
    load, in one line naming the file, the field and the character (as U+XXXX).
    """
    if isinstance(value, str):
        bad = unsafe_character(value)
        if bad is not None:
            raise InputError(
                f"holds the control character U+{ord(bad):04X}; text may not hold control "
                "or bidirectional characters",
                source=source,
                field=field_path(loc),
            )
    elif isinstance(value, dict):
        for k, v in value.items():
            check_text(str(k), source, (*loc, k))
            check_text(v, source, (*loc, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            check_text(v, source, (*loc, i))


def read_text(path: Path, kind: str = "text") -> str:
    """The UTF-8 text of a regular file of ``kind``, within its size limit
    (:func:`~legws_daemon.formats.files.read_limited`)."""
    data = read_limited(path, kind)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", source=str(path)) from None
