"""Counterbalanced orders of conditions for a within-subject study: pure combinatorics.

A design is a list of *rows*, each an order of the condition indices ``0 .. n-1``; the
participants take the rows in turn, so a study is balanced when its number of participants
is a multiple of the number of rows.

- ``latin``: the cyclic Latin square (row ``i`` is ``i, i+1, ..., i+n-1`` mod ``n``): every
  condition in every position equally often. ``n`` rows.
- ``williams``: Williams' balanced Latin square (Williams 1949): also every ordered pair of
  neighbours (A right before B) equally often, so a carry-over from one condition to the next
  is balanced too. First row ``0, 1, n-1, 2, n-2, ...``, row ``i`` that row plus ``i``
  (mod ``n``); for an odd ``n`` no single square does it, and the mirrored rows are added
  (``2n`` rows).
- ``fixed``: one row, the conditions in the protocol's order (a pilot; nothing balanced).

:func:`balance` counts what a schedule holds (positions, neighbour pairs) and
:func:`problems` says, in words, where it is not balanced.
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

Design = Literal["latin", "williams", "fixed"]
DESIGNS: tuple[Design, ...] = ("latin", "williams", "fixed")


def latin_square(n: int) -> list[list[int]]:
    """The cyclic Latin square of order ``n``: row ``i`` is ``(i + j) mod n``."""
    _check_order(n)
    return [[(i + j) % n for j in range(n)] for i in range(n)]


def williams_square(n: int) -> list[list[int]]:
    """Williams' design of order ``n``: ``n`` rows (even ``n``) or ``2n`` (odd ``n``, the
    square and its rows reversed), each ordered pair of distinct conditions adjacent equally
    often over the rows (once for even ``n``, twice for odd)."""
    _check_order(n)
    first = [0]
    low, high = 1, n - 1
    while len(first) < n:
        first.append(low)
        low += 1
        if len(first) < n:
            first.append(high)
            high -= 1
    rows = [[(c + i) % n for c in first] for i in range(n)]
    if n % 2 == 1 and n > 1:
        rows += [row[::-1] for row in rows]
    return rows


def design_rows(design: Design, n: int) -> list[list[int]]:
    """The rows of ``design`` for ``n`` conditions."""
    if design == "latin":
        return latin_square(n)
    if design == "williams":
        return williams_square(n)
    _check_order(n)
    return [list(range(n))]


def _check_order(n: int) -> None:
    if not 1 <= n <= 64:
        raise ValueError(f"a design needs 1 to 64 conditions, got {n}")


@dataclass(frozen=True, slots=True)
class Balance:
    """What a set of orders holds.

    Attributes:
        n: number of conditions.
        orders: how many orders (participants).
        positions: ``positions[c][k]``: how many orders put condition ``c`` at position ``k``.
        pairs: ``(a, b) ->`` how many orders have ``a`` right before ``b``.
    """

    n: int
    orders: int
    positions: tuple[tuple[int, ...], ...]
    pairs: dict[tuple[int, int], int]

    @property
    def positions_balanced(self) -> bool:
        return len({count for row in self.positions for count in row}) <= 1

    @property
    def pairs_balanced(self) -> bool:
        every = [self.pairs.get((a, b), 0) for a in range(self.n) for b in range(self.n) if a != b]
        return len(set(every)) <= 1


def balance(orders: Sequence[Sequence[int]], n: int) -> Balance:
    """Count positions and neighbour pairs of ``orders`` (each a permutation of ``0..n-1``).

    Raises:
        ValueError: an order that is not a permutation of the ``n`` conditions.
    """
    positions = [[0] * n for _ in range(n)]
    pairs: Counter[tuple[int, int]] = Counter()
    for k, order in enumerate(orders):
        if sorted(order) != list(range(n)):
            raise ValueError(f"order {k} is not a permutation of 0..{n - 1}: {list(order)}")
        for pos, c in enumerate(order):
            positions[c][pos] += 1
        pairs.update(itertools.pairwise(order))
    return Balance(n, len(orders), tuple(tuple(r) for r in positions), dict(pairs))


def problems(orders: Sequence[Sequence[int]], names: Sequence[str], design: Design) -> list[str]:
    """Where ``orders`` fail ``design``'s balance, one sentence each; ``[]``: balanced.

    ``latin`` and ``williams`` need every condition in every position equally often;
    ``williams`` also every ordered pair of neighbours equally often. ``fixed`` promises
    nothing.
    """
    if design == "fixed":
        return []
    n = len(names)
    found = balance(orders, n)
    out: list[str] = []
    if not found.positions_balanced:
        for c, row in enumerate(found.positions):
            if len(set(row)) > 1:
                out.append(f"condition '{names[c]}' is at positions 1..{n} {list(row)} times")
    if design == "williams" and not found.pairs_balanced:
        counts = Counter(found.pairs.get((a, b), 0) for a in range(n) for b in range(n) if a != b)
        usual = counts.most_common(1)[0][0]
        for a in range(n):
            for b in range(n):
                got = found.pairs.get((a, b), 0)
                if a != b and got != usual:
                    out.append(
                        f"'{names[a]}' comes right before '{names[b]}' {got} times, "
                        f"other pairs {usual}"
                    )
    return out
