"""Nesting measured before parsing (:mod:`legws_daemon.formats.nesting`)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.formats.nesting import (
    MAX_DEPTH,
    _deepest,
    check_json_nesting,
    check_toml_nesting,
)
from legws_daemon.formats.validation import parse_json, parse_toml
from tests.formats.helpers import toml_dumps

REPO = Path(__file__).parents[2]

# strings that look like structure: brackets, quotes, escapes, comment signs, dots
tricky_text = st.text(alphabet="[]{}\"\\#.'a \n", max_size=12)
leaves = st.one_of(st.integers(), st.floats(allow_nan=False), tricky_text, st.booleans())


def depth_of(value: Any) -> int:
    if isinstance(value, dict):
        return 1 + max((depth_of(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return 1 + max((depth_of(v) for v in value), default=0)
    return 0


def nested(depth: int, inner: Any, kind: str) -> Any:
    for _ in range(depth):
        inner = [inner] if kind == "list" else {"k": inner}
    return inner


documents = st.recursive(
    leaves,
    lambda children: st.one_of(
        st.lists(children, max_size=3),
        st.dictionaries(tricky_text, children, max_size=3),
    ),
    max_leaves=20,
)


@given(documents, st.integers(0, 80), st.sampled_from(["list", "dict"]))
def test_the_depth_of_json_is_measured_exactly_whatever_its_strings_hold(
    doc: Any, extra: int, kind: str
) -> None:
    value = nested(extra, doc, kind)
    text = json.dumps(value, indent=1)
    assert _deepest_json(text) == depth_of(value)
    if depth_of(value) > MAX_DEPTH:
        with pytest.raises(InputError, match=f"nested {depth_of(value)} levels deep"):
            check_json_nesting(text, "f.json")
    else:
        check_json_nesting(text, "f.json")
        assert parse_json(text, "f.json", None) == value or "\\" in text


def _deepest_json(text: str) -> int:
    from legws_daemon.formats.nesting import _JSON_STRING

    return _deepest(_JSON_STRING.sub("s", text))[0]


@given(st.dictionaries(tricky_text.filter(bool), documents, max_size=4), st.integers(0, 70))
def test_toml_of_any_strings_nests_as_deep_as_its_arrays(doc: dict[str, Any], extra: int) -> None:
    doc = {k: v for k, v in doc.items() if not isinstance(v, list) or v}
    doc["deep"] = nested(extra, 1, "list")
    text = toml_dumps(doc)
    if extra > MAX_DEPTH:
        with pytest.raises(InputError, match="levels deep"):
            check_toml_nesting(text, "f.toml")
    else:
        check_toml_nesting(text, "f.toml")  # strings and comments never count


def test_the_line_of_the_deepest_point_is_named() -> None:
    text = '{\n"a": "[[[[",\n"b":\n' + "[" * 70 + "]" * 70 + "\n}"
    with pytest.raises(InputError, match="71 levels deep at line 4"):
        check_json_nesting(text, "f.json")


@pytest.mark.parametrize(
    ("text", "parts"),
    [
        ("a" + ".a" * 32 + " = 1", 33),
        ("[" + ".".join(["t"] * 40) + "]\nx = 1", 40),
        ("[[" + ".".join(["t"] * 40) + "]]\nx = 1", 40),
        (".".join(['"q.q"'] * 33) + " = 1", 33),  # quoted parts count once each
        ("x = {" + ".".join(["k"] * 50) + " = 1}", 50),
        ("a . " * 35 + "a = 1", 36),  # spaces around the dots
    ],
)
def test_long_key_paths_are_refused_with_their_length(text: str, parts: int) -> None:
    with pytest.raises(InputError, match=f"a key path of {parts} parts at line"):
        check_toml_nesting(text, "f.toml")


@pytest.mark.parametrize(
    "text",
    [
        "a" + ".a" * 31 + " = 1",  # 32 parts: the most accepted
        "x = 1.5\ny = [1.5, 2.5e3, -0.25]\nwhen = 1979-05-27T07:32:00.999999Z",
        'k = "' + ".".join(["a"] * 100) + '"',  # dots in a string
        "k = '" + ".".join(["a"] * 100) + "'",
        'k = """\n' + ".".join(["a"] * 100) + '\n"""',
        "# " + ".".join(["a"] * 100) + "\nk = 1",  # and in a comment
    ],
)
def test_what_is_no_long_key_path_passes(text: str) -> None:
    check_toml_nesting(text, "f.toml")
    tomllib.loads(text)


def test_every_shipped_file_passes() -> None:
    files = [*REPO.glob("scenes/*.toml"), *REPO.glob("taskgraphs/*.toml"),
             *REPO.glob("hw_profiles/**/*.toml"), *REPO.glob("studies/*.toml")]  # fmt: skip
    assert len(files) > 10
    for path in files:
        parse_toml(path.read_text(), str(path))


@pytest.mark.parametrize(
    "text",
    [
        '"' + '\\"' * 50_000,  # an unterminated string of escaped quotes
        '"""' * 30_001,  # unterminated multi-line strings
        "'''" * 30_001,
        "a" * 200_000,
        ("a." * 20 + "\n") * 5_000,  # many key paths just under the bound
    ],
)
def test_pathological_texts_scan_without_blowing_up(text: str) -> None:
    # each pattern matches wherever it starts, so a scan is linear: these finish at once
    # (a quadratic scan of them takes minutes); whatever they are, the answer is a line
    for check in (check_toml_nesting, check_json_nesting):
        message = ""
        try:
            check(text, "f")
        except InputError as err:
            message = str(err)
        assert "\n" not in message
