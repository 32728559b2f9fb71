"""The ring's plane from the two eyes' row-matched disparities (the stereo estimator's step 5).

The eyes are rectified and parallel, so an image row is an epipolar line: matching the ends of
each eye's chord of the core ellipse on a row gives the plane's disparity there, linear in the
left eye's normalised coordinates. Pure functions on (3, 3) normalised conics.
"""

from __future__ import annotations

import numpy as np

from endocam.geometry import FloatArray

__all__ = ["PLANE_ROWS", "PLANE_ROW_SPAN", "plane_normal"]

PLANE_ROWS = 24  # rows of the core ellipses the stereo plane fit samples
PLANE_ROW_SPAN = 0.9  # the central share of the ellipses' common rows it samples


def plane_normal(Q_left: FloatArray, Q_right: FloatArray) -> FloatArray | None:
    """The ring plane's unit normal (3,), camera frame, from the core ellipses' disparities.

    ``Q_left``, ``Q_right`` (3, 3): each eye's core-circle conic in normalised coordinates (the
    eyes are rectified and parallel, so a row ``y`` is one epipolar line). On ``PLANE_ROWS``
    rows the two ends of each eye's chord are matched (left end to left end); a plane
    ``n · X = d`` in the left eye's frame has normalised disparity ``B / Z = B n · (x, y, 1) /
    d``, linear in the left eye's ``(x, y)``: a least-squares fit of the disparity gives
    ``n`` up to scale. Unlike the ellipse's shape, whose axis ratio changes as the cosine of the
    tilt, the disparity changes as its sine: the tilt is well conditioned near the axis.
    Pointing towards the eyes (negative z); None if fewer than 3 rows are shared or the fit is
    degenerate.
    """
    spans = [_row_span(Q) for Q in (Q_left, Q_right)]
    if spans[0] is None or spans[1] is None:
        return None
    lo, hi = max(spans[0][0], spans[1][0]), min(spans[0][1], spans[1][1])
    if not hi > lo:
        return None
    mid, half = 0.5 * (lo + hi), 0.5 * PLANE_ROW_SPAN * (hi - lo)
    y = np.linspace(mid - half, mid + half, PLANE_ROWS)
    xl, xr = _chord_ends(Q_left, y), _chord_ends(Q_right, y)
    ok = np.all(np.isfinite(xl) & np.isfinite(xr), axis=1)
    if np.count_nonzero(ok) < 3:
        return None
    x = xl[ok].ravel()
    A = np.stack([x, np.repeat(y[ok], 2), np.ones_like(x)], axis=1)
    coef, *_ = np.linalg.lstsq(A, (xl[ok] - xr[ok]).ravel(), rcond=None)
    norm = float(np.linalg.norm(coef))
    if not norm > 0.0:
        return None
    n = coef / norm
    return np.asarray(-n if n[2] > 0.0 else n)


def _row_span(Q: FloatArray) -> tuple[float, float] | None:
    """The rows ``y`` (normalised) the conic ``Q`` (3, 3) spans: (top, bottom), or None."""
    # rows where the quadratic in x has a double root: its discriminant, quadratic in y, is 0
    a, b, c = Q[0, 0], Q[0, 1], Q[0, 2]
    # disc(y) = (b y + c)^2 - a (Q11 y^2 + 2 Q12 y + Q22)
    p2 = b * b - a * Q[1, 1]
    p1 = 2.0 * (b * c - a * Q[1, 2])
    p0 = c * c - a * Q[2, 2]
    roots = np.roots([p2, p1, p0])
    if roots.shape != (2,) or np.any(np.abs(roots.imag) > 0.0):
        return None
    top, bottom = sorted(float(r) for r in roots.real)
    return top, bottom


def _chord_ends(Q: FloatArray, y: FloatArray) -> FloatArray:
    """(len(y), 2) normalised x of the conic ``Q``'s chord ends on rows ``y``, left first.

    NaN on rows off the conic.
    """
    a = Q[0, 0]
    half_b = Q[0, 1] * y + Q[0, 2]
    c = Q[1, 1] * y * y + 2.0 * Q[1, 2] * y + Q[2, 2]
    disc = half_b * half_b - a * c
    root = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
    ends = np.stack([(-half_b - root) / a, (-half_b + root) / a], axis=1)
    return np.sort(ends, axis=1)
