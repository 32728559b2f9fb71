"""Counterbalancing of the condition sets: a Williams design (balanced Latin square).

Each participant sees the conditions' sets in one of the **presentation orders**. For ``k``
conditions the orders are a Williams design (E. J. Williams, "Experimental designs balanced for
the estimation of residual effects of treatments", Aust. J. Sci. Res. A 2, 1949): with the
conditions numbered ``0 .. k−1``, the first row is ``0, 1, k−1, 2, k−2, 3, ...`` (position
``p ≥ 1`` holds ``(p + 1) // 2`` for odd ``p`` and ``k − p // 2`` for even ``p``), and row ``i``
adds ``i`` modulo ``k`` to every entry. For even ``k`` these ``k`` rows are a Latin square in
which every condition immediately follows every other condition exactly once. For odd ``k`` no
single square does that, and the design is the pair of squares: the ``k`` rows and their mirror
images (each row reversed), ``2k`` orders in which each condition follows each other exactly
twice. In every case each condition appears once per order and equally often in every position,
so position (practice, fatigue) and carry-over from the set just seen are balanced.

For three conditions the six orders are the six permutations. A new participant gets the order
with the fewest sessions that count (completed or still active; abandoned and withdrawn sessions
do not, see :mod:`endocam.study.db`), the first such order on ties. With no session abandoned
this is round-robin: participant ``n`` (0-based) gets order ``n mod len(orders)``, and the
counted group sizes never differ by more than one.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

from endocam.study.manifest import DEFAULT_CONDITIONS

T = TypeVar("T")


def williams_first_row(k: int) -> tuple[int, ...]:
    """The first row of the Williams square of order ``k`` (≥ 1): ``0, 1, k−1, 2, k−2, ...``."""
    if k < 1:
        raise ValueError(f"k must be ≥ 1, got {k}")
    return tuple(0 if p == 0 else (p + 1) // 2 if p % 2 else k - p // 2 for p in range(k))


def williams_design(items: Sequence[T]) -> tuple[tuple[T, ...], ...]:
    """The Williams design over ``items``: ``k`` orders for even ``k``, ``2k`` for odd ``k``.

    Parameters
    ----------
    items : sequence, length k ≥ 1
        Distinct items (the conditions).

    Returns
    -------
    tuple of orders, each a permutation of ``items``
        The square's rows (row ``i`` = the first row plus ``i`` mod ``k``), then for odd ``k``
        the same rows reversed (module docstring).
    """
    if len(items) == 0:
        raise ValueError("items must not be empty")
    if len(set(items)) != len(items):
        raise ValueError(f"items must be distinct, got {list(items)}")
    k = len(items)
    first = williams_first_row(k)
    square = tuple(tuple(items[(a + i) % k] for a in first) for i in range(k))
    if k % 2 == 0:
        return square
    return square + tuple(tuple(reversed(row)) for row in square)


def presentation_orders(
    conditions: Sequence[str] = DEFAULT_CONDITIONS,
) -> tuple[tuple[str, ...], ...]:
    """The presentation orders of a study's conditions: their Williams design.

    Parameters
    ----------
    conditions : sequence of str
        The condition sets, distinct.

    Returns
    -------
    tuple of orders
        ``k`` orders for an even number ``k`` of conditions, ``2k`` for an odd one; for three,
        the six permutations.
    """
    return williams_design(tuple(conditions))


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
