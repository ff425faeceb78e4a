"""Hypothesis strategies shared by the fuzzers: JSON values that are wrong somewhere, and
byte-level mutations of valid payloads or files."""

from __future__ import annotations

import math
from typing import Any

from hypothesis import strategies as st

# --- JSON values that are wrong somewhere -----------------------------------------------
#: Numbers at and past every edge a field may have.
EDGE_NUMBERS: list[Any] = [
    0, -1, 1, 2, -0.0, 1.0000001, -1.0000001, 1.0 + 1e-6, 0.5, 64, 65, 100.0, 100.0001, -100.5,
    2**31, 2**53 + 1, 2**63 - 1, 2**63, 2**64, -(2**63), 10**30, 10**400,
    1e308, -1e308, 5e-324, math.nan, math.inf, -math.inf,
]  # fmt: skip
#: Strings at and past the edges of labels and names.
EDGE_TEXT: list[Any] = [
    "", " ", "x" * 64, "x" * 65, "\x00", "\n", "é", "\u202e", "\ud800", "NaN", "1", "true",
    "null", "../desk", "desk.toml", "white_mug\n", "White_Mug", "💥" * 20,
]  # fmt: skip

leaves = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.sampled_from(EDGE_NUMBERS),
    st.floats(),  # NaN and infinities included
    st.text(max_size=12),
    st.sampled_from(EDGE_TEXT),
)
junk = st.recursive(
    leaves,
    lambda kids: (
        st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4)
    ),
    max_leaves=8,
)


def nested(value: Any, depth: int) -> Any:
    """``value`` inside ``depth`` one-item lists."""
    for _ in range(depth):
        value = [value]
    return value


# --- mutations of bytes ------------------------------------------------------------------
@st.composite
def mutated(draw: st.DrawFn, valid: st.SearchStrategy[bytes]) -> bytes:
    """A valid payload with 1-4 byte-level mutations."""
    data = bytearray(draw(valid))
    for _ in range(draw(st.integers(1, 4))):
        n = len(data)
        op = draw(st.sampled_from(["flip", "set", "truncate", "duplicate", "delete", "insert"]))
        i = draw(st.integers(0, max(n - 1, 0)))
        if op == "flip" and n:
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and n:
            data[i] = draw(st.integers(0, 255))
        elif op == "truncate":
            del data[i:]
        elif op == "duplicate":
            j = draw(st.integers(i, n))
            times = draw(st.sampled_from([1, 2, 100]))
            data[i:i] = data[i:j] * times
        elif op == "delete":
            del data[i : draw(st.integers(i, n))]
        else:
            data[i:i] = draw(st.binary(min_size=1, max_size=8))
    return bytes(data)
