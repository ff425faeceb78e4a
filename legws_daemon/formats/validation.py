"""Shared validation pieces: constrained field types and the errors of a file.

Every error names the source (a file, with the line of the field when the file's text is
at hand: :class:`~legws_daemon.formats.positions.SourceText`), the field and what was
expected: ``scenes/desk.toml:12: objects[0].size[0]: Input should be greater than 0 (got
-0.1)``. A file with several errors gets all of them (:class:`ManyInputsError`), in the order
of their lines; an unknown key close to a known one says ``did you mean 'action'?``.
"""

from __future__ import annotations

import difflib
import json
import math
import re
import tomllib
import types
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, Union, get_args, get_origin

from pydantic import AllowInfNan, BaseModel, Field, RootModel, Strict, ValidationError

from legws_daemon.errors import InputError
from legws_daemon.formats.files import read_limited
from legws_daemon.formats.nesting import check_json_nesting, check_toml_nesting
from legws_daemon.formats.positions import Loc, SourceText
from legws_daemon.formats.printable import safe_text

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
    file) escaped as Python writes it: a message quoting user input stays one line
    (:func:`~legws_daemon.formats.printable.safe_text`, unbounded)."""
    return safe_text(text, None)


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

    Raise it from a ``model_validator``; :func:`input_error` puts ``loc`` into the field
    path (and finds its line).
    """
    return ValueError(f"{_FIELD_MARK}{json.dumps(list(loc))}{_FIELD_MARK}{message}")


_FIELD_MARK = "\x1f"


class ManyInputsError(InputError):
    """Several errors of one input (every validation error of a file), in file order.

    ``str()`` joins them on one line with ``"; "`` (logs, events, messages); the CLI
    prints each on a line of its own (:func:`error_lines`). ``source`` and ``field`` are
    those of the first.
    """

    def __init__(self, errors: Sequence[InputError]) -> None:
        if not errors:
            raise ValueError("ManyInputsError needs at least one error")
        self.errors: tuple[InputError, ...] = tuple(errors)
        super().__init__("; ".join(str(e) for e in self.errors))
        self.source = self.errors[0].source
        self.field = self.errors[0].field


def error_lines(err: BaseException) -> list[str]:
    """The lines of an error as the CLI shows them: one per error of an :class:`ManyInputsError`."""
    if isinstance(err, ManyInputsError):
        return [str(e) for e in err.errors]
    return [str(err)]


def combine(errors: Sequence[InputError]) -> InputError:
    """One error as is; several as :class:`ManyInputsError`."""
    return errors[0] if len(errors) == 1 else ManyInputsError(errors)


def within(err: InputError, source: str, field: str) -> InputError:
    """``err`` (of a file another one names) as an error of ``source``'s ``field``: each of
    its errors prefixed ``source: field:``, every one of them kept (an error that names the
    same field alone, as an unknown name does, once)."""
    lines = [line.removeprefix(f"{field}: ") for line in error_lines(err)]
    return combine([InputError(line, source=source, field=field) for line in lines])


def located(err: InputError, where: SourceText | None) -> InputError:
    """``err`` with the line of its field in its source (when ``where`` finds it).

    For errors raised after validation that name a field (``name``, ``goals[1]``): the
    field path is read back into keys and indices. Each error of a
    :class:`ManyInputsError` is placed at its own line.
    """
    if isinstance(err, ManyInputsError):
        return combine([located(e, where) for e in err.errors])
    if where is None or err.source is None or err.field is None or _LINE.search(err.source):
        return err
    loc = parse_field_path(err.field)
    line = where.line(loc) if loc else None
    if line is None:
        return err
    message = str(err).removeprefix(f"{err.source}: {err.field}: ")
    return InputError(message, source=f"{err.source}:{line}", field=err.field)


def nested(err: InputError, source: str, at: Loc, where: SourceText | None = None) -> InputError:
    """``err``, the errors of a part of a file validated on its own (the value at ``at``: an
    elites entry's layout), as errors of the file: each field below ``at``, at its line in
    ``where``, named ``source:LINE: at.field: ...``; every one kept."""
    out = []
    for e in err.errors if isinstance(err, ManyInputsError) else (err,):
        prefix = ": ".join(p for p in (e.source, e.field) if p)
        message = str(e).removeprefix(f"{prefix}: ") if prefix else str(e)
        below = parse_field_path(e.field) if e.field and e.field != field_path(()) else ()
        loc = (*at, *below)
        src = where.at(source, loc) if where is not None else source
        out.append(InputError(message, source=src, field=field_path(loc)))
    return combine(out)


