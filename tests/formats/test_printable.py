"""Terminal-safe text (:mod:`legws_daemon.formats.printable`) and the sinks that use it:
the error line, the terminal log, zenoh's Python log, the client's refusals."""

from __future__ import annotations

import ast
import io
import logging
import sys
import time
import unicodedata
from collections.abc import Iterator

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.client.client import CommandRefusedError, Reply, _reply_detail
from legws_daemon.errors import InputError
from legws_daemon.formats.printable import (
    ELLIPSIS,
    LIMIT,
    MESSAGE_LIMIT,
    escape,
    guard_last_resort,
    is_safe,
    safe_lines,
    safe_text,
    unsafe,
)
from legws_daemon.formats.validation import ManyInputsError, error_lines
from legws_daemon.telemetry.terminal_log import LOGGERS, log_to_terminal
from legws_daemon.transport.session import ZENOH_LOGGER, route_zenoh_log
from tests.reliability.escape_corpus import BIDI, hostile_texts, unsafe_in

#: The categories no terminal gets as they are: controls, format characters (the
#: bidirectional controls, zero-width ones), surrogates, private use, unassigned, the line
#: and paragraph separators, and the spaces but U+0020.
UNSAFE_CATEGORIES = {"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp", "Zs"}


def refused(char: str) -> bool:
    """What must never come out, by the classes themselves (not by ``isprintable``)."""
    code = ord(char)
    return (
        code < 0x20
        or 0x7F <= code <= 0x9F
        or char in BIDI
        or char in "\u2028\u2029\u200b\u200c\u200d\u2060\ufeff"
        or (unicodedata.category(char) in UNSAFE_CATEGORIES and char != " ")
    )


#: Every code point, surrogates included, and the classes drawn often.
SPECIAL = [chr(c) for c in range(0x20)] + [chr(c) for c in range(0x7F, 0xA0)]
SPECIAL += [*BIDI, "\u2028", "\u2029", "\u200b", "\u200d", "\ufeff", "\udcff", "\ud800"]
SPECIAL += ["\U000e0001", "\u0378", "\ue000", "\\", "…", "é", "漢", "\u0301", " "]
ANY_CHAR = st.one_of(st.characters(exclude_categories=()), st.sampled_from(SPECIAL))
ANY_TEXT = st.text(ANY_CHAR, max_size=300)
LIMITS = st.one_of(st.none(), st.integers(1, 400))
PRINTABLE = st.text(
    st.characters(exclude_categories=("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp", "Zs"))
    | st.just(" ")
)


@given(ANY_TEXT, LIMITS)
def test_nothing_unsafe_comes_out_and_the_bound_holds(text: str, limit: int | None) -> None:
    out = safe_text(text, limit)
    assert not [c for c in out if refused(c)], repr(out)
    assert is_safe(out)
    if limit is not None:
        assert len(out) <= limit


@given(ANY_TEXT, LIMITS)
def test_made_safe_twice_reads_the_same(text: str, limit: int | None) -> None:
    once = safe_text(text, limit)
    assert safe_text(once, limit) == once
    lines = safe_lines(text, limit)
    assert safe_lines(lines, limit) == lines


@given(PRINTABLE, LIMITS)
def test_printable_text_within_the_bound_passes_unchanged(text: str, limit: int | None) -> None:
    if limit is None or len(text) <= limit:
        assert safe_text(text, limit) is text
        assert safe_lines(text, limit) == text


@given(st.text(st.sampled_from(SPECIAL + list("ab \u00e9")), max_size=200))
def test_the_escapes_are_what_python_reads_back(text: str) -> None:
    # uncut and without backslashes or quotes of its own, the safe text is a Python string
    # literal of the original: each escape says exactly which character stood there
    if "\\" in text or '"' in text:
        return
    out = safe_text(text, None)
    assert ast.literal_eval(f'"{out}"') == text


