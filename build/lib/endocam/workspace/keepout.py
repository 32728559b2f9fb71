"""The wire's keep-out zone: its compiled distance queries and their named state.

The camera must stay ``clearance`` away from the wire's surface (``control.clearance``'s
``ClearanceGuard`` builds the zone from a :class:`~endocam.task.wire.Wire`). The compiled queries
here take the zone as one named :class:`KeepOutState`: the wire's nearest-point search
(``Wire.query_state``), the tube radius, a small Lipschitz cache of recent queries and the
clearance. Both the controllers (goals kept clear) and the carriers (the workspace they keep the
camera in, :mod:`endocam.workspace.region`) ask it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple, Protocol

import numpy as np
from numba import njit
from numpy.typing import NDArray

from endocam.geometry import FloatArray
from endocam.kernels import dist3
from endocam.task.wire import surface_query

__all__ = [
    "CACHE_SIZE",
    "NO_KEEP_OUT",
    "KeepOut",
    "KeepOutState",
    "NearestWire",
    "keep_out_distance",
    "keep_out_first_outside",
    "keep_out_nearest",
    "remember",
]

CACHE_SIZE = 2  # count, queries kept for the Lipschitz bound (the goal's and the camera's)
IntArray = NDArray[np.integer]


class KeepOutState(NamedTuple):
    """The keep-out zone as compiled queries read it (one named argument).

    Attributes
    ----------
    points : (M, 3) float
        The wire's search points, world, m (``Wire.query_state``).
    table, pool, meta : int arrays
        The search's cell cache (``Wire.query_state``).
    radius : float
        The wire's tube radius, m.
    ref : (CACHE_SIZE, 4) float
        Recent queries, newest first: point (world, m) and its surface distance, m.
    nref : (1,) int
        Rows of ``ref`` in use.
    clearance : float
        How far from the wire's surface the camera must stay, m.
    """

    points: FloatArray
    table: IntArray
    pool: IntArray
    meta: IntArray
    radius: float
    ref: FloatArray
    nref: IntArray
    clearance: float


NO_KEEP_OUT = KeepOutState(
    np.zeros((1, 3)),
    np.full((2, 5), -1, dtype=np.int64),
    np.zeros(1, dtype=np.int32),
    np.array([0, 1], dtype=np.int64),
    0.0,
    np.zeros((CACHE_SIZE, 4)),
    np.zeros(1, dtype=np.int64),
    0.0,
)
"""A compiled caller's placeholder without a zone (the same types; never read)."""


class KeepOut(Protocol):
    """A region the camera must stay out of (``control.clearance.ClearanceGuard``: the wire)."""

    @property
    def kernel_state(self) -> KeepOutState:
        """Its compiled queries' state; the cache is shared with :meth:`margin`."""
        ...

    def margin(self, p_world: Sequence[float]) -> float:
        """Signed clearance of a camera position (3,), world, m: ≥ 0 outside the region."""
        ...

    def first_outside(self, p_world: FloatArray, count: int) -> int:
        """The first of ``p_world[:count]`` whose :meth:`margin` is not ≥ 0, else ``count``.

        ``p_world`` (N, 3): camera positions, world, m. As :meth:`margin` called on each in
        turn would find it, any cache it keeps left as those calls leave it.
        """
        ...


class NearestWire(NamedTuple):
    """:func:`keep_out_nearest`'s answer."""

    row: int  # the row of the zone's ``points`` nearest to the point asked
    surface: float  # m, the point's exact distance to the tube's surface


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def keep_out_nearest(zone: KeepOutState, x: float, y: float, z: float) -> NearestWire:
    """The wire's search point nearest to ``(x, y, z)`` (world, m) and its surface distance.

    One exact query (``Wire.nearest_surface``'s), not remembered in the zone's cache.
    """
    k, dist = surface_query(zone.points, zone.table, zone.pool, zone.meta, x, y, z)
    return NearestWire(k, dist - zone.radius)


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def remember(ref: FloatArray, nref: IntArray, x: float, y: float, z: float, d: float) -> None:
    """Keep a query, point ``(x, y, z)``, m, surface distance ``d``, m: the newest first."""
    for r in range(ref.shape[0] - 1, 0, -1):
        for c in range(4):
            ref[r, c] = ref[r - 1, c]
    ref[0, 0], ref[0, 1], ref[0, 2], ref[0, 3] = x, y, z, d
    nref[0] = min(nref[0] + 1, ref.shape[0])


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def keep_out_distance(
    zone: KeepOutState, x: float, y: float, z: float, exact_below: float
) -> float:
    """Distance of ``(x, y, z)`` (world, m) to the zone's tube surface, m; NaN if not finite.

    A cached query's Lipschitz lower bound is returned when it already exceeds
    ``clearance + exact_below`` (m); otherwise the exact distance, remembered.
    """
    if not math.isfinite(x + y + z):
        return math.nan
    ref = zone.ref
    for r in range(zone.nref[0]):
        bound = ref[r, 3] - dist3(x, y, z, ref[r, 0], ref[r, 1], ref[r, 2])
        if bound >= zone.clearance + exact_below:
            return bound  # a lower bound that already clears
    _, dist = surface_query(zone.points, zone.table, zone.pool, zone.meta, x, y, z)
    d = dist - zone.radius
    remember(ref, zone.nref, x, y, z, d)
    return d


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def keep_out_first_outside(zone: KeepOutState, p: FloatArray, count: int) -> int:
    """The first of the rows ``p[:count]`` ((N, 3), world, m) inside the zone; else ``count``."""
    for i in range(count):
        d = keep_out_distance(zone, p[i, 0], p[i, 1], p[i, 2], 0.0)
        if not d - zone.clearance >= 0.0:
            return i
    return count
