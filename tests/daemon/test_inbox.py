"""The joystick inbox: only valid, fresh samples count; everything else is counted and dropped."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.daemon.inbox import JoystickInbox


def payload(seq: int = 0, axes: object = (0.1, 0.0, 0.0), **extra: object) -> bytes:
    data = {"schema": 1, "seq": seq, "stamp": 0.0, "axes": axes, "source": "t", **extra}
    return json.dumps(data).encode()


def test_valid_sample_is_kept_until_the_deadman_timeout() -> None:
    box = JoystickInbox()
    assert box.offer(payload(1), now=10.0) is not None
    s = box.latest(10.2, timeout=0.25)
    assert s is not None
    assert s.message.axes == (0.1, 0.0, 0.0)
    assert box.latest(10.26, timeout=0.25) is None  # stale: no input
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
    assert box.latest(1.0, timeout=0.25) is None
    assert box.last_error is not None
    assert "\n" not in box.last_error


def test_a_bad_message_does_not_refresh_the_deadman() -> None:
    box = JoystickInbox()
    box.offer(payload(1), now=0.0)
    box.offer(b"garbage", now=0.2)
    assert box.latest(0.3, timeout=0.25) is None


def test_out_of_order_samples_are_dropped_but_a_restarted_publisher_is_not() -> None:
    box = JoystickInbox()
    box.offer(payload(5000, axes=[0.5, 0, 0]), now=0.0)
    assert box.offer(payload(4999, axes=[-0.5, 0, 0]), now=0.01) is None
    s = box.latest(0.02, 0.25)
    assert s is not None
    assert s.message.axes[0] == 0.5
    assert box.offer(payload(0, axes=[0.2, 0, 0]), now=0.03) is not None  # restarted at 0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    box = JoystickInbox()
    box.offer(data, now=0.0)
    assert box.accepted + box.rejected + box.reasons["stale_seq"] == 1


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
