"""The wire (rail) of the wire-chaser task: a cubic spline re-parametrised by arc length.

The centre line ``c(s)`` is a C² cubic spline through the configured knots. It is first
interpolated with a chord-length parameter, then re-fitted against its own arc length ``s``
(m, from the left end), so ``|c'(s)| = 1`` up to ~1e-6 and every query takes ``s`` in metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import overload

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import make_interp_spline
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

from endocam.geometry import FloatArray, as_vector3
from endocam.task.centreline import chord_spline
from endocam.task.config import WireConfig

_SEARCH_SAMPLES_PER_M = 4000  # 1/m, KD-tree sample density for nearest-point seeds (0.25 mm)
_CELL = 2.0e-3  # m, grid cell of the cached nearest-point candidates (nearest_surface)
_CELL_RANGE = 0.03  # m, cells whose centre is farther from the wire search every point
_BALL_SLACK = 1e-9  # m, widens the candidate ball against round-off at its edge
_MAX_CELLS = 20_000  # count, cached cells at most (then the cache starts afresh)
_TABLE = 1 << 15  # hash-table slots of the cell cache (> _MAX_CELLS: short probes)
_POOL = 1 << 20  # count, candidate indices the cell cache holds at most (int32: 4 MB)
# the cell cache's table rows: the cell's key (3 ints), then where its candidates are in the
# pool (first index, count; count -1: a far cell, start -1: an empty slot)
_KEY, _START, _COUNT = 0, 3, 4
ARC_TOL = 1e-9  # m, arc-length tolerance of queries just outside [0, length]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _nearest_kernel(
    pts: FloatArray, idx: np.ndarray, start: int, count: int, x: float, y: float, z: float
) -> tuple[int, float]:
    """The nearest candidate to ``(x, y, z)``, m: its row of ``pts`` (M, 3), m, and distance, m.

    The candidates are the rows ``idx[start:start + count]``, in that order; the first of
    least squared distance wins (as ``argmin``). The distance is ``√(a² + b² + c²)``.
    """
    best = idx[start]
    best_d2 = math.inf
    for i in range(start, start + count):
        r = idx[i]
        a, b, c = x - pts[r, 0], y - pts[r, 1], z - pts[r, 2]
        d2 = a * a + b * b + c * c
        if d2 < best_d2:
            best, best_d2 = r, d2
    a, b, c = x - pts[best, 0], y - pts[best, 1], z - pts[best, 2]
    return best, math.sqrt(a * a + b * b + c * c)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _cell_key(v: float) -> int:
    """``math.floor(v / _CELL)``, a grid cell's integer coordinate, with Python's errors."""
    f = v / _CELL
    if math.isnan(f):
        raise ValueError("cannot convert float NaN to integer")
    if math.isinf(f):
        raise OverflowError("cannot convert float infinity to integer")
    return math.floor(max(-4e18, min(4e18, f)))  # beyond: a far cell either way


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def surface_query(
    pts: FloatArray,
    table: np.ndarray,
    pool: np.ndarray,
    meta: np.ndarray,
    x: float,
    y: float,
    z: float,
) -> tuple[int, float]:
    """:meth:`Wire.nearest_surface`'s search: the row of ``pts`` (M, 3) nearest ``(x, y, z)``.

    Returns the row and its distance to the point, m (to the centre line). The candidates of
    the point's 2 mm grid cell (``_ball_kernel``, cached: ``table`` (``_TABLE``, 5) int64
    rows key / start / count, ``pool`` (``_POOL``,) int32 indices whose first M are every
    row, for far cells; ``meta``: cells cached, pool entries used). The
    cache starts afresh when ``_MAX_CELLS`` cells or the pool are full. ``ValueError`` /
    ``OverflowError`` for a NaN / infinite coordinate, as ``math.floor``.
    """
    kx, ky, kz = _cell_key(x), _cell_key(y), _cell_key(z)
    n = pts.shape[0]
    mask = table.shape[0] - 1
    slot = ((kx * 73856093) ^ (ky * 19349663) ^ (kz * 83492791)) & mask
    while table[slot, _START] >= 0 and not (
        table[slot, 0] == kx and table[slot, 1] == ky and table[slot, 2] == kz
    ):
        slot = (slot + 1) & mask
    if table[slot, _START] < 0:  # not cached: find the cell's candidates
        if meta[0] >= _MAX_CELLS or meta[1] + n > pool.shape[0]:
            table[:, _START] = -1  # bounded memory; cells are rebuilt on demand
            meta[0], meta[1] = 0, n
            slot = ((kx * 73856093) ^ (ky * 19349663) ^ (kz * 83492791)) & mask
        h = _CELL
        idx, d_c = _ball_kernel(pts, (kx + 0.5) * h, (ky + 0.5) * h, (kz + 0.5) * h, h)
        table[slot, 0], table[slot, 1], table[slot, 2] = kx, ky, kz
        if d_c > _CELL_RANGE:  # far from the wire: every search point
            table[slot, _START], table[slot, _COUNT] = 0, -1
        else:
            start = meta[1]
            for i in range(idx.shape[0]):  # a loop: a slice copy compiles numba's shape errors
                pool[start + i] = idx[i]
            table[slot, _START], table[slot, _COUNT] = start, idx.shape[0]
            meta[1] = start + idx.shape[0]
        meta[0] += 1
    start, count = table[slot, _START], table[slot, _COUNT]
    if count < 0:  # every search point (one signature: no literal argument to specialise on)
        start, count = 0, n
    return _nearest_kernel(pts, pool, start, count, x, y, z)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _ball_kernel(
    pts: FloatArray, x: float, y: float, z: float, h: float
) -> tuple[np.ndarray, float]:
    """A grid cell's candidates (``Wire._cell``): rows of ``pts`` (n, 3), m, near its centre.

    ``d_c`` is the centre ``(x, y, z)``'s distance to the nearest row, m; the candidates are
    the rows within ``d_c + h√3`` (``h`` the cell's edge, m), widened by ``_BALL_SLACK``
    against round-off, in increasing order. Returns the row indices (k,) and ``d_c``, m.
    """
    n = pts.shape[0]
    d2 = np.empty(n)
    least = math.inf
    for i in range(n):
        a, b, c = x - pts[i, 0], y - pts[i, 1], z - pts[i, 2]
        d2[i] = a * a + b * b + c * c
        least = min(least, d2[i])
    d_c = math.sqrt(least)
    r = d_c + h * math.sqrt(3.0) + _BALL_SLACK
    r2 = r * r
    idx = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        if d2[i] <= r2:
            idx[count] = i
            count += 1
    return idx[:count].copy(), d_c


class Wire:
    """The wire's centre line and posts.

    Parameters
    ----------
    cfg : WireConfig
        Knots (m), tube radius (m), post radius (m) and the dense polyline count.

    Attributes
    ----------
    cfg : WireConfig
        The configuration it was built from.
    """

    def __init__(self, cfg: WireConfig) -> None:
        self.cfg = cfg
        param, u, s = chord_spline(cfg.knots)
        self._length = float(s[-1])
        self._spline = make_interp_spline(s, param(u), k=3)
        self._d_spline = self._spline.derivative()
        n_search = max(int(self._length * _SEARCH_SAMPLES_PER_M), cfg.samples)
        self._search_s = np.linspace(0.0, self._length, n_search)
        self._search_pts = self._spline(self._search_s)
        self._tree = cKDTree(self._search_pts)
        # the nearest_surface cell cache (surface_query): table, pool, meta
        self._table = np.full((_TABLE, 5), -1, dtype=np.int64)
        self._pool = np.empty(max(_POOL, 2 * n_search), dtype=np.int32)
        self._pool[:n_search] = np.arange(n_search)
        self._meta = np.array([0, n_search], dtype=np.int64)
        self.query_state = (self._search_pts, self._table, self._pool, self._meta)
        """The arrays compiled kernels pass to :func:`surface_query` (read-only use)."""

    @property
    def length(self) -> float:
        """Arc length of the centre line, m."""
        return self._length

    @property
    def radius(self) -> float:
        """Wire tube radius, m."""
        return self.cfg.radius

    def _check_s(self, s: ArrayLike) -> FloatArray:
        arr = np.asarray(s, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ValueError("s must be finite")
        if np.any(arr < -ARC_TOL) or np.any(arr > self._length + ARC_TOL):
            raise ValueError(f"s must lie in [0, {self._length:.6f}] m")
        return np.clip(arr, 0.0, self._length)

    def point(self, s: float) -> FloatArray:
        """Centre-line point (3,) in world, m, at arc length ``s`` (m)."""
        return np.asarray(self._spline(float(self._check_s(s))), dtype=float)

    def points(self, s: ArrayLike) -> FloatArray:
        """Centre-line points (N, 3) in world, m, at arc lengths ``s`` (N,), m."""
        return np.asarray(self._spline(np.atleast_1d(self._check_s(s))), dtype=float)

    @overload
    def tangent(self, s: float) -> FloatArray: ...
    @overload
    def tangent(self, s: ArrayLike) -> FloatArray: ...
    def tangent(self, s: ArrayLike) -> FloatArray:
        """Unit tangent(s) in world, pointing towards increasing ``s``.

        Parameters
        ----------
        s : float or (N,)
            Arc length(s), m.

        Returns
        -------
        (3,) or (N, 3)
            Unit tangent(s), unitless.
        """
        d = np.asarray(self._d_spline(self._check_s(s)), dtype=float)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def polyline(self, n: int | None = None) -> FloatArray:
        """Dense centre line: ``n`` points (n, 3) in world, m, evenly spaced by arc length.

        ``n`` defaults to ``cfg.samples``; it must be ≥ 2.
        """
        count = self.cfg.samples if n is None else n
        if count < 2:
            raise ValueError(f"n must be ≥ 2, got {count}")
        return self.points(np.linspace(0.0, self._length, count))

    def closest(self, p_world: ArrayLike) -> tuple[float, float]:
        """Closest centre-line point to ``p_world``.

        Parameters
        ----------
        p_world : (3,)
            Query point in world, m.

        Returns
        -------
        s : float
            Arc length of the closest centre-line point, m.
        distance : float
            Distance from ``p_world`` to the centre line, m (≈1e-9 exact).
        """
        p = as_vector3(p_world, "p_world")
        _, k = self._tree.query(p)
        step = self._search_s[1]
        lo = max(0.0, self._search_s[k] - step)
        hi = min(self._length, self._search_s[k] + step)
        res = minimize_scalar(
            lambda x: float(np.sum((self._spline(x) - p) ** 2)),
            bounds=(lo, hi),
            method="bounded",
            options={"xatol": 1e-10},
        )
        s = float(res.x)
        return s, float(np.linalg.norm(self._spline(s) - p))

    def nearest_s(self, p_world: FloatArray) -> FloatArray:
        """Arc lengths (N,), m, of the search-polyline points nearest to ``p_world`` (N, 3), m.

        Resolution is the internal search spacing (0.25 mm); use :meth:`closest` for exact.
        """
        return np.asarray(self._search_s[self.nearest_index(p_world)], dtype=float)

    def nearest_index(self, p_world: FloatArray) -> NDArray[np.intp]:
        """Indices (N,) of the :attr:`search_points` nearest to ``p_world`` (N, 3), m."""
        _, k = self._tree.query(np.atleast_2d(p_world))
        return np.asarray(k, dtype=np.intp)

    def surface_distance(self, p_world: ArrayLike) -> FloatArray:
        """Distance (N,) from points (N, 3) in world, m, to the wire's tube surface, m.

        Negative inside the tube. Measured to the nearest point of the internal search polyline,
        so it overestimates by at most half its spacing (≤ 0.125 mm); use :meth:`closest` for
        exact. Vectorised: a whole episode's camera positions in one call.
        """
        p = np.asarray(p_world, dtype=float).reshape(-1, 3)
        d, _ = self._tree.query(p)
        return np.asarray(d, dtype=float) - self.cfg.radius

    def nearest_surface(self, p_world: Sequence[float]) -> tuple[float, int]:
        """One point's distance to the tube surface, m, and its nearest search-polyline index.

        The control loop's query on plain floats: ``p_world`` (3,) in world, m. Near the wire
        the candidates of its 2 mm grid cell (cached) are searched instead of the KD-tree, with
        the tree's answer (``tests/test_task_wire.py``), by compiled kernels
        (:func:`surface_query`; ~1 µs a query near the wire, ``bench/bench_clearance.py``);
        far from it every search point is tried (a few µs). Every candidate of a cell lies
        within ``d(c) + h√3`` of its centre ``c`` (``_ball_kernel``), so the argmin over them
        is the tree's answer; cells farther than ``_CELL_RANGE`` from the wire search all the
        points (their balls would hold too many). Same resolution as
        :meth:`surface_distance` (≤ 0.125 mm over); the index points into
        :attr:`search_points`.
        """
        j, dist = surface_query(*self.query_state, p_world[0], p_world[1], p_world[2])
        return dist - self.cfg.radius, j

    def forget_cells(self) -> None:
        """Empty the cell cache of :meth:`nearest_surface` (benchmarks: time new cells)."""
        self._table[:, _START] = -1
        self._meta[:] = (0, self._search_pts.shape[0])

    @property
    def search_spacing(self) -> float:
        """Arc-length spacing of the internal nearest-point search polyline, m."""
        return float(self._search_s[1])

    @property
    def search_arc_length(self) -> FloatArray:
        """(M,) arc lengths of the internal search polyline (spacing ≤ 0.25 mm), m. Read-only."""
        view = self._search_s.view()
        view.flags.writeable = False
        return view

    @property
    def search_points(self) -> FloatArray:
        """(M, 3) centre-line points at :attr:`search_arc_length`, world, m. Read-only."""
        view = self._search_pts.view()
        view.flags.writeable = False
        return view

    @property
    def post_tops(self) -> FloatArray:
        """(2, 3) the wire's two ends in world, m (tops of the posts)."""
        return self.points(np.array([0.0, self._length]))

    @property
    def post_bases(self) -> FloatArray:
        """(2, 3) the posts' feet on the board (z = 0), m, vertically under the wire's ends."""
        base = self.post_tops.copy()
        base[:, 2] = 0.0
        return base