def in_line_order(errors: Sequence[InputError]) -> InputError:
    """The errors of one file as one, every one kept (those of a :class:`ManyInputsError`
    too), in the order of their lines (``FILE:LINE``; an error without a line first)."""
    flat = [
        e for err in errors for e in (err.errors if isinstance(err, ManyInputsError) else (err,))
    ]

    def line(e: InputError) -> int:
        found = _LINE.search(e.source or "")
        return int(found.group()[1:]) if found else 0

    return combine(sorted(flat, key=line))


_LINE = re.compile(r":[0-9]+$")
_PATH_PART = re.compile(r"\[(\d+)\]|\.?([^.\[\]]+)")


def parse_field_path(path: str) -> Loc:
    """``goals[1].position`` -> ``("goals", 1, "position")`` (:func:`field_path` read back,
    for plain keys); ``()`` when ``path`` is not one."""
    loc: list[int | str] = []
    i = 0
    while i < len(path):
        m = _PATH_PART.match(path, i)
        if m is None or m.end() == i:
            return ()
        loc.append(int(m.group(1)) if m.group(1) is not None else m.group(2))
        i = m.end()
    return tuple(loc)


# --- the errors of a validation ----------------------------------------------------------


def _members(tp: Any) -> list[Any]:
    """The alternatives of a type: ``Annotated``, ``Optional`` and unions unwrapped, a
    root model replaced by its root's type."""
    origin = get_origin(tp)
    if origin is Annotated:
        return _members(get_args(tp)[0])
    if origin is Union or origin is types.UnionType:
        return [m for arg in get_args(tp) for m in _members(arg)]
    if isinstance(tp, type) and issubclass(tp, RootModel):
        return _members(tp.model_fields["root"].annotation)
    return [tp]


def _step(tp: Any, part: int | str) -> list[Any]:
    """The types of the entry ``part`` of a value of type ``tp``."""
    out: list[Any] = []
    for m in _members(tp):
        if isinstance(m, type) and issubclass(m, BaseModel):
            out += [f.annotation for name, f in m.model_fields.items() if (f.alias or name) == part]
            continue
        origin, args = get_origin(m), get_args(m)
        if origin is tuple and args and isinstance(part, int):
            if len(args) == 2 and args[1] is Ellipsis:
                out.append(args[0])
            elif part < len(args):
                out.append(args[part])
        elif origin in (list, set, frozenset, Sequence) and args and isinstance(part, int):
            out.append(args[0])
        elif origin in (dict, Mapping) and len(args) == 2:
            out.append(args[1])
    return out


def known_keys(model: Any, loc: Loc) -> list[str]:
    """The keys a model accepts in the table or object at ``loc`` (``[]``: unknown)."""
    tps = [model]
    for part in loc:
        tps = [t for tp in tps for t in _step(tp, part)]
    keys: list[str] = []
    for tp in tps:
        for m in _members(tp):
            if isinstance(m, type) and issubclass(m, BaseModel):
                keys += [f.alias or name for name, f in m.model_fields.items()]
    return list(dict.fromkeys(keys))


def literal_choices(model: Any, loc: Loc) -> list[str]:
    """The values a model's field at ``loc`` may take when it is a ``Literal`` of
    strings (``[]`` otherwise)."""
    tps = [model]
    for part in loc:
        tps = [t for tp in tps for t in _step(tp, part)]
    members = [m for tp in tps for m in _members(tp)]
    if not members or any(get_origin(m) is not Literal for m in members):
        return []
    values = [v for m in members for v in get_args(m)]
    return [v for v in dict.fromkeys(values) if isinstance(v, str)]


def did_you_mean(word: str, choices: Iterable[str]) -> str | None:
    """The choice closest to ``word`` when one is close (a typo), else ``None``."""
    found = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return found[0] if found else None


def _data_loc(loc: Sequence[int | str], data: Any) -> Loc:
    """pydantic's location of an error as keys and indices of ``data``: the names it
    inserts for validators and union members (``function-after[...]``, ``int``,
    ``LinkSpec``) left out; a last key that is not in the data (a missing one) kept."""
    parts = [
        p for p in loc if not (isinstance(p, str) and (p.startswith("function-") or p == "[key]"))
    ]
    if not isinstance(data, (Mapping, list)):
        return tuple(parts)
    out: list[int | str] = []
    value: Any = data
    for k, part in enumerate(parts):
        if value is _LOST:  # below what the data holds (a validator reshaped it): keep all
            out.append(part)
        elif isinstance(part, int):
            out.append(part)
            ok = isinstance(value, list) and 0 <= part < len(value)
            value = value[part] if ok else _LOST
        elif isinstance(value, Mapping) and part in value:
            out.append(part)
            value = value[part]
        elif isinstance(value, Mapping) and k == len(parts) - 1:
            out.append(part)  # a missing key
        # else: the name of a union member, not a key
    return tuple(out)


