"""CPython's ``math.hypot``, ``math.dist`` and ``math.remainder``, compiled: the same floats.

CPython 3.11 does not call the C library's ``hypot``: both functions scale the coordinates'
absolute values by a power of two, square them exactly (Veltkamp–Dekker splitting), add the
squares with a compensated sum and correct the square root once (``Modules/mathmodule.c``,
``vector_norm``). Numba's ``math.hypot`` is the C library's, which rounds differently in the
last bit now and then, and a compiled kernel that steers by such a value (an IK branch, a
Lipschitz bound) must see the interpreter's floats (``docs/conventions.md``, "Compiled
kernels"). So :func:`hypot2` and :func:`dist3` are that algorithm, operation for operation;
the interpreter's ``math.hypot`` / ``math.dist`` are their checked counterparts, pinned on
over 10⁶ random inputs, edge cases included (``tests/test_pyfloat.py``).

CPython 3.12 rewrote the exact squaring with ``fma``; the same test, run under another
interpreter, says whether these kernels still match it.
"""

from __future__ import annotations

import math

from numba import njit

__all__ = ["dist3", "hypot2", "remainder"]

_T27 = 134217729.0  # 2**27 + 1, the Veltkamp splitting constant


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _vector_norm(vec: tuple[float, ...], max_abs: float, found_nan: bool) -> float:
    """CPython 3.11's ``vector_norm``: ``sqrt(sum(x**2))`` of the absolute values ``vec``.

    ``max_abs`` is the largest of ``vec`` (inf if any is inf), ``found_nan`` whether any is
    NaN; same units as ``vec``.
    """
    if math.isinf(max_abs):
        return max_abs
    if found_nan:
        return math.nan
    if max_abs == 0.0 or len(vec) <= 1:
        return max_abs
    _, max_e = math.frexp(max_abs)
    csum, frac1, frac2, frac3 = 1.0, 0.0, 0.0, 0.0
    if max_e >= -1023:
        scale = math.ldexp(1.0, -max_e)
        for v in vec:
            x = v * scale
            t = x * _T27
            hi = t - (t - x)
            lo = x - hi
            x = hi * hi
            oldcsum = csum
            csum += x
            frac1 += (oldcsum - csum) + x
            x = 2.0 * hi * lo
            oldcsum = csum
            csum += x
            frac2 += (oldcsum - csum) + x
            frac3 += lo * lo
        h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
        x = h
        t = x * _T27
        hi = t - (t - x)
        lo = x - hi
        x = -hi * hi
        oldcsum = csum
        csum += x
        frac1 += (oldcsum - csum) + x
        x = -2.0 * hi * lo
        oldcsum = csum
        csum += x
        frac2 += (oldcsum - csum) + x
        x = -lo * lo
        oldcsum = csum
        csum += x
        frac3 += (oldcsum - csum) + x
        x = csum - 1.0 + (frac1 + frac2 + frac3)
        return (h + x / (2.0 * h)) / scale
    # max_e < -1023: ldexp(1.0, -max_e) would overflow, so divide by the largest instead
    for v in vec:
        x = v / max_abs
        x = x * x
        oldcsum = csum
        csum += x
        frac1 += (oldcsum - csum) + x
    return max_abs * math.sqrt(csum - 1.0 + frac1)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def hypot2(x: float, y: float) -> float:
    """``math.hypot(x, y)`` as CPython 3.11 computes it: ``sqrt(x² + y²)``, units of x, y."""
    a, b = abs(x), abs(y)
    found_nan = math.isnan(a) or math.isnan(b)
    m = 0.0
    if a > m:
        m = a
    if b > m:
        m = b
    return _vector_norm((a, b), m, found_nan)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def dist3(ax: float, ay: float, az: float, bx: float, by: float, bz: float) -> float:
    """``math.dist((ax, ay, az), (bx, by, bz))`` as CPython 3.11 computes it, m (units of a)."""
    d0, d1, d2 = abs(ax - bx), abs(ay - by), abs(az - bz)
    found_nan = math.isnan(d0) or math.isnan(d1) or math.isnan(d2)
    m = 0.0
    if d0 > m:
        m = d0
    if d1 > m:
        m = d1
    if d2 > m:
        m = d2
    return _vector_norm((d0, d1, d2), m, found_nan)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def remainder(x: float, y: float) -> float:
    """``math.remainder(x, y)``: IEEE 754 ``x − n·y``, ``n`` the integer nearest ``x / y``.

    CPython's own ``m_remainder`` (numba has no ``math.remainder``), operation for operation:
    ``fmod`` is exact, so is the result. ``ValueError`` where CPython raises it (``y`` zero,
    ``x`` infinite).
    """
    if math.isfinite(x) and math.isfinite(y):
        if y == 0.0:
            raise ValueError("math domain error")
        absx, absy = abs(x), abs(y)
        m = absx % absy  # C's fmod: the operands are ≥ 0 (numba has no math.fmod)
        c = absy - m
        if m < c:
            r = m
        elif m > c:
            r = -c
        else:  # half way: the even multiple
            r = m - 2.0 * ((0.5 * (absx - m)) % absy)
        return math.copysign(1.0, x) * r
    if math.isnan(x):
        return x
    if math.isnan(y):
        return y
    if math.isinf(x):
        raise ValueError("math domain error")
    return x
