from collections import Counter
from itertools import permutations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from endocam.study.counterbalance import (
    assign_order,
    presentation_orders,
    williams_design,
    williams_first_row,
)
from endocam.study.manifest import DEFAULT_CONDITIONS

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

Orders = tuple[tuple[object, ...], ...]


def williams_problems(orders: Orders, items: tuple[object, ...]) -> list[str]:
    """Where ``orders`` break the Williams design's defining properties (empty: none)."""
    k = len(items)
    problems = []
    if len(orders) != (k if k % 2 == 0 else 2 * k):
        problems.append(f"{len(orders)} orders")
    if any(sorted(map(str, row)) != sorted(map(str, items)) for row in orders):
        problems.append("an order is not a permutation")
    for position in range(k):  # each condition equally often in every position
        counts = Counter(row[position] for row in orders if len(row) == k)
        if len(set(counts.values())) != 1 or set(counts) != set(items):
            problems.append(f"position {position} unbalanced: {counts}")
    follows = Counter((row[j], row[j + 1]) for row in orders for j in range(len(row) - 1))
    pairs = [(a, b) for a in items for b in items if a != b]
    if pairs and len({follows[p] for p in pairs}) != 1:  # each ordered pair adjacent equally often
        problems.append(f"carry-over unbalanced: {dict(follows)}")
    return problems


@pytest.mark.parametrize("k", [3, 4, 5])
def test_williams_design_is_balanced_for_carry_over(k: int) -> None:
    items = tuple(f"c{i}" for i in range(k))
    orders = williams_design(items)
    assert williams_problems(orders, items) == []
    assert len(set(orders)) == len(orders)  # the manifest needs distinct orders
    follows = Counter((row[j], row[j + 1]) for row in orders for j in range(k - 1))
    assert set(follows.values()) == {1 if k % 2 == 0 else 2}


def test_williams_first_rows_are_the_standard_ones() -> None:
    assert williams_first_row(4) == (0, 1, 3, 2)
    assert williams_first_row(5) == (0, 1, 4, 2, 3)
    assert williams_first_row(6) == (0, 1, 5, 2, 4, 3)


@pytest.mark.parametrize("k", [4, 5])
def test_the_balance_check_catches_a_broken_construction(k: int) -> None:
    items = tuple(range(k))
    cyclic = tuple(tuple(items[(i + j) % k] for j in range(k)) for i in range(k))
    assert williams_problems(cyclic, items)  # a plain cyclic Latin square: carry-over unbalanced
    orders = williams_design(items)
    swapped = tuple((row[1], row[0], *row[2:]) for row in orders)
    assert williams_problems(swapped, items)
    if k % 2:
        assert williams_problems(orders[:k], items)  # odd k: one square alone is not enough


@given(st.lists(st.integers(), min_size=2, max_size=9, unique=True))
def test_williams_design_any_size(items: list[int]) -> None:
    orders = williams_design(items)
    assert williams_problems(orders, tuple(items)) == []
    assert len(set(orders)) == len(orders)


def test_three_conditions_give_all_six_permutations() -> None:
    orders = presentation_orders()
    assert len(orders) == 6
    assert set(orders) == set(permutations(DEFAULT_CONDITIONS))


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
def test_williams_design_rejects_bad_items(bad: list[str]) -> None:
    with pytest.raises(ValueError, match="items"):
        williams_design(bad)


def test_assign_order_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="counts"):
        assign_order([1, -1])
    with pytest.raises(ValueError, match="counts"):
        assign_order([])
