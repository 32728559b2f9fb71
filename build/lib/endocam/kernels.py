"""Plain-float kernels of the hot-path maths: 3-vectors, 3×3 rotations as row lists, SO(3).

The control loop runs every 10 ms and must take tens of microseconds: on this machine scipy's
``Rotation.from_matrix`` costs ~150 µs per call and each MuJoCo ``mju_*`` call ~3 µs of binding
overhead. So the loop works on Python floats, with these kernels. The rule
(``docs/conventions.md``): each kernel has a checked numpy counterpart in
:mod:`endocam.geometry` (scipy's ``Rotation``), and a property test (hypothesis) pins the two
together over random inputs; nothing else in the package re-implements them.

Types: ``Vec`` is a 3-tuple of floats; ``Rows`` is a 3×3 (or 4×4) matrix as a list of row lists.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba.extending import register_jitable

__all__ = [
    "Rows",
    "Vec",
    "copy_into",
    "cross",
    "dist3",
    "dot",
    "dot3",
    "finite_rows",
    "matmul",
    "matmul4_into",
    "matvec3",
    "norm",
    "reject",
    "rotation_angle",
    "scaled",
    "so3_exp",
    "so3_exp_entries",
    "so3_log",
    "tmatmul",
    "tmatmul3_into",
    "unit_checked",
    "unit_or_none",
    "wrap_angle",
]

Vec = tuple[float, float, float]
Rows = list[list[float]]
_SMALL_ANGLE = 1e-8  # rad, below this the first-order series of log/exp is exact in floats


@register_jitable  # also callable from compiled kernels (the same source)
def cross(a: Vec, b: Vec) -> Vec:
    """Cross product ``a × b`` of two 3-vectors."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@register_jitable  # also callable from compiled kernels (the same source)
