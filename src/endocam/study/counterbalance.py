"""Counterbalancing of the condition sets (paper Sec. IV-D).

Two 3×3 Latin squares are built: the first is cyclic (row ``i`` starts with condition ``i``), the
second is its mirror (each row reversed). Each condition appears once in every position of each
square; for three conditions the six rows are the six permutations. Participants are assigned to
the orders round-robin: participant ``k`` (0-based, in order of arrival) gets order ``k mod 6``,
so group sizes never differ by more than one.
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


def assign_order(participant_index: int, n_orders: int) -> int:
    """Round-robin order index for the ``participant_index``-th participant (0-based)."""
    if participant_index < 0:
        raise ValueError(f"participant_index must be >= 0, got {participant_index}")
    if n_orders < 1:
        raise ValueError(f"n_orders must be >= 1, got {n_orders}")
    return participant_index % n_orders