_LOST = object()


def _at(data: Any, loc: Loc) -> Any:
    for part in loc:
        if isinstance(data, Mapping) and isinstance(part, str):
            data = data.get(part)
        elif isinstance(data, list) and isinstance(part, int) and 0 <= part < len(data):
            data = data[part]
        else:
            return None
    return data


_QUOTED = re.compile(r"'((?:[^'\\]|\\.)*)'")


def input_error(
    err: ValidationError,
    source: str,
    model: Any = None,
    data: Any = None,
    where: SourceText | None = None,
) -> InputError:
    """Every error of a validation as :class:`InputError` s naming the source (with the
    line of the field when ``where`` has the file's text), the field and what was
    expected, in file order (:func:`combine`). An unknown key close to one ``model``
    accepts says ``did you mean 'KEY'?``, and a required key missing next to it names it."""
    found: list[tuple[Loc, str, dict[str, Any]]] = []
    for e in err.errors(include_url=False):
        loc = _data_loc(e["loc"], data)
        msg = str(e["msg"]).removeprefix("Value error, ")
        detail = dict(e)
        if msg.startswith(_FIELD_MARK):  # a model validator's error below the model
            _, sub, msg = msg.split(_FIELD_MARK, 2)
            loc = (*loc, *json.loads(sub))
            detail.pop("input", None)  # the model's whole input, not the field's
        found.append((loc, msg, detail))
    unknown = {loc for loc, _, d in found if d["type"] == "extra_forbidden" and loc}

    def line(loc: Loc) -> int | None:
        return where.line(loc) if where is not None else None

    out: list[tuple[int, InputError]] = []
    seen: set[tuple[Loc, str]] = set()
    for loc, msg, detail in found:
        kind = detail["type"]
        if kind == "extra_forbidden" and loc and isinstance(loc[-1], str):
            here = _at(data, loc[:-1])
            present = set(here) if isinstance(here, Mapping) else set()
            known = known_keys(model, loc[:-1]) if model is not None else []
            guess = did_you_mean(loc[-1], [k for k in known if k not in present])
            if guess is not None:
                msg += f"; did you mean {guess!r}?"
            elif known:
                msg += f"; known keys: {', '.join(known)}"
        elif kind == "missing" and loc and isinstance(loc[-1], str):
            choices = literal_choices(model, loc) if model is not None else []
            if choices:
                msg += f" (one of {', '.join(repr(c) for c in choices)})"
            siblings = {u[-1]: u for u in unknown if u[:-1] == loc[:-1] and isinstance(u[-1], str)}
            typo = did_you_mean(loc[-1], [str(s) for s in siblings])
            if typo is not None:
                at = line(siblings[typo])
                msg += f"; is {typo!r}{f' on line {at}' if at else ''} a misspelling of it?"
        elif "input" in detail and kind != "missing":
            got = detail["input"]
            msg += f" (got {_describe(got)}"
            if kind == "literal_error" and isinstance(got, str):
                ctx = detail.get("ctx")
                expected = ctx.get("expected", "") if isinstance(ctx, dict) else ""
                options = _QUOTED.findall(str(expected))
                guess = did_you_mean(got, options)
                msg += f"; did you mean {guess!r}?" if guess is not None else ""
            msg += ")"
        if (loc, msg) in seen:  # the same words for two members of a union
            continue
        seen.add((loc, msg))
        at = line(loc)
        src = f"{source}:{at}" if at is not None else source
        out.append((at or 0, InputError(msg, source=src, field=field_path(loc))))
    out.sort(key=lambda pair: pair[0])  # stable: pydantic's order within a line
    return combine([e for _, e in out])


