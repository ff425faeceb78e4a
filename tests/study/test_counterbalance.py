"""Counterbalancing designs: every condition in every position equally often, and Williams'
design every ordered pair of neighbours too, for every number of conditions."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.study.counterbalance import (
    balance,
    design_rows,
    latin_square,
    problems,
    williams_square,
)


@given(st.integers(1, 12))
def test_the_latin_square_puts_every_condition_once_in_every_position(n: int) -> None:
    rows = latin_square(n)
    assert len(rows) == n
    b = balance(rows, n)
    assert all(count == 1 for row in b.positions for count in row)


@given(st.integers(1, 12))
def test_williams_balances_positions_and_ordered_neighbours(n: int) -> None:
    rows = williams_square(n)
    assert len(rows) == (n if n % 2 == 0 or n == 1 else 2 * n)
    b = balance(rows, n)
    assert b.positions_balanced and b.pairs_balanced
    if n > 1:
        # every ordered pair occurs (once per square: twice for odd n, whose design is two)
        assert set(b.pairs.values()) == {1 if n % 2 == 0 else 2}
        assert len(b.pairs) == n * (n - 1)


def test_the_plain_latin_square_of_four_does_not_balance_neighbours() -> None:
    # what Williams' design is for: the cyclic square has A before B three times, B before
    # A never
    b = balance(latin_square(4), 4)
    assert b.positions_balanced and not b.pairs_balanced
    assert b.pairs.get((0, 1)) == 3 and b.pairs.get((1, 0)) is None


@given(st.integers(2, 8), st.integers(1, 4))
def test_whole_blocks_of_rows_stay_balanced_and_a_part_block_is_named(n: int, k: int) -> None:
    names = [f"c{i}" for i in range(n)]
    rows = williams_square(n)
    assert problems(rows * k, names, "williams") == []
    cut = rows * k + rows[:1]
    found = problems(cut, names, "williams")
    assert found and any("positions" in p for p in found)


def test_problems_name_the_condition_and_the_pair() -> None:
    orders = [[0, 1, 2], [0, 2, 1], [1, 0, 2]]
    found = problems(orders, ["a", "b", "c"], "williams")
    assert "condition 'a' is at positions 1..3 [2, 1, 0] times" in found
    assert any(p.startswith("'b' comes right before 'c'") or "before" in p for p in found)
    assert problems(orders, ["a", "b", "c"], "fixed") == []


def test_an_order_that_is_not_a_permutation_is_refused() -> None:
    with pytest.raises(ValueError, match="order 1 is not a permutation"):
        balance([[0, 1], [1, 1]], 2)


def test_design_rows_of_fixed_is_the_protocol_order() -> None:
    assert design_rows("fixed", 3) == [[0, 1, 2]]
    with pytest.raises(ValueError, match="1 to 64 conditions, got 0"):
        design_rows("latin", 0)
