"""The operator lease: one holder at a time, passed only for the documented reasons."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.daemon.lease import Lease, SessionKey
from legws_daemon.formats.messages import public_session_id

KEYS = [
    SessionKey("a", "pad"),
    SessionKey("b", "pad"),
    SessionKey(None, "a"),
    SessionKey(None, "b"),
]

Step = tuple[str, int, bool, bool, float]
steps = st.lists(
    st.tuples(
        st.sampled_from(["msg", "msg", "msg", "release", "take", "tick", "stall"]),
        st.integers(0, len(KEYS) - 1),
        st.booleans(),  # steering
        st.booleans(),  # bye
        st.floats(0.0, 1.0),  # time since the previous step, s
    ),
    max_size=60,
)


def test_a_session_id_and_a_source_label_are_never_the_same_session() -> None:
    assert SessionKey("a", "x") == SessionKey("a", "y")  # the label is only a name
    assert SessionKey("a", "x") != SessionKey(None, "a")
    assert len({SessionKey("a", "x"), SessionKey("a", "y"), SessionKey(None, "a")}) == 2


@settings(max_examples=400, deadline=None)
@given(steps)
def test_one_holder_and_every_change_is_accounted_for(sequence: list[Step]) -> None:
    lease = Lease(timeout=0.25, grace=0.5)
    now = 0.0
    for what, k, steering, bye, dt in sequence:
        now += dt
        before = lease.holder
        heard = lease.heard
        lapsed = lease.lapsed
        if what == "msg":
            mine, changes = lease.offer(KEYS[k], now, steering=steering, bye=bye)
            # the message is the operator's only if its session held the lease or took it
            assert mine == (
                (before == KEYS[k] and heard is not None and now - heard <= 0.75)
                or any(
                    c.operator == KEYS[k] and c.reason in ("first_input", "resumed")
                    for c in changes
                )
            )
            if mine and bye:
                assert lease.holder is None and changes[-1].reason == "goodbye"
            if not mine:
                assert lease.holder != KEYS[k] or lease.holder is None
        elif what == "release":
            changes = [c for c in [lease.release(now)] if c is not None]
            assert lease.holder is None
        elif what == "take":
            changes = [c for c in [lease.take(KEYS[k], now)] if c is not None]
            assert lease.holder == KEYS[k]
        elif what == "stall":
            lease.stall(now)
            changes = []
            assert lease.holder == before  # the daemon's pause is not the holder's silence
            if before is not None:
                assert lease.heard == now
        else:
            changes = [c for c in [lease.expire(now)] if c is not None]
        # the changes chain from the holder before to the holder after
        chain = before
        for change in changes:
            assert change.previous == chain
            assert change.operator != change.previous
            if change.reason == "first_input":
                assert change.previous is None and steering and not bye
            if change.reason == "resumed":  # the one that lapsed, and nobody had it since
                assert change.previous is None and lapsed == change.operator and not bye
            if change.reason == "timeout":
                assert change.operator is None
            if change.reason == "timeout":
                lapsed = change.previous  # (an expiry inside this step)
            chain = change.operator
        assert chain == lease.holder
        if lease.holder is not None:
            assert lease.heard is not None and lease.since is not None
            assert lease.since <= lease.heard <= now


def test_a_silent_holder_keeps_the_lease_for_exactly_the_timeout_plus_the_grace() -> None:
    lease = Lease(timeout=0.25, grace=0.5)
    a, b = KEYS[0], KEYS[1]
    mine, changes = lease.offer(a, 0.0, steering=True, bye=False)
    assert mine and [c.reason for c in changes] == ["first_input"]
    assert lease.expire(0.75) is None
    mine, changes = lease.offer(b, 0.7501, steering=True, bye=False)
    assert mine and [c.reason for c in changes] == ["timeout", "first_input"]


def test_a_holder_that_lapsed_takes_it_back_unless_someone_else_had_it() -> None:
    lease = Lease(timeout=0.25, grace=0.5)
    a, b = KEYS[0], KEYS[1]
    lease.offer(a, 0.0, steering=True, bye=False)
    # silence past 0.75 s, then a's stick centred (not steering): it is a's again
    mine, changes = lease.offer(a, 1.0, steering=False, bye=False)
    assert mine and [c.reason for c in changes] == ["timeout", "resumed"]
    # ... but not with enable released, and not once b had it
    mine, changes = lease.offer(a, 2.0, steering=False, bye=False, enabled=False)
    assert not mine and [c.reason for c in changes] == ["timeout"]
    lease.offer(b, 2.1, steering=True, bye=False)
    lease.expire(3.0)
    mine, _ = lease.offer(a, 3.1, steering=False, bye=False)
    assert not mine and lease.holder is None


def test_a_stall_keeps_the_holder_heard_from_the_resume_and_nobody_else_takes_it() -> None:
    lease = Lease(timeout=0.25, grace=0.5)
    a, b = KEYS[0], KEYS[1]
    lease.offer(a, 0.0, steering=True, bye=False)
    lease.stall(2.0)  # paused 2 s: far past timeout + grace
    assert lease.holder == a and lease.heard == 2.0  # the lease did not change hands
    assert lease.expire(2.5) is None  # its silence counts from the resume
    # whoever sends first after the pause does not win it (an attacker's stream would)
    assert not lease.offer(b, 2.01, steering=True, bye=False)[0]
    mine, changes = lease.offer(a, 2.05, steering=False, bye=False)
    assert mine and changes == []
    assert lease.expire(2.05 + 0.76) is not None  # a holder silent after it still lapses


def test_status_names_a_session_by_its_public_id() -> None:
    assert SessionKey("abc", "pad").describe() == {
        "source": "pad", "session": public_session_id("abc")
    }  # fmt: skip
    assert SessionKey(None, "legacy").describe() == {"source": "legacy", "session": None}
