"""Session keys: a keyed session's messages count only with its tag; the table is bounded,
keys each session once and never one that holds the lease or was heard without a key."""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.daemon.inbox import JoystickInbox
from legws_daemon.daemon.service import answer_hello
from legws_daemon.daemon.session_keys import MAX_KEYS, SessionKeys
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import (
    HelloRequest,
    JoystickMessage,
    auth_tag,
    canonical_bytes,
    dump,
    parse,
    parse_request,
    public_session_id,
    tag_matches,
)


def message(sid: str, seq: int, axes: tuple[float, float, float] = (0.1, 0.0, 0.0),
            **extra: Any) -> JoystickMessage:  # fmt: skip
    data = {"schema": 1, "seq": seq, "stamp": 10.0 + seq, "axes": list(axes),
            "source": f"pub-{sid}", "session": sid, **extra}  # fmt: skip
    return JoystickMessage.model_validate(data)


def signed(key: bytes, m: JoystickMessage) -> bytes:
    return dump(m.model_copy(update={"auth": auth_tag(key, m)}))


def keyed(box: JoystickInbox, sid: str) -> bytes:
    key, public = box.hello(sid)
    assert public == public_session_id(sid)
    return key


# --- the table ---------------------------------------------------------------------------
def test_a_session_is_keyed_once_with_a_fresh_random_key() -> None:
    table = SessionKeys()
    a, b = table.issue("a", holder=None, heard=False), table.issue("b", holder=None, heard=False)
    assert len(a) == len(b) == 32 and a != b
    assert table.key("a") == a and table.key("nobody") is None
    with pytest.raises(InputError, match="has a key already"):
        table.issue("a", holder=None, heard=False)
    assert table.key("a") == a  # unchanged
    with pytest.raises(InputError, match="holds the operator lease"):
        table.issue("h", holder="h", heard=False)
    with pytest.raises(InputError, match="heard from without a key"):
        table.issue("old", holder=None, heard=True)
    table.mark_unknown("restarted")
    with pytest.raises(InputError, match="no key for"):
        table.issue("restarted", holder=None, heard=False)
    # the refusal names the session by its public id, never by its id
    with pytest.raises(InputError) as info:
        table.issue("a", holder=None, heard=False)
    assert public_session_id("a") in str(info.value) and "'a'" not in str(info.value)


def test_the_table_is_bounded_and_never_forgets_the_holder() -> None:
    table = SessionKeys()
    holder = table.issue("holder", holder=None, heard=False)
    for i in range(3 * MAX_KEYS):
        table.issue(f"s{i}", holder="holder", heard=False)
        assert len(table) <= MAX_KEYS
    assert table.key("holder") == holder
    assert table.sessions()[-1] == f"s{3 * MAX_KEYS - 1}"
    assert table.key("s0") is None  # the oldest went first
    assert table.evicted == 2 * MAX_KEYS + 1 and table.issued == 3 * MAX_KEYS + 1


# --- the tag -------------------------------------------------------------------------------
def test_the_canonical_bytes_do_not_depend_on_how_the_json_was_written() -> None:
    a = parse(JoystickMessage, b'{"schema":1,"seq":3,"stamp":0,"axes":[0,1,0],"session":"s"}', "t")
    b = parse(
        JoystickMessage,
        b'{"session": "s", "buttons": {"enable": null}, "axes": [0.0, 1.0, 0.0], '
        b'"bye": false, "source": "unknown", "stamp": 0.0, "seq": 3, "schema": 1}',
        "t",
    )
    assert canonical_bytes(a) == canonical_bytes(b)
    assert b"auth" not in canonical_bytes(a.model_copy(update={"auth": "0" * 32}))
    assert canonical_bytes(a).startswith(b'{"axes":[0.0,1.0,0.0],"buttons":{')


#: every field of a joystick message (but auth), and a way to change it
CHANGES: dict[str, st.SearchStrategy[Any]] = {
    "seq": st.integers(0, 2**63 - 1),
    "stamp": st.floats(-1e12, 1e12, allow_nan=False),
    "axes": st.tuples(*[st.floats(-0.5, 0.5, allow_nan=False)] * 3),
    "buttons": st.fixed_dictionaries(
        {"cancel": st.booleans(), "confirm": st.booleans(), "enable": st.none() | st.booleans()}
    ),
    "source": st.text(st.characters(min_codepoint=32, max_codepoint=126), min_size=1, max_size=64),
    "session": st.from_regex(r"[A-Za-z0-9_.:-]{1,64}", fullmatch=True),
    "bye": st.booleans(),
}


