"""Where a field is in a file's text: the line of a key path such as ``stages[1].action``.

Python's parsers give data, not positions (``tomllib`` and ``json`` keep none), so a small
scanner reads the text again — only when an error is to be shown — and notes the line of
every key, table header, array-of-tables element and array element:
``("stages", 1, "action")`` -> 23. The text has already parsed, so the scanners need not
diagnose anything; on text they do not follow they return what they found so far.

A path that is not in the file (a required key that is missing) is placed at its
nearest enclosing entry that is: a missing ``stages[1].action`` at the ``[[stages]]``
header of stage 1.
"""

from __future__ import annotations

import bisect
import json
import re
import tomllib
from typing import Literal

Loc = tuple[int | str, ...]
Syntax = Literal["toml", "json"]


class SourceText:
    """The text of a file, to find the line of a field path in (:meth:`line`).

    The index of lines is built on the first question (an error), not when the file is
    read: a file that validates costs nothing more.
    """

    def __init__(self, text: str, syntax: Syntax) -> None:
        self.text = text
        self.syntax = syntax
        self._lines: dict[Loc, int] | None = None

    def line(self, loc: Loc) -> int | None:
        """The 1-based line of ``loc``, or of its nearest enclosing entry in the file;
        ``None`` when not even its first key is in the file (a missing top-level key)."""
        if self._lines is None:
            try:
                scan = toml_lines if self.syntax == "toml" else json_lines
                self._lines = scan(self.text)
            except RecursionError:  # nested deeper than the scanner follows: no lines
                self._lines = {}
        for end in range(len(loc), 0, -1):
            found = self._lines.get(tuple(loc[:end]))
            if found is not None:
                return found
        return None

    def at(self, source: str, loc: Loc) -> str:
        """``source:LINE`` for the line of ``loc``, or ``source`` when it has none."""
        line = self.line(loc)
        return f"{source}:{line}" if line is not None else source


class _Lines:
    """Offsets to 1-based line numbers."""

    def __init__(self, text: str) -> None:
        self.starts = [m.end() for m in re.finditer("\n", text)]

    def __call__(self, offset: int) -> int:
        return bisect.bisect_right(self.starts, offset) + 1


# --- JSON ------------------------------------------------------------------------------

_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_JSON_SCALAR = re.compile(r"[-+0-9.eEa-zA-Z]+")
_JSON_SPACE = re.compile(r"[ \t\r\n]*")


def json_lines(text: str) -> dict[Loc, int]:
    """The line of every key and array element of a JSON text (iterative: any depth)."""
    line_of = _Lines(text)
    out: dict[Loc, int] = {}
    # each open container: [path, is_object, next array index, key awaited, current key]
    stack: list[list[object]] = []
    i, n = 0, len(text)

    def value_path(at: int) -> Loc:
        if not stack:
            return ()
        path, is_object, index, _, key = stack[-1]
        assert isinstance(path, tuple)
        if is_object:
            return (*path, str(key))
        assert isinstance(index, int)
        loc: Loc = (*path, index)
        out.setdefault(loc, line_of(at))
        return loc

    while i < n:
        i = _JSON_SPACE.match(text, i).end()  # type: ignore[union-attr]
        if i >= n:
            break
        c = text[i]
        if c == '"':
            m = _JSON_STRING.match(text, i)
            if m is None:
                break
            if stack and stack[-1][1] and stack[-1][3]:  # a key
                path = stack[-1][0]
                assert isinstance(path, tuple)
                key = json.loads(m.group())
                stack[-1][3], stack[-1][4] = False, key
                out.setdefault((*path, key), line_of(i))
            else:
                value_path(i)
            i = m.end()
        elif c in "{[":
            stack.append([value_path(i), c == "{", 0, c == "{", None])
            i += 1
        elif c in "}]":
            if stack:
                stack.pop()
            i += 1
        elif c == ",":
            if stack:
                top = stack[-1]
                if top[1]:
                    top[3] = True
                else:
                    assert isinstance(top[2], int)
                    top[2] += 1
            i += 1
        elif c == ":":
            i += 1
        else:
            m = _JSON_SCALAR.match(text, i)
            if m is None:
                break
            value_path(i)
            i = m.end()
    return out


# --- TOML ------------------------------------------------------------------------------

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_TOML_SPACE = re.compile(r"[ \t]*")
_TOML_SCALAR = re.compile(r"[^,\]}\n#]*")