def validate(model: type[M], data: Any, source: str, where: SourceText | None = None) -> M:
    """Validate ``data`` against ``model``; every error becomes an :class:`InputError`
    naming ``source`` (and the line, from ``where``: the text ``data`` was parsed from)."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise input_error(err, source, model, data, where) from None


def read_json(path: Path, kind: str = "text") -> Any:
    """Parse a JSON file of ``kind`` (its size limit: :data:`~legws_daemon.formats.files.LIMITS`).

    Syntax errors name file, line and column; a key given twice in one object and text
    with control or bidirectional characters (:func:`check_text`) are refused. ``NaN``
    and ``Infinity`` literals parse (as Python's json module allows) and are then rejected
    by the schema's finite-number fields, so the message names the field.
    """
    return parse_json(read_text(path, kind), str(path), None)


def read_json_with_lines(path: Path, kind: str = "text") -> tuple[Any, SourceText]:
    """:func:`read_json`, and the file's text to find the line of each error in (pass it
    to :func:`validate`); the errors of reading name the line of their field too."""
    where = SourceText(read_text(path, kind), "json")
    return parse_json(where.text, str(path), where), where


def parse_json(text: str, source: str, where: SourceText | None) -> Any:
    check_json_nesting(text, source)
    try:
        data = json.loads(text, object_pairs_hook=unique_keys)
    except DuplicateKeyError as dup:
        raise InputError(
            f"the key {printable(dup.key)!r} appears twice in one object", source=source
        ) from None
    except json.JSONDecodeError as err:
        raise InputError(
            f"invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}", source=source
        ) from None
    except RecursionError:
        raise InputError("invalid JSON: nested too deeply", source=source) from None
    except ValueError as err:  # e.g. an integer of more than 4300 digits
        raise InputError(f"invalid JSON: {err}", source=source) from None
    check_json_text(data, text, source, where)
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


def read_toml_with_lines(path: Path, kind: str = "text") -> tuple[dict[str, Any], SourceText]:
    """:func:`read_toml`, and the file's text to find the line of each error in (pass it
    to :func:`validate`)."""
    text = read_text(path, kind)
    return parse_toml(text, str(path)), SourceText(text, "toml")


def parse_toml(text: str, source: str) -> dict[str, Any]:
    """:func:`read_toml` of text already read from ``source``; a non-finite number or a
    control character names the line of its field."""
    check_toml_nesting(text, source)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"invalid TOML: {err}", source=source) from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise InputError("invalid TOML: nested too deeply", source=source) from None
    except ValueError as err:  # e.g. an integer of more than 4300 digits
        raise InputError(f"invalid TOML: {err}", source=source) from None
    where = SourceText(text, "toml")
    _reject_non_finite(data, source, (), where)
    check_text(data, source, where=where)
    return data


def _reject_non_finite(
    value: Any, source: str, loc: tuple[int | str, ...], where: SourceText | None
) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        src = where.at(source, loc) if where is not None else source
        raise InputError(
            f"expected a finite number, got {value}", source=src, field=field_path(loc)
        )
    if isinstance(value, dict):
        for k, v in value.items():
            _reject_non_finite(v, source, (*loc, k), where)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _reject_non_finite(v, source, (*loc, i), where)


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


def check_text(
    value: Any, source: str, loc: tuple[int | str, ...] = (), where: SourceText | None = None
) -> None:
    """Refuse control and bidirectional characters in every key and string of ``value``.

    Names, labels, prompts and descriptions are printed on terminals and in tables: a
    character that moves the cursor, clears the screen or reorders text is refused at
    load, in one line naming the file (and the line, from ``where``), the field and the
    character (as U+XXXX).
    """
    if isinstance(value, str):
        bad = unsafe_character(value)
        if bad is not None:
            raise InputError(
                f"holds the control character U+{ord(bad):04X}; text may not hold control "
                "or bidirectional characters",
                source=where.at(source, loc) if where is not None else source,
                field=field_path(loc),
            )
    elif isinstance(value, dict):
        for k, v in value.items():
            check_text(str(k), source, (*loc, k), where)
            check_text(v, source, (*loc, k), where)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            check_text(v, source, (*loc, i), where)


def check_json_text(data: Any, text: str, source: str, where: SourceText | None = None) -> None:
    """:func:`check_text` of ``data`` parsed from the JSON ``text``: the walk only where a
    string of it can hold such a character (JSON writes a control character only as an
    escape, so a text without a backslash or an unsafe character of its own has none)."""
    if "\\" in text or unsafe_character(text) is not None:
        check_text(data, source, where=where)


def read_text(path: Path, kind: str = "text") -> str:
    """The UTF-8 text of a regular file of ``kind``, within its size limit
    (:func:`~legws_daemon.formats.files.read_limited`)."""
    data = read_limited(path, kind)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file", source=str(path)) from None


def resolve_named(name_or_path: str, folder: Path, what: str, field: str) -> Path:
    """``name`` -> ``folder/name.toml`` (a shipped file); a ``.toml`` path or one with a
    ``/`` is used as is. An unknown name lists the known ones (``did you mean ...?`` for a
    close one), as an :class:`InputError` of ``field``."""
    if name_or_path.endswith(".toml") or "/" in name_or_path:
        return Path(name_or_path)
    path = folder / f"{name_or_path}.toml"
    if not path.is_file():
        names = sorted(p.stem for p in folder.glob("*.toml"))
        guess = did_you_mean(name_or_path, names)
        hint = f"; did you mean '{guess}'?" if guess is not None else ";"
        known = ", ".join(names) or "(none)"
        raise InputError(f"unknown {what} '{name_or_path}'{hint} known: {known}", field=field)
    return path
