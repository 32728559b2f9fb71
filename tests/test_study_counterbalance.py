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


@given(st.integers(min_value=0, max_value=500), st.integers(min_value=1, max_value=12))
def test_round_robin_groups_stay_balanced(n_participants: int, n_orders: int) -> None:
    counts = Counter(assign_order(k, n_orders) for k in range(n_participants))
    sizes = [counts.get(i, 0) for i in range(n_orders)]
    assert sum(sizes) == n_participants
    assert max(sizes) - min(sizes) <= 1
    # the first participants fill the orders in sequence
    assert [assign_order(k, n_orders) for k in range(min(n_participants, n_orders))] == list(
        range(min(n_participants, n_orders))
    )


@pytest.mark.parametrize("bad", [[], ["a", "a"]])
def test_latin_square_rejects_bad_items(bad: list[str]) -> None:
    with pytest.raises(ValueError, match="items"):
        latin_square(bad)


def test_assign_order_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="participant_index"):
        assign_order(-1, 6)
    with pytest.raises(ValueError, match="n_orders"):
        assign_order(0, 0)
