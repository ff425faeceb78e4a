"""Participants are pseudonyms: names and e-mail addresses are refused, and not echoed."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.study.pseudonym import check_pseudonym, what_it_looks_like


@pytest.mark.parametrize("ok", ["P01", "P07", "S012", "PX0031", "ABCD9999"])
def test_pseudonyms_pass(ok: str) -> None:
    assert check_pseudonym(ok) == ok


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("alice", "looks like a name"),
        ("Alice Smith", "looks like a name"),
        ("Smith1", "looks like a name"),
        ("jane.doe@example.org", "looks like an e-mail address"),
        ("P07@lab", "looks like an e-mail address"),
        ("p07", "is not a pseudonym"),
        ("", "is not a pseudonym"),
        ("P07\nrm -rf", "is not a pseudonym"),
    ],
)
def test_anything_else_is_refused_with_what_it_looks_like(text: str, why: str) -> None:
    assert what_it_looks_like(text) == why
    with pytest.raises(InputError) as err:
        check_pseudonym(text)
    message = str(err.value)
    assert message.startswith(f"--participant: {why}") and "\n" not in message
    if len(text) > 3:
        assert text not in message  # a real name never reaches a log line


@given(st.from_regex(r"[A-Za-z]{2,12}( [A-Za-z]{2,12})?", fullmatch=True))
def test_no_word_of_letters_alone_is_a_pseudonym(text: str) -> None:
    assert what_it_looks_like(text) is not None


@given(st.emails())
def test_no_email_address_is_a_pseudonym(text: str) -> None:
    assert what_it_looks_like(text) == "looks like an e-mail address"
