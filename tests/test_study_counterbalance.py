from collections import Counter
from itertools import permutations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from endocam.study.counterbalance import (
    DEFAULT_CONDITIONS,
    assign_order,
    latin_square,
    mirror,
    presentation_orders,
)


def _is_latin(square: tuple[tuple[object, ...], ...], items: tuple[object, ...]) -> bool:
    n = len(items)
    rows_ok = all(sorted(map(str, row)) == sorted(map(str, items)) for row in square)
    cols_ok = all(
        sorted(str(square[r][c]) for r in range(n)) == sorted(map(str, items)) for c in range(n)
    )
    return len(square) == n and rows_ok and cols_ok


def test_both_squares_are_balanced_latin_squares() -> None:
    orders = presentation_orders()
    first, second = orders[:3], orders[3:]
    assert _is_latin(first, DEFAULT_CONDITIONS)
    assert _is_latin(second, DEFAULT_CONDITIONS)
    for square in (first, second):
        for position in range(3):  # each condition once per position
            assert Counter(row[position] for row in square) == Counter(DEFAULT_CONDITIONS)


def test_second_square_mirrors_the_first() -> None:
    orders = presentation_orders()
    assert orders[3:] == tuple(tuple(reversed(row)) for row in orders[:3])


def test_six_distinct_orders_are_all_permutations() -> None:
    orders = presentation_orders()
    assert len(orders) == 6
    assert len(set(orders)) == 6
    assert set(orders) == set(permutations(DEFAULT_CONDITIONS))


@given(st.lists(st.integers(), min_size=1, max_size=7, unique=True))
def test_latin_square_any_size(items: list[int]) -> None:
    square = latin_square(items)
    assert _is_latin(square, tuple(items))
    assert _is_latin(mirror(square), tuple(items))


def _assign_all(n_participants: int, n_orders: int) -> list[int]:
    counts = [0] * n_orders
    assigned = []
    for _ in range(n_participants):
        k = assign_order(counts)
        counts[k] += 1
        assigned.append(k)
    return assigned


@given(st.integers(min_value=0, max_value=500), st.integers(min_value=1, max_value=12))
def test_groups_stay_balanced_and_fill_in_sequence(n_participants: int, n_orders: int) -> None:
    assigned = _assign_all(n_participants, n_orders)
    sizes = [assigned.count(i) for i in range(n_orders)]
    assert sum(sizes) == n_participants
    assert max(sizes) - min(sizes) <= 1
    assert assigned == [k % n_orders for k in range(n_participants)]  # round-robin


def test_a_gap_left_by_an_abandoned_session_is_filled_first() -> None:
    # orders 0..5 have 2 counted sessions each, except order 3 whose second session was abandoned
    assert assign_order([2, 2, 2, 1, 2, 2]) == 3
    assert assign_order([1, 0, 0]) == 1


@pytest.mark.parametrize("bad", [[], ["a", "a"]])
def test_latin_square_rejects_bad_items(bad: list[str]) -> None:
    with pytest.raises(ValueError, match="items"):
        latin_square(bad)


def test_assign_order_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="counts"):
        assign_order([1, -1])
    with pytest.raises(ValueError, match="counts"):
        assign_order([])