class _TomlScanner:
    def __init__(self, text: str) -> None:
        self.text = text
        self.line_of = _Lines(text)
        self.out: dict[Loc, int] = {}
        self.arrays: dict[Loc, int] = {}  # the last index of each array of tables

    def note(self, loc: Loc, at: int) -> None:
        self.out.setdefault(loc, self.line_of(at))

    def space(self, i: int, newlines: bool = False) -> int:
        """Past blanks and comments (and line breaks when ``newlines``)."""
        text, n = self.text, len(self.text)
        while i < n:
            i = _TOML_SPACE.match(text, i).end()  # type: ignore[union-attr]
            if i < n and text[i] == "#":
                end = text.find("\n", i)
                i = n if end < 0 else end
            elif i < n and text[i] in "\r\n" and newlines:
                i += 1
            else:
                break
        return i

    def string_end(self, i: int) -> int:
        """The offset past the string that starts at ``i``."""
        text = self.text
        for quote in ('"""', "'''"):
            if text.startswith(quote, i):
                j = i + 3
                while True:
                    k = text.find(quote, j)
                    if k < 0:
                        return len(text)
                    if quote == '"""' and _escaped(text, k):
                        j = k + 1
                        continue
                    k += 3
                    extra = 0  # up to two quotes may end the content
                    while extra < 2 and text.startswith(quote[0], k):
                        k, extra = k + 1, extra + 1
                    return k
        quote = text[i]
        j = i + 1
        while j < len(text) and text[j] != quote and text[j] != "\n":
            j += 2 if quote == '"' and text[j] == "\\" else 1
        return j + 1

    def key(self, i: int) -> tuple[list[str], int]:
        """A dotted key starting at ``i``: its parts and the offset after it."""
        text, parts = self.text, []
        while True:
            i = self.space(i)
            if i < len(text) and text[i] in "\"'":
                end = self.string_end(i)
                try:
                    parts.append(str(tomllib.loads(f"k = {text[i:end]}")["k"]))
                except tomllib.TOMLDecodeError:
                    parts.append(text[i + 1 : end - 1])
                i = end
            else:
                m = _BARE_KEY.match(text, i)
                if m is None:
                    return parts, i
                parts.append(m.group())
                i = m.end()
            i = self.space(i)
            if i < len(text) and text[i] == ".":
                i += 1
                continue
            return parts, i

    def value(self, i: int, loc: Loc) -> int:
        """Note the entries of the value at ``i`` (at ``loc``); the offset after it."""
        text, n = self.text, len(self.text)
        if i >= n:
            return i
        c = text[i]
        if c in "\"'":
            return self.string_end(i)
        if c == "[":
            i, index = i + 1, 0
            while True:
                i = self.space(i, newlines=True)
                if i >= n or text[i] == "]":
                    return i + 1
                self.note((*loc, index), i)
                i = self.space(self.value(i, (*loc, index)), newlines=True)
                if i < n and text[i] == ",":
                    i += 1
                    index += 1
                elif i >= n or text[i] != "]":
                    return n
        if c == "{":
            i += 1
            while True:
                i = self.space(i, newlines=True)
                if i >= n or text[i] == "}":
                    return i + 1
                parts, i = self.key(i)
                if not parts:
                    return n
                start = i
                for k in range(1, len(parts) + 1):
                    self.note((*loc, *parts[:k]), start)
                i = self.space(i)
                if i < n and text[i] == "=":
                    i = self.space(i + 1)
                i = self.space(self.value(i, (*loc, *parts)), newlines=True)
                if i < n and text[i] == ",":
                    i += 1
                elif i >= n or text[i] != "}":
                    return n
        return _TOML_SCALAR.match(text, i).end()  # type: ignore[union-attr]

    def header(self, i: int) -> tuple[Loc, int]:
        """A ``[table]`` or ``[[array]]`` header at ``i``: the table's path, the offset."""
        text = self.text
        many = text.startswith("[[", i)
        parts, j = self.key(i + (2 if many else 1))
        resolved: Loc = ()
        for k, part in enumerate(parts):
            resolved = (*resolved, part)
            last = k == len(parts) - 1
            if not last and resolved in self.arrays:  # a table in the array's last element
                resolved = (*resolved, self.arrays[resolved])
            self.note(resolved, i)
        if many:
            index = self.arrays.get(resolved, -1) + 1
            self.arrays[resolved] = index
            resolved = (*resolved, index)
            self.note(resolved, i)
        j = self.space(j)
        return resolved, j + (2 if many else 1)

    def scan(self) -> dict[Loc, int]:
        text, n = self.text, len(self.text)
        table: Loc = ()
        i = 0
        while i < n:
            i = self.space(i, newlines=True)
            if i >= n:
                break
            if text[i] == "[":
                table, i = self.header(i)
                continue
            start = i
            parts, i = self.key(i)
            if not parts:  # not a key: skip the line
                end = text.find("\n", i)
                i = n if end < 0 else end
                continue
            for k in range(1, len(parts) + 1):
                self.note((*table, *parts[:k]), start)
            i = self.space(i)
            if i < n and text[i] == "=":
                i = self.space(i + 1)
            i = self.value(i, (*table, *parts))
        return self.out


def _escaped(text: str, at: int) -> bool:
    """Whether the character at ``at`` is escaped by an odd run of backslashes."""
    run = 0
    while at - run - 1 >= 0 and text[at - run - 1] == "\\":
        run += 1
    return run % 2 == 1


def toml_lines(text: str) -> dict[Loc, int]:
    """The line of every key, table, array-of-tables element and array element of a TOML
    text that :mod:`tomllib` has parsed."""
    return _TomlScanner(text).scan()
