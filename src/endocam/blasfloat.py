"""numpy's small products (``@``, ``.dot``) as OpenBLAS computes them, compiled: the same floats.

numpy hands every float64 product of contiguous (or evenly strided) operands to its BLAS,
whatever the size, and OpenBLAS's x86-64 kernels (Haswell and newer) use fused multiply-adds in
an order of their own. A compiled kernel that replaces such a product with plain ``a*b + c*d``
rounds differently in the last bit now and then, and the logs drift (``docs/conventions.md``,
"Compiled kernels"). So these are the orders OpenBLAS uses, found and pinned by
``tests/test_blasfloat.py`` against numpy itself on 10⁵ random operands per shape:

- ``a @ b``, ``a.dot(b)`` of two n-vectors (``ddot``), and every entry of a matrix product
  ``A @ B`` (``dgemm``, 3×3 and 4×4): the products summed in index order, each added with one
  rounding, from a zero accumulator: ``fma(a[2], b[2], fma(a[1], b[1], fma(a[0], b[0], 0.0)))``
  (the zero matters for signs only: all-negative-zero products sum to ``+0.0``);
- ``R @ v``, a 3×3 matrix times a 3-vector (``dgemv``, transposed kernel): each row's entry is
  ``fma(r[2], v[2], fma(r[0], v[0], r[1] * v[1])) + 0.0``;
- ``v @ R``, a 3-vector times a 3×3 matrix: the ``ddot`` order over each column;
- ``A.T @ B``, a 3×3 matrix's transpose (a view, e.g. ``T[:3, :3].T``) times a (3, m) matrix
  (``dgemm`` with the first operand transposed; probed for m = 3 and 6): the ``ddot`` order too.

``fma`` is LLVM's ``llvm.fma.f64``: one rounding on every CPU (a library call where the CPU has
no FMA unit), so the kernels' floats do not depend on the machine. Which order numpy's BLAS uses
does (another BLAS, or OpenBLAS on a CPU older than Haswell, may sum differently): the test says
whether these kernels still match it. Every other shape: probe it first (4×4 times a 4-vector
does not follow either order above).

These are for compiled kernels only (``fma`` has no interpreted counterpart in Python 3.11);
the interpreted code keeps calling numpy, their checked counterpart.
"""

from __future__ import annotations

from typing import Any

from numba import njit, types
from numba.extending import intrinsic

__all__ = ["dot3", "fma", "matmul3", "matmul4", "matvec3", "tmatmul3", "vecmat3"]


def _fma_typing(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    """``a * b + c`` rounded once: LLVM's ``llvm.fma.f64``."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.fma(*args)

    return sig, codegen


_fma: Any = intrinsic(_fma_typing)


@njit(cache=True, inline="always")
def fma(a: float, b: float, c: float) -> float:
    """``a * b + c`` with one rounding (IEEE 754 fusedMultiplyAdd)."""
    return _fma(a, b, c)


@njit(cache=True, inline="always")
def dot3(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    """``a @ b`` of two 3-vectors, as numpy computes it (OpenBLAS ``ddot``)."""
    return _fma(a2, b2, _fma(a1, b1, _fma(a0, b0, 0.0)))


@njit(cache=True)
def matvec3(R: Any, v: Any) -> tuple[float, float, float]:
    """``R @ v`` as numpy computes it: ``R`` (3, 3) array, ``v`` any 3-indexable; a 3-tuple."""
    return (
        _fma(R[0, 2], v[2], _fma(R[0, 0], v[0], R[0, 1] * v[1])) + 0.0,
        _fma(R[1, 2], v[2], _fma(R[1, 0], v[0], R[1, 1] * v[1])) + 0.0,
        _fma(R[2, 2], v[2], _fma(R[2, 0], v[0], R[2, 1] * v[1])) + 0.0,
    )


@njit(cache=True)
def vecmat3(v: Any, R: Any) -> tuple[float, float, float]:
    """``v @ R`` as numpy computes it: ``v`` any 3-indexable, ``R`` (3, 3) array; a 3-tuple."""
    return (
        _fma(v[2], R[2, 0], _fma(v[1], R[1, 0], _fma(v[0], R[0, 0], 0.0))),
        _fma(v[2], R[2, 1], _fma(v[1], R[1, 1], _fma(v[0], R[0, 1], 0.0))),
        _fma(v[2], R[2, 2], _fma(v[1], R[1, 2], _fma(v[0], R[0, 2], 0.0))),
    )


@njit(cache=True)
def matmul3(A: Any, B: Any, out: Any) -> None:
    """``A @ B`` of two (3, 3) arrays as numpy computes it, into ``out`` (3, 3), not aliasing."""
    for r in range(3):
        for c in range(3):
            out[r, c] = _fma(A[r, 2], B[2, c], _fma(A[r, 1], B[1, c], _fma(A[r, 0], B[0, c], 0.0)))


@njit(cache=True)
def matmul4(A: Any, B: Any, out: Any) -> None:
    """``A @ B`` of two (4, 4) arrays as numpy computes it, into ``out`` (4, 4), not aliasing."""
    for r in range(4):
        for c in range(4):
            s: float = fma(A[r, 0], B[0, c], 0.0)
            s = fma(A[r, 1], B[1, c], s)
            s = fma(A[r, 2], B[2, c], s)
            out[r, c] = fma(A[r, 3], B[3, c], s)


@njit(cache=True)
def tmatmul3(A: Any, B: Any, out: Any) -> None:
    """``A.T @ B`` of a (3, 3) and a (3, m) array as numpy computes it, into ``out`` (3, m).

    ``out`` must not alias ``A`` or ``B``.
    """
    for r in range(3):
        for c in range(B.shape[1]):
            out[r, c] = _fma(A[2, r], B[2, c], _fma(A[1, r], B[1, c], _fma(A[0, r], B[0, c], 0.0)))
