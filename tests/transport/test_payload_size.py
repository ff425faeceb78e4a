"""A payload's size is read before its bytes: a huge one is refused without a copy."""

from __future__ import annotations

import tracemalloc

import pytest
import zenoh

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import MAX_PAYLOAD
from legws_daemon.transport.session import payload_bytes


def test_a_16_mib_payload_is_refused_without_copying_it() -> None:
    huge = zenoh.ZBytes(b"x" * (16 << 20))
    tracemalloc.start()
    try:
        with pytest.raises(InputError) as err:
            payload_bytes(huge, "legws/r/joystick")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert str(err.value) == f"legws/r/joystick: payload of {16 << 20} bytes exceeds {MAX_PAYLOAD}"
    assert peak < 64 * 1024  # no 16 MiB bytes object was made
    # within the limit: the bytes themselves; nothing: empty
    assert payload_bytes(zenoh.ZBytes(b"x" * MAX_PAYLOAD), "k") == b"x" * MAX_PAYLOAD
    assert payload_bytes(None, "k") == b""
    with pytest.raises(InputError, match="payload of 65537 bytes exceeds 65536"):
        payload_bytes(zenoh.ZBytes(b"x" * (MAX_PAYLOAD + 1)), "k")
