"""endocam.blasfloat's products are numpy's (its BLAS's) floats, bit for bit.

Each kernel against the numpy expression the interpreted code writes, on random operands over
eight decades, with signed zeros, infinities and NaN mixed in. Equality is of the bits
(``np.array_equal`` would call ``-0.0 == 0.0`` equal, and NaN unequal to itself).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from numba import njit

from endocam.blasfloat import dot3, fma, matmul3, matmul4, matvec3, tmatmul3, vecmat3

N_RANDOM = 100_000  # operands per shape
SPECIAL = np.array([0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, 5e-324, 1e308])


def _bits(x: object) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(x, dtype=np.float64)).view(np.int64)


def _operands(shape: tuple[int, ...], seed: int) -> np.ndarray:
    """``N_RANDOM`` arrays of ``shape``: normal × 10^U(-4, 4), 1 % of the entries special values."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(N_RANDOM, *shape)) * 10.0 ** rng.uniform(-4, 4, (N_RANDOM, *shape))
    special = rng.random(x.shape) < 0.01
    x[special] = rng.choice(SPECIAL, special.sum())
    x[:50] = -1.0  # all-negative operands against zeros: the sign of a zero sum
    return x


@njit(cache=False)
def _dot3_all(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(a.shape[0])
    for i in range(a.shape[0]):
        out[i] = dot3(a[i, 0], a[i, 1], a[i, 2], b[i, 0], b[i, 1], b[i, 2])
    return out


@njit(cache=False)
def _matvec3_all(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.empty((R.shape[0], 3))
    for i in range(R.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = matvec3(R[i], v[i])
    return out


@njit(cache=False)
def _vecmat3_all(v: np.ndarray, R: np.ndarray) -> np.ndarray:
    out = np.empty((R.shape[0], 3))
    for i in range(R.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = vecmat3(v[i], R[i])
    return out


@njit(cache=False)
def _matmul3_all(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    out = np.empty((A.shape[0], 3, 3))
    for i in range(A.shape[0]):
        matmul3(A[i], B[i], out[i])
    return out


@njit(cache=False)
def _matmul4_all(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    out = np.empty((A.shape[0], 4, 4))
    for i in range(A.shape[0]):
        matmul4(A[i], B[i], out[i])
    return out


@njit(cache=False)
def _tmatmul3_all(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A[:3, :3].T @ B`` per operand: a pose's rotation block transposed, B (3, m)."""
    out = np.empty((A.shape[0], 3, B.shape[2]))
    for i in range(A.shape[0]):
        tmatmul3(A[i, :3, :3], B[i], out[i])
    return out


def _zero_rhs(b: np.ndarray) -> np.ndarray:
    b = b.copy()
    b[:50] = 0.0
    return b


CASES: list[tuple[str, tuple[int, ...], tuple[int, ...], Callable, Callable]] = [
    ("a @ b (3,)", (3,), (3,), lambda a, b: a @ b, _dot3_all),
    ("R @ v (3, 3)(3,)", (3, 3), (3,), lambda R, v: R @ v, _matvec3_all),
    ("v @ R (3,)(3, 3)", (3,), (3, 3), lambda v, R: v @ R, _vecmat3_all),
    ("A @ B (3, 3)", (3, 3), (3, 3), lambda A, B: A @ B, _matmul3_all),
    ("A @ B (4, 4)", (4, 4), (4, 4), lambda A, B: A @ B, _matmul4_all),
    (
        "A.T @ B (3, 3)",
        (4, 4),
        (4, 4),
        lambda A, B: A[:3, :3].T @ B[:3, :3],
        lambda A, B: _tmatmul3_all(A, B[:, :3, :3]),
    ),
    (
        "A.T @ B (3, 3)(3, 6)",
        (4, 4),
        (6, 6),
        lambda A, B: A[:3, :3].T @ B[3:],
        lambda A, B: _tmatmul3_all(A, B[:, 3:]),
    ),
]


@pytest.mark.parametrize(
    ("name", "sa", "sb", "numpy_op", "kernel"), CASES, ids=[c[0] for c in CASES]
)
def test_kernel_is_numpy_bit_for_bit(name, sa, sb, numpy_op, kernel) -> None:
    a, b = _operands(sa, seed=1), _zero_rhs(_operands(sb, seed=2))
    with np.errstate(all="ignore"):  # the infinities and NaN are on purpose
        expected = np.array([numpy_op(a[i], b[i]) for i in range(N_RANDOM)])
    got = kernel(a, b)
    differ = np.flatnonzero((_bits(got) != _bits(expected)).reshape(N_RANDOM, -1).any(axis=1))
    assert differ.size == 0, f"{name}: {differ.size} of {N_RANDOM} differ, first at {differ[:3]}"


def test_strided_operands_are_summed_in_the_same_order() -> None:
    """A pose's column (stride 4) and its rotation block: numpy's BLAS sees strides, same sums."""
    rng = np.random.default_rng(3)
    for _ in range(2000):
        T, u = rng.normal(size=(4, 4)), rng.normal(size=3)
        col = T[:3, 2]
        assert _bits(col @ u) == _bits(dot3(col[0], col[1], col[2], u[0], u[1], u[2]))
        assert (_bits(T[:3, :3] @ u) == _bits(np.array(matvec3(T[:3, :3], u)))).all()


def test_the_fma_rounds_once() -> None:
    """(1 + 2⁻³⁰)² - 1 needs the unrounded product: 2⁻²⁹ + 2⁻⁶⁰ exactly, not 2⁻²⁹."""
    x = 1.0 + 2.0**-30
    assert x * x - 1.0 == 2.0**-29
    assert fma(x, x, -1.0) == 2.0**-29 + 2.0**-60