@given(ANY_TEXT, st.integers(1, 400))
def test_a_cut_text_is_the_start_of_the_whole_and_ends_with_the_ellipsis(
    text: str, limit: int
) -> None:
    whole = safe_text(text, None)
    out = safe_text(text, limit)
    if len(whole) <= limit:
        assert out == whole
    else:
        assert out.endswith(ELLIPSIS)
        assert whole.startswith(out[: -len(ELLIPSIS)])
        assert len(out) > limit - 10  # cut at the bound, not far before (an escape is <= 10)


@given(st.lists(ANY_TEXT, max_size=6))
def test_lines_stay_lines_each_made_safe(lines: list[str]) -> None:
    text = "\n".join(lines)
    out = safe_lines(text)
    assert out.split("\n") == [safe_text(line) for line in text.split("\n")]
    assert not unsafe_in(out.replace("\ufffd", ""))


@pytest.mark.parametrize(("label", "text"), list(hostile_texts()))
def test_each_class_of_hostile_text_is_made_visible(label: str, text: str) -> None:
    out = safe_text(text)
    assert out.startswith("desk"), label
    assert not [c for c in out if refused(c)], (label, out)
    assert "\\" in out, label  # something was escaped, visibly
    assert len(out) <= LIMIT


def test_the_escapes_by_example() -> None:
    assert safe_text("desk\x1b]0;x\x07") == "desk\\x1b]0;x\\x07"
    assert safe_text("a\tb\nc\rd") == "a\\tb\\nc\\rd"
    assert safe_text("\x9b2J\x7f") == "\\x9b2J\\x7f"
    assert safe_text("abc\u202etxt.exe") == "abc\\u202etxt.exe"
    assert safe_text("x\u2028y\u200d") == "x\\u2028y\\u200d"
    assert safe_text("\udcff\ud800") == "\\udcff\\ud800"
    assert safe_text("tag\U000e0041") == "tag\\U000e0041"
    assert safe_text("a\u00a0b") == "a\\xa0b"  # a space that is not one
    assert safe_text("white_mug · é 漢 ✓") == "white_mug · é 漢 ✓"
    assert escape("\x00") == "\\x00" and unsafe("\x1b") and not unsafe("a")
    assert safe_lines("a\x1b[2J\nb\u202e\n") == "a\\x1b[2J\nb\\u202e\n"


def test_a_cut_never_splits_an_escape() -> None:
    assert safe_text("ab\x1bcd", 5) == "ab…"  # "ab\x1b" would be 6: the escape goes whole
    assert safe_text("abcdef", 4) == "abc…"
    assert safe_text("abcd", 4) == "abcd"
    assert safe_text("\x1b", 1) == "…"
    with pytest.raises(ValueError, match="at least 1"):
        safe_text("a", 0)


def test_a_huge_text_costs_what_its_bound_does() -> None:
    huge = "\x1b[2J" * 2_500_000  # 10 million characters
    t0 = time.perf_counter()
    out = safe_text(huge)
    assert time.perf_counter() - t0 < 0.1
    assert len(out) <= LIMIT and out.endswith(ELLIPSIS)


# --- the sinks ------------------------------------------------------------------------------


def test_an_input_error_is_one_safe_line_naming_source_and_field() -> None:
    err = InputError("unknown scene 'desk\x1b]0;x\x07'", source="a\u202eb.toml", field="x\ny")
    assert str(err) == "a\\u202eb.toml: x\\ny: unknown scene 'desk\\x1b]0;x\\x07'"
    assert err.source == "a\\u202eb.toml" and err.field == "x\\ny"
    # what the validators strip off an error's text is what it starts with
    assert str(err).startswith(f"{err.source}: {err.field}: ")
    long = InputError("x" * 100_000, source="s" * 100_000)
    assert len(str(long)) <= LIMIT + 2 + MESSAGE_LIMIT
    assert str(InputError("plain", source="desk.toml", field="name")) == ("desk.toml: name: plain")


