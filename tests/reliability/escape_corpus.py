"""Hostile text by class: what a name, a label or a message may hold to act on a terminal.

:func:`hostile_texts` yields one ``(label, text)`` per class — C0 and C1 controls, CSI,
OSC (a title, a hyperlink, the clipboard), DCS, the bidirectional controls, zero-width and
other format characters, the line separators, lone surrogates (what a name of bytes that
are not UTF-8 decodes to), private-use and unassigned code points, a very long name — each
inside a plausible name. :func:`unsafe_in` says what of such text reached an output.
"""

from __future__ import annotations

from collections.abc import Iterator

#: Every bidirectional control: embeddings, overrides, isolates, the marks.
BIDI = "\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069\u200e\u200f\u061c"

#: Length of the very long name, characters (an argument may be up to 128 KiB on Linux).
LONG = 100_000


def hostile_texts(base: str = "desk") -> Iterator[tuple[str, str]]:
    """``(label, text)`` for each class of hostile text, the text a name beginning with
    ``base``."""
    yield "c0", f"{base}\x00\x01\x07\x08\x0b\x0c\x0e\x1f"
    yield "tab-newline-return", f"{base}\tx\ny\rlegws: error: fake"
    yield "del", f"{base}\x7f\x7f"
    yield "c1", f"{base}\x80\x85\x8d\x90\x9b2J\x9d0;x\x9c\x9f"
    yield "csi", f"{base}\x1b[2J\x1b[1;1H\x1b[31mred\x1b[0m\x1b[?25l"
    yield "osc-title", f"{base}\x1b]0;owned\x07"
    yield "osc-hyperlink", f"{base}\x1b]8;;https://example.invalid/\x1b\\link\x1b]8;;\x1b\\"
    yield "osc-clipboard", f"{base}\x1b]52;c;ZWNobyBvd25lZA==\x07"
    yield "dcs", f"{base}\x1bP+q544e\x1b\\\x1bPtmux;\x1b\x1b[2J\x1b\\"
    yield "bidi", f"{base}{BIDI}txt.exe"
    yield "zero-width", f"{base}\u200b\u200c\u200d\u2060\ufeff\u00ad"
    yield "line-separators", f"{base}\u2028x\u2029y\x85z"
    yield "tags", f"{base}\U000e0001\U000e0041\U000e007f"
    yield "surrogates", f"{base}\udcff\udc80\ud800"
    yield "unassigned-private", f"{base}\u0378\U0010fffe\ue000\U000f0000"
    yield "very-long", base + ("\x1b]0;x\x07\u202e" + "a" * 90) * (LONG // 100)


def as_argument(text: str) -> str:
    """``text`` as a process's argument can hold it: without NUL (an argument ends there)
    and with only the surrogates that bytes which are not UTF-8 decode to (U+DC80 to U+DCFF,
    Python's ``surrogateescape``)."""
    return "".join(
        c
        for c in text
        if c != "\x00" and not ("\ud800" <= c < "\udc80" or "\udd00" <= c <= "\udfff")
    )


def unsafe_in(text: str) -> list[str]:
    """The characters of ``text`` no terminal should get (as ``U+XXXX``), each once, in
    order: those :func:`str.isprintable` refuses, but the line breaks between lines; and
    U+FFFD, which an output read back with ``errors="replace"`` holds where it had bytes
    that are not UTF-8 (a surrogate written as it was)."""
    seen: list[str] = []
    for char in text:
        if (char != "\n" and not char.isprintable()) or char == "\ufffd":
            code = f"U+{ord(char):04X}"
            if code not in seen:
                seen.append(code)
    return seen