def dot(a: Vec, b: Vec) -> float:
    """Dot product ``a · b``."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@register_jitable  # also callable from compiled kernels (the same source)
def norm(a: Vec) -> float:
    """Euclidean length ``|a|``."""
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@register_jitable  # also callable from compiled kernels (the same source)
def scaled(a: Vec, k: float) -> Vec:
    """``k a``."""
    return (a[0] * k, a[1] * k, a[2] * k)


@register_jitable  # also callable from compiled kernels (the same source)
def unit_checked(a: Vec, eps: float = 1e-9) -> tuple[bool, Vec]:
    """``(True, a / |a|)``, or ``(False, a)`` if ``|a|`` is ≤ ``eps`` (unitless) or not finite.

    :func:`unit_or_none` without the ``None`` (compiled kernels cannot index an optional).
    """
    length = norm(a)
    if not length > eps:
        return False, a
    return True, scaled(a, 1.0 / length)


def unit_or_none(a: Vec, eps: float = 1e-9) -> Vec | None:
    """``a`` normalised, or ``None`` if its length is ≤ ``eps`` (unitless) or not finite."""
    ok, u = unit_checked(a, eps)
    return u if ok else None


@register_jitable  # also callable from compiled kernels (the same source)
def reject(a: Vec, z: Vec) -> Vec:
    """Component of ``a`` perpendicular to the unit vector ``z``."""
    k = dot(a, z)
    return (a[0] - k * z[0], a[1] - k * z[1], a[2] - k * z[2])


@register_jitable  # also callable from compiled kernels (the same source)
def so3_log(R: Sequence[Sequence[float]]) -> list[float]:
    """Rotation vector (3,) of a rotation matrix given as rows, rad; |θ| ≤ π.

    Uses the quaternion of ``R`` (Shepperd's branch choice, stable for every angle) and
    ``θ = 2 atan2(|v|, w) v/|v|`` with ``w ≥ 0``.
    """
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
    tr = r00 + r11 + r22
    if tr > 0.0:
        k = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * k, (r21 - r12) / k, (r02 - r20) / k, (r10 - r01) / k
    elif r00 > r11 and r00 > r22:
        k = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        w, x, y, z = (r21 - r12) / k, 0.25 * k, (r01 + r10) / k, (r02 + r20) / k
    elif r11 > r22:
        k = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        w, x, y, z = (r02 - r20) / k, (r01 + r10) / k, 0.25 * k, (r12 + r21) / k
    else:
        k = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        w, x, y, z = (r10 - r01) / k, (r02 + r20) / k, (r12 + r21) / k, 0.25 * k
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s < _SMALL_ANGLE:
        return [2.0 * x, 2.0 * y, 2.0 * z]
    scale = 2.0 * math.atan2(s, w) / s
    return [scale * x, scale * y, scale * z]


@register_jitable  # also callable from compiled kernels (the same source)
def so3_exp_entries(
    x: float, y: float, z: float
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """The rotation matrix of the rotation vector ``(x, y, z)`` (rad), row by row: 9 floats.

    Rodrigues' formula; :func:`so3_exp` and the compiled callers that fill an array share it.
    """
    a2 = x * x + y * y + z * z
    if a2 < _SMALL_ANGLE * _SMALL_ANGLE:
        s, c = 1.0, 0.5  # sin(a)/a and (1 − cos a)/a² to first order
    else:
        a = math.sqrt(a2)
        s, c = math.sin(a) / a, (1.0 - math.cos(a)) / a2
    return (
        1.0 - c * (y * y + z * z),
        c * x * y - s * z,
        c * x * z + s * y,
        c * x * y + s * z,
        1.0 - c * (x * x + z * z),
        c * y * z - s * x,
        c * x * z - s * y,
        c * y * z + s * x,
        1.0 - c * (x * x + y * y),
    )


@register_jitable  # also callable from compiled kernels (the same source)
def so3_exp(theta: Sequence[float]) -> Rows:
    """Rotation matrix (rows) of a rotation vector (3,), rad (Rodrigues' formula)."""
    e = so3_exp_entries(theta[0], theta[1], theta[2])
    return [[e[0], e[1], e[2]], [e[3], e[4], e[5]], [e[6], e[7], e[8]]]


@register_jitable  # also callable from compiled kernels (the same source)
def matmul(A: Sequence[Sequence[float]], B: Sequence[Sequence[float]]) -> Rows:
    """``A B`` for 3×3 row lists (unrolled: this runs every control step)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = B
    return [
        [a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21,
         a00 * b02 + a01 * b12 + a02 * b22],
        [a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21,
         a10 * b02 + a11 * b12 + a12 * b22],
        [a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21,
         a20 * b02 + a21 * b12 + a22 * b22],
    ]  # fmt: skip


@register_jitable  # also callable from compiled kernels (the same source)
def tmatmul(A: Sequence[Sequence[float]], B: Sequence[Sequence[float]]) -> Rows:
    """``A^T B`` for 3×3 row lists."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    return matmul([[a00, a10, a20], [a01, a11, a21], [a02, a12, a22]], B)


@register_jitable  # also callable from compiled kernels (the same source)
def rotation_angle(A: Sequence[Sequence[float]], B: Sequence[Sequence[float]]) -> float:
    """Angle of the relative rotation ``A^T B`` of two rotations (rows), rad, in [0, π].

    ``atan2(|sin|, cos)`` from the skew and trace parts of ``M = A^T B``: accurate near 0 and π
    (``arccos`` of the trace is not). ``A`` and ``B`` may hold more columns or rows (a
    (4, 4) pose's rows); only the top-left 3×3 is read.

    """
    a0, a1, a2, b0, b1, b2 = A[0], A[1], A[2], B[0], B[1], B[2]
    # M_ij = sum_k A_ki B_kj, written out (no call per entry: this runs several times a step)
    m00 = a0[0] * b0[0] + a1[0] * b1[0] + a2[0] * b2[0]
    m01 = a0[0] * b0[1] + a1[0] * b1[1] + a2[0] * b2[1]
    m02 = a0[0] * b0[2] + a1[0] * b1[2] + a2[0] * b2[2]
    m10 = a0[1] * b0[0] + a1[1] * b1[0] + a2[1] * b2[0]
    m11 = a0[1] * b0[1] + a1[1] * b1[1] + a2[1] * b2[1]
    m12 = a0[1] * b0[2] + a1[1] * b1[2] + a2[1] * b2[2]
    m20 = a0[2] * b0[0] + a1[2] * b1[0] + a2[2] * b2[0]
    m21 = a0[2] * b0[1] + a1[2] * b1[1] + a2[2] * b2[1]
    m22 = a0[2] * b0[2] + a1[2] * b1[2] + a2[2] * b2[2]
    s0, s1, s2 = m21 - m12, m02 - m20, m10 - m01
    s = 0.5 * math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    c = 0.5 * (m00 + m11 + m22 - 1.0)
    return math.atan2(s, c)


def finite_rows(T: object) -> Rows | None:
    """Rows of a finite (4, 4) array as plain floats, or ``None`` if missing or not finite.

    The boundary from the numpy API into the loop's floats.
    """
    if T is None:
        return None
    arr = T if isinstance(T, np.ndarray) else np.asarray(T, dtype=float)
    if arr.shape != (4, 4):
        return None
    rows: Rows = arr.tolist()
    if not math.isfinite(math.fsum(rows[0] + rows[1] + rows[2] + rows[3])):
        return None  # any NaN or inf makes the sum non-finite
    return rows


# Small array products and distances for compiled kernels: plain arithmetic, pinned to numpy
# (``@``, ``np.linalg.norm``) and Python's ``math`` by a tolerance (tests/test_kernels.py).


@register_jitable  # also callable from compiled kernels (the same source)
def dot3(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> float:
    """``a · b`` of two 3-vectors given by their components."""
    return a0 * b0 + a1 * b1 + a2 * b2


@register_jitable  # also callable from compiled kernels (the same source)
def dist3(ax: float, ay: float, az: float, bx: float, by: float, bz: float) -> float:
    """Euclidean distance between the points ``a`` and ``b`` (units of the points)."""
    dx, dy, dz = ax - bx, ay - by, az - bz
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@register_jitable  # also callable from compiled kernels (the same source)
def matvec3(R: np.ndarray, v: Sequence[float]) -> Vec:
    """``R @ v``: ``R`` a (3, 3) array (or larger, top-left read), ``v`` any 3-indexable."""
    return (
        R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2],
        R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2],
        R[2, 0] * v[0] + R[2, 1] * v[1] + R[2, 2] * v[2],
    )


@register_jitable  # also callable from compiled kernels (the same source)
def matmul4_into(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """``out = A @ B`` of two (4, 4) arrays; ``out`` (4, 4) must not alias ``A`` or ``B``."""
    for r in range(4):
        for c in range(4):
            out[r, c] = (
                A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c] + A[r, 3] * B[3, c]
            )


@register_jitable  # also callable from compiled kernels (the same source)
def tmatmul3_into(A: np.ndarray, B: np.ndarray, out: np.ndarray) -> None:
    """``out = A[:3, :3].T @ B`` for ``B`` (3, m); ``out`` (3, m) must not alias either."""
    for r in range(3):
        for c in range(B.shape[1]):
            out[r, c] = A[0, r] * B[0, c] + A[1, r] * B[1, c] + A[2, r] * B[2, c]


@register_jitable  # also callable from compiled kernels (the same source)
def wrap_angle(angle: float) -> float:
    """``angle`` wrapped into [−π, π], rad (``math.remainder(angle, 2π)`` up to ties at ±π)."""
    two_pi = 2.0 * math.pi
    return angle - two_pi * math.floor(angle / two_pi + 0.5)


@register_jitable  # also callable from compiled kernels (the same source)
def copy_into(src: np.ndarray, out: np.ndarray) -> None:
    """``out[:, :] = src`` for two 2-D arrays of one shape, as plain loops.

    A compiled slice assignment also compiles numba's shape-mismatch message (string
    formatting, ~2 s of a first run's compile); the caller guarantees the shapes.
    """
    for r in range(src.shape[0]):
        for c in range(src.shape[1]):
            out[r, c] = src[r, c]