def test_every_error_of_a_file_stays_safe() -> None:
    errors = [InputError(f"bad\x1b[{i}m", source="f\x07.toml", field=f"k{i}") for i in range(3)]
    many = ManyInputsError(errors)
    assert all(is_safe(line) for line in error_lines(many))
    assert is_safe(str(many))


@pytest.fixture
def _restore_loggers() -> Iterator[None]:
    names = (*LOGGERS, ZENOH_LOGGER)
    saved = {
        n: (list(logging.getLogger(n).handlers), logging.getLogger(n).level,
            logging.getLogger(n).propagate)
        for n in names
    }  # fmt: skip
    yield
    for name, (handlers, level, propagate) in saved.items():
        logger = logging.getLogger(name)
        logger.handlers[:] = handlers
        logger.setLevel(level)
        logger.propagate = propagate


@pytest.mark.usefixtures("_restore_loggers")
def test_the_terminal_log_prints_one_safe_line_per_record(monkeypatch: pytest.MonkeyPatch) -> None:
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    log_to_terminal("legws daemon")
    log = logging.getLogger("legws.daemon")
    log.info("operator %s took the lease", "evil\x1b]0;owned\x07\u202e\nlegws daemon: fake")
    try:
        raise ValueError("boom \x1b[2J")
    except ValueError:
        log.exception("listener failed on %s", "commit\u2028")
    lines = err.getvalue().split("\n")
    assert lines[0] == (
        "legws daemon: operator evil\\x1b]0;owned\\x07\\u202e\\nlegws daemon: fake took the lease"
    )
    assert lines[1] == "legws daemon: listener failed on commit\\u2028"
    assert lines[2] == "Traceback (most recent call last):"
    assert "ValueError: boom \\x1b[2J" in lines
    assert not unsafe_in(err.getvalue())


@pytest.mark.usefixtures("_restore_loggers")
def test_zenoh_python_log_is_one_safe_line_of_legws(monkeypatch: pytest.MonkeyPatch) -> None:
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    log_to_terminal("legws daemon")
    route_zenoh_log()
    route_zenoh_log()  # idempotent: one handler
    try:
        raise RuntimeError("payload \x1b]52;c;eA==\x07\nsecond line")
    except RuntimeError:
        logging.getLogger("zenoh.handlers").exception("callback error")
    assert err.getvalue() == (
        "legws daemon: zenoh: callback error: RuntimeError: payload \\x1b]52;c;eA==\\x07\n"
    )
    assert not logging.getLogger(ZENOH_LOGGER).propagate


def test_a_record_no_handler_takes_is_printed_safe(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(logging, "lastResort", logging.lastResort)  # put back afterwards
    guard_last_resort()
    guard_last_resort()
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    lone = logging.getLogger("tests.formats.no_handler")
    monkeypatch.setattr(lone, "propagate", False)  # (pytest's own handlers sit on the root)
    lone.warning("legws: warning: the cached plan in %s is not usable", "p\x1b]0;x\x07\u202e")
    lone.info("below WARNING: not shown")
    assert err.getvalue() == (
        "legws: warning: the cached plan in p\\x1b]0;x\\x07\\u202e is not usable\n"
    )


def test_a_refusal_from_a_hostile_daemon_is_safe() -> None:
    reply = Reply("load_scene", False, {}, "no such scene '\x1b[2J\u202e'")
    assert str(CommandRefusedError(reply)) == (
        "load_scene: refused: no such scene '\\x1b[2J\\u202e'"
    )
    assert _reply_detail(None, "k") == {}
    assert _reply_detail(zenoh.ZBytes(b'{"ok": true}'), "k") == {"ok": True}
    assert _reply_detail(zenoh.ZBytes(b"[1]"), "k")["ok"] is False
    assert _reply_detail(zenoh.ZBytes(b"\xff\x1b"), "k")["ok"] is False
