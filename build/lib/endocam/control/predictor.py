"""The ring predictor: the ring centre and normal extrapolated across the sensing delay."""

from __future__ import annotations

import numpy as np
from numba import njit

from endocam.geometry import FloatArray
from endocam.kernels import (
    Vec,
    unit_checked,
)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def ring_push(
    buf: FloatArray, count: np.ndarray, t: float, p: Vec, n: Vec
) -> None:  # pragma: no cover - compiled
    """Append a sample to ``buf`` (L, 7): time (s), centre (3,) world m, unit normal (3,).

    ``count`` (1,): rows in use, oldest first; a full buffer drops its oldest row (a deque
    of length L).
    """
    rows = buf.shape[0]
    if count[0] == rows:
        for r in range(rows - 1):
            for c in range(7):
                buf[r, c] = buf[r + 1, c]
        row = rows - 1
    else:
        row = count[0]
        count[0] += 1
    buf[row, 0] = t
    buf[row, 1], buf[row, 2], buf[row, 3] = p[0], p[1], p[2]
    buf[row, 4], buf[row, 5], buf[row, 6] = n[0], n[1], n[2]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def ring_predict(buf: FloatArray, count: np.ndarray, m: int, h: float) -> tuple[Vec, Vec]:
    """:meth:`RingPredictor.predict` from its samples ``buf`` (L, 7) and ``count`` (1,).

    Ring centre (m) and unit normal in world, ``h`` s after the newest sample; ``m`` the
    spacing.
    """
    k = count[0] - 1
    t_k = buf[k, 0]
    x = np.empty(6)
    for i in range(6):
        x[i] = buf[k, i + 1]
    if count[0] > m and h != 0.0:
        tau = t_k - buf[k - m, 0]
        if not tau > 0.0:
            pass
        elif count[0] > 2 * m:
            inv = 1.0 / tau
            for i in range(6):
                a0, a1, a2 = buf[k, i + 1], buf[k - m, i + 1], buf[k - 2 * m, i + 1]
                v = (a0 - a1) * inv
                acc = (a0 - 2.0 * a1 + a2) * inv * inv
                x[i] = a0 + (v + 0.5 * acc * tau) * h + 0.5 * acc * h * h
        else:
            f = h / tau
            for i in range(6):
                a0, a1 = buf[k, i + 1], buf[k - m, i + 1]
                x[i] = a0 + (a0 - a1) * f
    ok, n = unit_checked((x[3], x[4], x[5]))
    if not ok:
        n = (buf[k, 4], buf[k, 5], buf[k, 6])
    return (x[0], x[1], x[2]), n


class RingPredictor:
    r"""Extrapolates the ring centre and normal from delayed, evenly timed samples.

    Velocity and acceleration are finite differences over samples ``spacing`` steps apart:
    with the newest sample ``x_k`` at ``t_k``,

    .. math::

        v_b = \frac{x_k - x_{k-m}}{\tau}, \quad a = \frac{x_k - 2x_{k-m} + x_{k-2m}}{\tau^2},
        \quad x(t_k + h) \approx x_k + (v_b + a\tau/2)\,h + a h^2/2

    (``v_b`` is the velocity at ``t_k − τ/2``). The normal is extrapolated the same way and
    renormalised. With fewer samples it falls back to lower orders. Compiled
    (:func:`ring_push`, :func:`ring_predict`; the tracker's step calls them inside its own
    kernel).

    Parameters
    ----------
    spacing : int
        ``m``, samples between the differenced ones (≥ 1).
    """

    def __init__(self, spacing: int) -> None:
        if spacing < 1:
            raise ValueError(f"spacing must be ≥ 1, got {spacing}")
        self.spacing = spacing
        self.buf = np.zeros((2 * spacing + 1, 7))  # (t s, centre m, normal), oldest first
        self.count = np.zeros(1, dtype=np.int64)  # rows of buf in use

    def reset(self) -> None:
        """Forget every sample (after lost tracking: no differencing across a gap)."""
        self.count[0] = 0

    def push(self, t: float, p_world: Vec, n_world: Vec) -> None:
        """Add a sample: time ``t`` (s), ring centre (3,) in world (m), unit normal (3,)."""
        p, n = p_world, n_world
        ring_push(
            self.buf,
            self.count,
            float(t),
            (float(p[0]), float(p[1]), float(p[2])),
            (float(n[0]), float(n[1]), float(n[2])),
        )

    def predict(self, h: float) -> tuple[Vec, Vec]:
        """Ring centre (m) and unit normal in world, ``h`` seconds after the newest sample."""
        if not self.count[0]:
            raise IndexError("no sample to predict from")
        return ring_predict(self.buf, self.count, self.spacing, float(h))