@settings(max_examples=300, deadline=None)
@given(
    st.binary(min_size=32, max_size=32),
    st.fixed_dictionaries(CHANGES),
    st.sampled_from(sorted(CHANGES)),
    st.data(),
)
def test_any_change_of_any_field_breaks_the_tag(
    key: bytes, fields: dict[str, Any], changed: str, data: st.DataObject
) -> None:
    original = JoystickMessage.model_validate({"schema": 1, **fields})
    tag = auth_tag(key, original)
    assert len(tag) == 32 and tag_matches(key, original.model_copy(update={"auth": tag}))
    value = data.draw(CHANGES[changed].filter(lambda v: v != fields[changed]), label=changed)
    forged = JoystickMessage.model_validate({"schema": 1, **fields, changed: value, "auth": tag})
    if forged.model_dump(exclude={"auth"}) == original.model_dump(exclude={"auth"}):
        return  # (the same message written another way, e.g. -0.0 for 0.0)
    assert not tag_matches(key, forged)
    # and the right fields under another key
    other = bytes(b ^ 1 for b in key)
    assert not tag_matches(other, original.model_copy(update={"auth": tag}))


# --- the inbox -----------------------------------------------------------------------------
def test_a_keyed_session_counts_only_with_its_tag_and_a_forgery_changes_nothing() -> None:
    box = JoystickInbox(timeout=0.25, grace=0.5)
    key = keyed(box, "op")
    assert box.offer(signed(key, message("op", 0)), now=0.0) is not None
    assert box.operator() == {"source": "pub-op", "session": public_session_id("op")}
    # copies of its id: no tag, a copied tag on other content, another key's tag
    fast = message("op", 10**18, axes=(0.0, 1.0, 0.0))
    assert box.offer(dump(fast), now=0.01) is None
    copied = signed(key, message("op", 0)).replace(b'"seq":0', b'"seq":1000000')
    assert box.offer(copied, now=0.02) is None
    assert box.offer(signed(b"x" * 32, fast), now=0.03) is None
    assert box.counts()["auth"] == 3
    # none of them moved its seq on, nor the sample: the operator's next message counts
    s = box.latest(0.04)
    assert s is not None and s.message.seq == 0
    assert box.offer(signed(key, message("op", 1)), now=0.05) is not None
    # an exact replay of its message is stale, tag and all
    assert box.offer(signed(key, message("op", 1)), now=0.06) is None
    assert box.counts() == {"invalid": 0, "auth": 3, "stale_seq": 1, "not_operator": 0}
    report = box.take_report()
    assert report.rejections["auth"].count == 3
    assert report.rejections["auth"].session == public_session_id("op")
    assert report.rejections["auth"].error == "wrong tag"


def test_a_copy_of_a_keyed_holder_neither_steers_nor_takes_the_lease() -> None:
    """What the bench's red team did: copy the holder's session and send a higher seq."""
    box = JoystickInbox(timeout=0.25, grace=0.5)
    key = keyed(box, "op")
    now = 0.0
    for seq in range(100):
        now = 0.05 * seq
        mine = message("op", seq, axes=(0.0, 0.0, 0.0), buttons={"enable": True})
        assert box.offer(signed(key, mine), now) is not None
        copy = message("op", seq + 1000, axes=(0.0, 1.0, 0.0), buttons={"enable": True})
        assert box.offer(dump(copy), now + 0.01) is None
        sample, why = box.poll(now + 0.02)
        assert why is None and sample is not None and sample.message.axes == (0.0, 0.0, 0.0)
    assert box.counts()["auth"] == 100
    assert [c.reason for c in box.take_report().changes] == ["first_input"]


def test_hello_refuses_the_holder_a_heard_session_and_a_second_key() -> None:
    box = JoystickInbox()
    box.offer(message("legacy", 0).model_dump_json(by_alias=True).encode(), now=0.0)
    assert box.operator() == {"source": "pub-legacy", "session": public_session_id("legacy")}
    with pytest.raises(InputError, match="holds the operator lease"):
        box.hello("legacy")
    box.release(now=0.1)
    with pytest.raises(InputError, match="heard from without a key"):
        box.hello("legacy")
    # an unkeyed session goes on as before (a schema-1 sender without hello)
    assert box.offer(dump(message("legacy", 1)), now=0.2) is not None
    keyed(box, "new")
    with pytest.raises(InputError, match="has a key already"):
        box.hello("new")


