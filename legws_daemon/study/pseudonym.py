"""Participant identifiers: pseudonyms only.

A study's files are published; a participant's real name or e-mail address must never get
into them. An identifier is a pseudonym when it is one to four capital letters and one to
four digits (``P07``, ``S012``, ``PX0031``), which no name or address is. Anything else
is refused with one line saying what it looks like.
"""

from __future__ import annotations

import re

from legws_daemon.errors import InputError
from legws_daemon.formats.printable import safe_text

PSEUDONYM = re.compile(r"^[A-Z]{1,4}[0-9]{1,4}$")
_EMAIL = re.compile(r"@|\bmailto:", re.IGNORECASE)
_WORDS = re.compile(r"[A-Za-z]{2,}")


def what_it_looks_like(text: str) -> str | None:
    """Why ``text`` is not a pseudonym (``None``: it is one)."""
    if PSEUDONYM.match(text):
        return None
    if _EMAIL.search(text):
        return "looks like an e-mail address"
    if _WORDS.search(text) and not any(ch.isdigit() for ch in text):
        return "looks like a name"
    if _WORDS.search(text) and len(_WORDS.findall(text)[0]) > 4:
        return "looks like a name"
    return "is not a pseudonym"


def check_pseudonym(text: str, field: str = "--participant") -> str:
    """``text`` if it is a pseudonym; else an :class:`InputError` (the text itself is not
    repeated: it may be a person's name, and error lines go to logs)."""
    why = what_it_looks_like(text)
    if why is None:
        return text
    raise InputError(
        f"{why}; participants are identified by pseudonyms only: 1-4 capital letters "
        f"and 1-4 digits, e.g. P07 (got {len(safe_text(text, 200))} characters)",
        field=field,
    )
