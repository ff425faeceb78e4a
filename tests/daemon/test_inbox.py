"""The joystick inbox: only the operator's valid, fresh, enabled samples count; everything
else is counted by reason and dropped."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.daemon.inbox import MAX_SESSIONS, JoystickInbox
from legws_daemon.formats.messages import public_session_id as public


def payload(seq: int = 0, axes: object = (0.1, 0.0, 0.0), **extra: object) -> bytes:
    data = {"schema": 1, "seq": seq, "stamp": 0.0, "axes": axes, "source": "t", **extra}
    return json.dumps(data).encode()


def session(sid: str, seq: int, axes: object = (0.1, 0.0, 0.0), **extra: object) -> bytes:
    return payload(seq, axes, session=sid, source=f"pub-{sid}", **extra)


def test_valid_sample_is_kept_until_the_deadman_timeout() -> None:
    box = JoystickInbox()
    assert box.offer(payload(1), now=10.0) is not None
    s = box.latest(10.2)
    assert s is not None
    assert s.message.axes == (0.1, 0.0, 0.0)
    assert box.poll(10.26) == (None, "no_input")  # stale: no input
    assert box.accepted == 1
    assert box.rejected == 0


@pytest.mark.parametrize(
    "bad",
    [
        b"\xff\xfe garbage",
        b"",
        b"[1, 2, 3]",
        payload(axes=[0.1, 0.2]),
        payload(axes=["0.1", 0, 0]),
        payload(axes=[math.nan, 0, 0]).replace(b"NaN", b"NaN"),
        b'{"schema": 1, "seq": 1, "stamp": 0, "axes": [Infinity, 0, 0]}',
        payload(axes=[1e308, 0, 0]),
        payload(axes=[0.9, 0.9, 0.0]),  # norm > 1
        payload(schema=2),
        payload(seq=-1),
        payload(unknown_field=1),
        b"{" * 100_000,
        b"x" * 100_000,
    ],
)
def test_malformed_messages_are_counted_and_never_used(bad: bytes) -> None:
    box = JoystickInbox()
    assert box.offer(bad, now=1.0) is None
    assert box.rejected == 1
    assert box.latest(1.0) is None
    assert box.counts() == {"invalid": 1, "auth": 0, "stale_seq": 0, "not_operator": 0}
    assert box.last_error is not None
    assert "\n" not in box.last_error


def test_a_bad_message_does_not_refresh_the_deadman() -> None:
    box = JoystickInbox()
    box.offer(payload(1), now=0.0)
    box.offer(b"garbage", now=0.2)
    assert box.latest(0.3) is None


def test_out_of_order_samples_are_dropped_but_a_restarted_publisher_is_not() -> None:
    box = JoystickInbox()
    box.offer(payload(5000, axes=[0.5, 0, 0]), now=0.0)
    assert box.offer(payload(4999, axes=[-0.5, 0, 0]), now=0.01) is None
    assert box.offer(payload(5000, axes=[-0.5, 0, 0]), now=0.01) is None
    assert box.counts()["stale_seq"] == 2 and box.rejected == 2
    s = box.latest(0.02)
    assert s is not None
    assert s.message.axes[0] == 0.5
    # a publisher without a session id that starts over at 0 is a restart: at once
    assert box.offer(payload(0, axes=[0.2, 0, 0]), now=0.03) is not None
    assert box.offer(payload(900, axes=[0.2, 0, 0]), now=0.04) is not None


def test_a_replayed_seq_within_a_session_is_refused_even_at_zero() -> None:
    box = JoystickInbox()
    for i in range(3):
        assert box.offer(session("a", i), now=0.01 * i) is not None
    assert box.offer(session("a", 0), now=0.05) is None
    assert box.offer(session("a", 2), now=0.05) is None
    assert box.counts()["stale_seq"] == 2
    assert box.offer(session("a", 3), now=0.06) is not None


def test_the_first_session_that_steers_holds_the_lease_and_others_are_not_operator() -> None:
    box = JoystickInbox(timeout=0.25, grace=0.5)
    # a stream of zeros and a message without enable claim nothing
    assert box.offer(session("idle", 0, axes=[0, 0, 0]), now=0.0) is None
    assert box.offer(session("lazy", 0, buttons={"enable": False}), now=0.0) is None
    assert box.poll(0.0) == (None, "no_operator")
    assert box.operator() is None and box.rejected == 0
    assert box.offer(session("a", 0), now=0.01) is not None
    assert box.operator() == {"source": "pub-a", "session": public("a")}
    assert box.offer(session("b", 0, axes=[0, -0.9, 0]), now=0.02) is None
    assert box.offer(session("idle", 1, axes=[0, 0, 0]), now=0.02) is None
    assert box.counts() == {"invalid": 0, "auth": 0, "stale_seq": 0, "not_operator": 2}
    s = box.latest(0.03)
    assert s is not None and s.message.session == "a"
    report = box.take_report()
    assert [(c.operator and c.operator.session, c.reason) for c in report.changes] == [
        ("a", "first_input")
    ]
    assert report.rejections["not_operator"].count == 2
    assert report.rejections["not_operator"].session == public("idle")
    assert box.take_report().changes == []


@pytest.mark.parametrize("button", ["confirm", "cancel"])
def test_a_press_between_two_ticks_reaches_the_next_tick_once(button: str) -> None:
    """Samples bunched between two ticks (a publisher faster than the loop, or a late
    delivery): a button pressed in one that no tick saw still reaches the next tick, once;
    one a tick saw, or of another holder, does not come again."""
    box = JoystickInbox(timeout=0.25, grace=0.5)
    pressed = {"enable": True, button: True}
    assert box.offer(session("pad", 0, buttons=pressed), now=0.00) is not None
    assert box.offer(session("pad", 1, buttons={"enable": True}), now=0.01) is not None
    assert box.offer(session("pad", 2, buttons={"enable": True}), now=0.02) is not None
    sample, why = box.poll(0.05)
    assert why is None and sample is not None
    assert getattr(sample.operator, button) is True  # the tap, though released since
    assert getattr(sample.message.buttons, button) is False  # (the message as it came)
    sample, _ = box.poll(0.10)  # the same sample at the next tick: the tap was delivered
    assert sample is not None and getattr(sample.operator, button) is False
    assert box.offer(session("pad", 3, buttons={"enable": True}), now=0.11) is not None
    sample, _ = box.poll(0.12)
    assert sample is not None and getattr(sample.operator, button) is False
    # a reply's look at the input does not use the press up
    assert box.offer(session("pad", 4, buttons=pressed), now=0.13) is not None
    assert box.poll(0.14, tick=False)[0] is not None
    assert box.offer(session("pad", 5, buttons={"enable": True}), now=0.15) is not None
    sample, _ = box.poll(0.16)
    assert sample is not None and getattr(sample.operator, button) is True
    # a press of the holder before the lease passed is not the new holder's
    assert box.offer(session("pad", 6, buttons=pressed), now=0.17) is not None
    box.release(now=0.18)
    assert box.offer(session("other", 0, buttons={"enable": True}), now=0.19) is not None
    sample, _ = box.poll(0.20)
    assert sample is not None and sample.message.session == "other"
    assert getattr(sample.operator, button) is False


def test_a_press_is_not_carried_past_a_released_enable() -> None:
    """A tap then the enable button let go: no input, and the tap is gone with it."""
    box = JoystickInbox(timeout=0.25, grace=0.5)
    assert box.offer(session("pad", 0, buttons={"enable": True}), now=0.0) is not None
    box.poll(0.01)
    assert box.offer(session("pad", 1, buttons={"enable": True, "cancel": True}), now=0.02)
    assert box.offer(session("pad", 2, buttons={"enable": False}), now=0.03) is not None
    assert box.poll(0.04) == (None, "enable_released")
    assert box.offer(session("pad", 3, buttons={"enable": True}), now=0.05) is not None
    sample, _ = box.poll(0.06)
    assert sample is not None and sample.operator.cancel is False


def test_holding_the_enable_button_claims_a_free_lease_with_the_stick_centred() -> None:
    """A person who joins during assistance holds enable and keeps the stick still."""
    box = JoystickInbox(timeout=0.25, grace=0.5)
    assert box.offer(session("nobutton", 0, axes=[0, 0, 0]), now=0.0) is None  # no claim
    held = session("pad", 0, axes=[0, 0, 0], buttons={"enable": True})
    assert box.offer(held, now=0.1) is not None
    assert box.operator() == {"source": "pub-pad", "session": public("pad")}
    assert box.poll(0.1)[0] is not None


def test_the_lease_passes_after_the_timeout_plus_the_grace() -> None:
    box = JoystickInbox(timeout=0.25, grace=0.5)
    box.offer(session("a", 0), now=0.0)
    assert box.offer(session("b", 0), now=0.74) is None  # 0.74 s of silence: still a's
    assert box.offer(session("b", 1), now=0.76) is not None  # 0.76 > 0.75: b takes it
    assert box.operator() == {"source": "pub-b", "session": public("b")}
    reasons = [c.reason for c in box.take_report().changes]
    assert reasons == ["first_input", "timeout", "first_input"]
    # the control loop's poll ends a silent lease too
    assert box.poll(1.6) == (None, "no_operator")
    assert [c.reason for c in box.take_report().changes] == ["timeout"]


def test_a_goodbye_is_no_input_at_once_and_a_restarted_publisher_steers_at_once() -> None:
    box = JoystickInbox(timeout=0.25, grace=0.5)
    box.offer(session("a", 0, axes=[0.5, 0, 0]), now=0.0)
    assert box.latest(0.01) is not None
    bye = session("a", 1, axes=[0, 0, 0], buttons={"enable": False}, bye=True)
    assert box.offer(bye, now=0.02) is None
    assert box.poll(0.03) == (None, "no_operator")  # not 0.25 s of a zero "input"
    assert box.offer(session("a2", 0), now=0.05) is not None  # the restarted publisher
    assert box.latest(0.05) is not None
    assert [c.reason for c in box.take_report().changes] == [
        "first_input",
        "goodbye",
        "first_input",
    ]


def test_enable_released_is_no_input_but_keeps_the_lease() -> None:
    box = JoystickInbox(timeout=0.25, grace=0.5)
    box.offer(session("a", 0), now=0.0)
    off = session("a", 1, axes=[0.4, 0, 0], buttons={"enable": False})
    assert box.offer(off, now=0.1) is not None
    assert box.poll(0.1) == (None, "enable_released")
    for i in range(2, 20):  # resting with enable released for 2 s
        box.offer(session("a", i, axes=[0, 0, 0], buttons={"enable": False}), now=0.1 * i)
    assert box.offer(session("b", 0), now=2.0) is None
    assert box.operator() == {"source": "pub-a", "session": public("a")}


def test_release_and_take_control() -> None:
    box = JoystickInbox(timeout=0.25, grace=0.5)
    box.offer(session("a", 0), now=0.0)
    change = box.take_control("b", now=0.1)  # b has not been heard yet
    assert change is not None and change.reason == "take_control"
    assert box.latest(0.1) is None  # a's sample is not b's input
    assert box.offer(session("a", 1), now=0.15) is None
    assert box.offer(session("b", 0), now=0.2) is not None
    assert box.operator() == {"source": "pub-b", "session": public("b")}
    assert box.take_control("b", now=0.3) is None  # already b's
    release = box.release(now=0.4)
    assert release is not None and release.reason == "release"
    assert box.operator() is None and box.release(now=0.5) is None
    # a publisher without a session id is named by its source
    box.offer(payload(0, source="legacy"), now=0.6)
    box.take_control("legacy", now=0.7)
    assert box.operator() == {"source": "legacy", "session": None}
    assert box.offer(payload(1, source="legacy"), now=0.8) is not None


def test_the_remembered_sessions_are_bounded() -> None:
    box = JoystickInbox()
    box.offer(session("op", 0), now=0.0)
    for i in range(MAX_SESSIONS + 50):
        box.offer(session(f"s{i}", 0), now=0.0)
    assert len(box._last_seq) == MAX_SESSIONS
    assert box.offer(session("op", 0), now=0.1) is None  # the operator's seq is remembered


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    box = JoystickInbox()
    box.offer(data, now=0.0)
    assert box.accepted + box.rejected == 1


@settings(max_examples=300, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["schema", "seq", "stamp", "axes", "buttons", "source", "x"]),
        st.one_of(
            st.none(),
            st.booleans(),
            st.integers(),
            st.floats(allow_nan=True, allow_infinity=True),
            st.text(max_size=5),
            st.lists(st.floats(allow_nan=True), max_size=4),
        ),
    )
)
def test_arbitrary_objects_never_raise_and_accepted_ones_are_valid(data: dict[str, object]) -> None:
    box = JoystickInbox()
    raw = json.dumps(data).encode()
    sample = box.offer(raw, now=0.0)
    if sample is not None:
        axes = sample.message.axes
        assert all(math.isfinite(a) and -1 <= a <= 1 for a in axes)
        assert math.hypot(*axes) <= 1 + 1e-6