def test_a_tag_the_daemon_gave_no_key_for_is_refused_and_burns_the_id() -> None:
    """A daemon restarted under a running publisher: its tagged messages and any untagged
    copy of its id are refused, and nobody can key that id here."""
    box = JoystickInbox()
    assert box.offer(signed(b"k" * 32, message("old", 7)), now=0.0) is None
    assert box.offer(dump(message("old", 8)), now=0.01) is None  # an untagged copy
    assert box.counts()["auth"] == 2
    with pytest.raises(InputError, match="gave no key"):
        box.hello("old")
    assert box.offer(dump(message("t", 0, auth="0" * 32, session=None)), now=0.02) is None
    assert box.counts()["auth"] == 3  # a tag without a session id


def test_take_control_names_a_session_by_id_or_by_public_id_heard_yet_or_not() -> None:
    box = JoystickInbox()
    key = keyed(box, "pub")
    public = public_session_id("pub")
    change = box.take_control(public, now=0.0)  # what status would show, before a message
    assert change is not None and change.operator is not None
    assert change.operator.session == "pub"
    assert box.operator() == {"source": "(not heard yet)", "session": public}
    assert box.offer(signed(key, message("pub", 0)), now=0.1) is not None
    box.offer(dump(message("x", 0)), now=0.11)
    assert box.take_control(public_session_id("x"), now=0.2) is not None
    assert box.operator() == {"source": "pub-x", "session": public_session_id("x")}
    assert box.take_control("pub", now=0.3) is not None
    assert box.operator() == {"source": "pub-pub", "session": public}


def test_a_stall_drops_the_input_and_keeps_the_lease_for_its_holder() -> None:
    box = JoystickInbox(timeout=0.25, grace=0.5)
    key = keyed(box, "op")
    other = keyed(box, "other")
    box.offer(signed(key, message("op", 0)), now=0.0)
    box.stalled(now=2.0)  # the lease does not change hands (the changes: below)
    assert box.poll(2.0) == (None, "no_input")  # what came before the pause is stale
    # another session that steers first after the pause is refused
    assert box.offer(signed(other, message("other", 0)), now=2.01) is None
    assert box.offer(signed(key, message("op", 1, axes=(0.0, 0.0, 0.0))), now=2.03) is not None
    assert box.poll(2.04)[0] is not None
    assert [c.reason for c in box.take_report().changes] == ["first_input"]


def test_a_message_long_after_the_last_poll_finds_the_daemon_stalled() -> None:
    """After a pause the transport may hand over a message before the loop's first tick:
    the holder's silence was the daemon's own, so it is a stall there too, never a timeout."""
    box = JoystickInbox(timeout=0.25, grace=0.5, stall_after=0.5)
    key = keyed(box, "op")
    box.poll(0.0)
    box.offer(signed(key, message("op", 0)), now=0.01)
    box.poll(0.02)
    box.offer(signed(key, message("op", 1)), now=0.45)  # 0.43 s: the loop only ran late
    assert box.operator() is not None
    assert box.offer(signed(key, message("op", 2)), now=2.0) is not None  # heard after it
    box.stalled(now=2.01)  # the loop sees it now: handled already (no change: below)
    assert box.poll(2.02) == (None, "no_input")  # its tick moves nothing
    assert box.offer(signed(key, message("op", 3)), now=2.03) is not None
    assert box.poll(2.04)[0] is not None
    reasons = [c.reason for c in box.take_report().changes]
    assert reasons == ["first_input"]  # the holder kept it through the pause


def test_the_hello_reply_carries_the_key_to_the_asker() -> None:
    box = JoystickInbox()
    request = parse_request(b'{"schema": 1, "command": "hello", "argument": "abc"}', "cmd")
    assert isinstance(request, HelloRequest)
    ok, body = answer_hello(box, request, 1234.5)
    reply = json.loads(body)
    assert ok and reply["ok"] and reply["command"] == "hello" and reply["started"] == 1234.5
    key = bytes.fromhex(reply["key"])
    assert box.keys.key("abc") == key
    assert reply["session"] == public_session_id("abc")
    ok, body = answer_hello(box, request, 1234.5)
    assert not ok and "has a key already" in json.loads(body)["error"]
    for bad in (b'{"schema": 1, "command": "hello"}',
                b'{"schema": 1, "command": "hello", "argument": "a b"}'):  # fmt: skip
        with pytest.raises(InputError, match="argument"):
            parse_request(bad, "cmd")
