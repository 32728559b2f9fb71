"""Counterbalancing of the condition sets (paper Sec. IV-D).

Two 3×3 Latin squares are built: the first is cyclic (row ``i`` starts with condition ``i``), the
second is its mirror (each row reversed). Each condition appears once in every position of each
square; for three conditions the six rows are the six permutations. A new participant gets the
order with the fewest sessions that count (completed or still active; abandoned and withdrawn
sessions do not, see :mod:`endocam.study.db`), the first such order on ties. With no session
abandoned this is round-robin: participant ``k`` (0-based) gets order ``k mod 6``, and the counted
group sizes never differ by more than one.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

from endocam.study.manifest import Condition

T = TypeVar("T")

DEFAULT_CONDITIONS = (Condition.FIXED, Condition.CENTERING, Condition.ORIENTATION)


def latin_square(items: Sequence[T]) -> tuple[tuple[T, ...], ...]:
    """Cyclic Latin square: row ``i`` is ``items`` rotated left by ``i``.

    Parameters
    ----------
    items : sequence, length n ≥ 1
        Distinct items (the condition sets).

    Returns
    -------
    tuple of n tuples of length n
        Each item once per row and once per column.
    """
    if len(items) == 0:
        raise ValueError("items must not be empty")
    if len(set(items)) != len(items):
        raise ValueError(f"items must be distinct, got {list(items)}")
    n = len(items)
    return tuple(tuple(items[(row + col) % n] for col in range(n)) for row in range(n))


def mirror(square: Sequence[Sequence[T]]) -> tuple[tuple[T, ...], ...]:
    """Mirror a Latin square left-right (reverse each row); the result is again a Latin square."""
    return tuple(tuple(reversed(row)) for row in square)


def presentation_orders(
    conditions: Sequence[Condition] = DEFAULT_CONDITIONS,
) -> tuple[tuple[Condition, ...], ...]:
    """The presentation orders: a cyclic Latin square followed by its mirror.

    Parameters
    ----------
    conditions : sequence of Condition
        The condition sets, distinct.

    Returns
    -------
    tuple of 2n orders
        For three conditions, the six distinct permutations.
    """
    square = latin_square(tuple(conditions))
    return square + mirror(square)


def assign_order(counts: Sequence[int]) -> int:
    """Order index for a new participant: the order with the fewest counted sessions.

    Parameters
    ----------
    counts : sequence of int, length n_orders ≥ 1
        Sessions per order that count (completed or active), each ≥ 0.

    Returns
    -------
    int
        Index of the smallest count, the lowest index on ties.
    """
    if len(counts) < 1:
        raise ValueError("counts must list at least one order")
    if min(counts) < 0:
        raise ValueError(f"counts must be >= 0, got {list(counts)}")
    return min(range(len(counts)), key=lambda i: (counts[i], i))
