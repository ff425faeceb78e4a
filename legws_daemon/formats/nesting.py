"""How deep a structured text nests, measured before a parser sees it.

Python's parsers recurse: ``json`` with its own limit (~1000 levels, close to the
interpreter's), ``tomllib`` without one for arrays and inline tables, and every walk over
the parsed document (the non-finite check, the control-character check, pydantic, the
``repr`` of an error's value) recurses again. A dotted key or table header of many parts
(``[a.a.a.…]``) nests as deep as it has parts, and ``tomllib`` builds such a key in time
quadratic in its parts (100,000 parts in 200 KB: gigabytes in seconds).

So the text is scanned first, linearly, with its strings and comments blanked out:

- **depth**: the deepest nesting of ``[``/``{`` brackets (JSON's arrays and objects,
  TOML's arrays and inline tables) is at most :data:`MAX_DEPTH`;
- **key paths** (TOML): a dotted key or table header has at most :data:`MAX_KEY_PARTS`
  parts.

Both are far above any real file (a scene nests 4 levels, a plan 7; the longest key path
in the shipped files has 3 parts) and far below where anything recurses into trouble.
A text over either is refused in one line naming the line it happens on.
"""

from __future__ import annotations

import re

import numpy as np

from legws_daemon.errors import InputError

#: Deepest bracket nesting accepted (JSON arrays/objects, TOML arrays/inline tables).
MAX_DEPTH = 64
#: Most parts of a TOML dotted key or table header (``a.b.c``: 3).
MAX_KEY_PARTS = 32

# A JSON string; an unterminated one ends at the line's end (the parser reports it). Every
# pattern here matches wherever it starts (it never fails after a scan), so a search over
# the text is linear in its length whatever it holds.
_JSON_STRING = re.compile(r'"(?:[^"\\\n]|\\[^\n])*(?:["\n\\]|$)')
# TOML: multi-line strings first, then one-line strings, then comments.
_TOML_BLANK = re.compile(
    r'"""(?:[^\\]|\\.?)*?(?:"""|\Z)|\'\'\'.*?(?:\'\'\'|\Z)'
    r'|"(?:[^"\\\n]|\\[^\n])*(?:["\n\\]|$)|\'[^\'\n]*(?:[\'\n]|$)|#[^\n]*',
    re.S,
)
# A bare or blanked key part, and the dots between parts (floats have one dot: 2 parts).
_KEY_PATH = re.compile(rf"(?<![\w-])[\w-]+(?:[ \t]*\.[ \t]*[\w-]+){{{MAX_KEY_PARTS},}}")

_OPEN = np.zeros(256, dtype=np.int8)
for _c in b"[{":
    _OPEN[_c] = 1
for _c in b"]}":
    _OPEN[_c] = -1


def _blank(match: re.Match[str]) -> str:
    # a string becomes one word character (a key part still counts); newlines stay, so
    # line numbers stay right
    text = match.group()
    if text.startswith("#"):
        return ""
    return "s" + "\n" * text.count("\n")


def _line_of(text: str, index: int) -> int:
    return text.count("\n", 0, index) + 1


def _deepest(text: str) -> tuple[int, int]:
    """The deepest bracket nesting of ``text`` and the index where it is first reached."""
    raw = np.frombuffer(text.encode("utf-8", errors="surrogatepass"), dtype=np.uint8)
    if raw.size == 0:
        return 0, 0
    steps = _OPEN[raw]
    if not steps.any():
        return 0, 0
    depth = np.cumsum(steps, dtype=np.int64)
    where = int(np.argmax(depth))
    byte_prefix = raw[:where].tobytes().decode("utf-8", errors="ignore")
    return int(depth[where]), len(byte_prefix)


def _too_deep(text: str, source: str, what: str) -> None:
    depth, at = _deepest(text)
    if depth > MAX_DEPTH:
        raise InputError(
            f"invalid {what}: nested {depth} levels deep at line {_line_of(text, at)}; "
            f"at most {MAX_DEPTH} are accepted",
            source=source,
        )


def check_json_nesting(text: str, source: str) -> None:
    """Refuse JSON text nested deeper than :data:`MAX_DEPTH` (one line naming ``source``
    and the line)."""
    if text.count("[") + text.count("{") > MAX_DEPTH:  # else it cannot nest deeper
        _too_deep(_JSON_STRING.sub("s", text), source, "JSON")


def check_toml_nesting(text: str, source: str) -> None:
    """Refuse TOML text nested deeper than :data:`MAX_DEPTH` brackets or holding a key
    path of more than :data:`MAX_KEY_PARTS` parts (one line naming ``source`` and the
    line)."""
    if text.count(".") < MAX_KEY_PARTS and text.count("[") + text.count("{") <= MAX_DEPTH:
        return  # too few dots for a long key path, too few brackets to nest deep
    bare = _TOML_BLANK.sub(_blank, text)
    long_key = _KEY_PATH.search(bare)
    if long_key is not None:
        parts = long_key.group().count(".") + 1
        raise InputError(
            f"invalid TOML: a key path of {parts} parts at line "
            f"{_line_of(bare, long_key.start())}; at most {MAX_KEY_PARTS} are accepted",
            source=source,
        )
    _too_deep(bare, source, "TOML")
