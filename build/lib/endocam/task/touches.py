r"""Ground-truth ring–wire touches from the exact clearance of two tubes.

The ring is a torus: the tube of radius ``r`` around its core circle (centre ``c``, unit normal
``n`` = ring z, radius ``R``). The wire is the tube of radius ``r_w`` around its centre line
``w(s)``. Their clearance is

.. math::

    \operatorname{clearance} = \min_s \, d_\circ\bigl(w(s)\bigr) - r - r_w, \qquad
    d_\circ(p) = \sqrt{h^2 + (\rho - R)^2},\; h = (p - c)\cdot n,\;
    \rho = \lVert (p - c) - h\,n \rVert,

the distance between the two centre curves minus both radii: positive is a gap, zero is a touch,
negative is the overlap depth. The minimum over ``s`` is found on a 0.25 mm polyline near the ring
and refined with scipy's elementwise bracketing minimiser (``xatol`` 1e-9 m), so values are exact
to ~1e-9 m (a few µm in the rare case where two near-equal local minima sit in different bins).
A touch is ``clearance ≤ 0``. The result depends only on the ring trajectory and the wire, never on
a camera policy.

Sampling bound: every point of the ring lies within ``R + r`` of its centre, so the clearance
changes no faster than ``L = max(|v| + |ω| (R + r))`` (m/s, from the trajectory's splines, times a
safety factor ``SPEED_MARGIN``). Between two samples ``Δt`` apart with clearances ``c₀, c₁ > 0`` the
clearance stays above ``(c₀ + c₁ − L Δt) / 2``, so a touch can hide there only if
``|c₀| + |c₁| < L Δt``; the same test bounds a hidden release inside a contact and extra
crossings inside a sign change. Every such interval is re-sampled ``REFINE``-fold, recursively,
until ``L Δt / 2 ≤ DEPTH_TOL``. So no touch deeper than ``DEPTH_TOL`` is missed (nor two touches
merged across a gap wider than ``DEPTH_TOL``), and event start/end times are root-found to 1e-6 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import elementwise, minimize_scalar

from endocam.geometry import FloatArray, as_pose, as_vector3
from endocam.kernels import dot3
from endocam.task.config import RingConfig
from endocam.task.wire import Wire


class RingPath(Protocol):
    """What touch detection reads of a ring's path (``task.trajectory.RingTrajectory`` is one)."""

    @property
    def duration(self) -> float:
        """Length of the path, s."""
        ...

    def poses(self, ts: ArrayLike) -> FloatArray:
        """Ring poses (N, 4, 4), world, m, at the times ``ts`` (N,), s."""
        ...

    def max_point_speed(self, ts: ArrayLike, radius: float) -> float:
        """Largest speed over ``ts`` (s) of any point within ``radius`` (m) of the centre, m/s."""
        ...


DEFAULT_TOUCH_DT = 2.0e-3  # s, base clearance sampling step (see TrajectoryConfig)
DEPTH_TOL = 1.0e-6  # m, touches shallower than this may go unseen between samples
SPEED_MARGIN = 1.25  # unitless, safety factor on the sampled maximum surface-point speed
REFINE = 8  # count, sub-intervals per refinement of a suspicious interval
X_TOL = 1e-9  # m, arc-length tolerance of the local refinement
T_TOL = 1e-6  # s, time tolerance of event start/end root finding (≪ 1 µm of ring motion)
COARSE_STEP = 0.5e-3  # m, arc-length step of the coarse search before refinement
WINDOW_FACTOR = 3.0  # unitless, searched arc length each side, in units of R + r + r_w
_SCALAR_LIMIT = 4  # poses, below this refine with scalar Brent instead of the array method
_CHUNK = 2048  # poses per block; a last block of ≤ _SCALAR_LIMIT poses refines with Brent
_EPS = 1e-15  # m, below this a direction is undefined
_SKIP_MARGIN = 1e-12  # m, the coarse search skips points only this much beyond the best
_REACH_SLACK = 1e-6  # unitless, widening of the polyline's longest chord (round-off)
_LANES = 8  # poses the coarse search advances together (instruction-level parallelism)


@dataclass(frozen=True)
class TouchEvent:
    """One touch: a maximal time interval with ``clearance ≤ 0``.

    Attributes
    ----------
    t_start, t_end : float
        First and last instant of contact, s.
    p_world_contact : (3,)
        Contact point in world, m, at the deepest sampled instant: the midpoint of the gap (or
        overlap) between the wire's and the ring's surfaces along their shortest connection.
    min_clearance : float
        Deepest sampled clearance (≤ 0), m.
    """

    t_start: float
    t_end: float
    p_world_contact: FloatArray
    min_clearance: float

    @property
    def duration(self) -> float:
        """Length of the touch, s."""
        return self.t_end - self.t_start


@dataclass(frozen=True)
class TouchReport:
    """Ground-truth touches of one trajectory.

    Attributes
    ----------
    events : list of TouchEvent
        Touches in time order.
    t : (K,)
        Sample times, s, sorted; uniform at ``dt`` except where refined.
    clearance : (K,)
        Clearance at ``t``, m.
    in_contact : (K,)
        ``clearance ≤ 0``.
    dt : float
        Base sampling step, s.
    max_point_speed : float
        Lipschitz bound ``L`` used for refinement, m/s.
    """

    events: list[TouchEvent]
    t: FloatArray
    clearance: FloatArray
    in_contact: NDArray[np.bool_]
    dt: float
    max_point_speed: float = field(default=0.0)

    @property
    def count(self) -> int:
        """Number of touch events."""
        return len(self.events)

    @property
    def duration(self) -> float:
        """Time covered by the samples, s (the trajectory's duration)."""
        return float(self.t[-1] - self.t[0]) if self.t.size else 0.0

    @property
    def contact_fraction(self) -> float:
        """Time in contact over the duration, unitless in [0, 1] (0 for a zero duration)."""
        span = self.duration
        if span <= 0.0:
            return 0.0
        return float(sum(e.duration for e in self.events) / span)


@register_jitable  # inlined into the compiled kernels below (the same source)
def _circle_distance(
    dx: float, dy: float, dz: float, n0: float, n1: float, n2: float, major: float
) -> float:
    """Distance, m, of ``c + (dx, dy, dz)`` to the core circle (centre ``c``, normal ``n``).

    ``√(h² + (ρ − R)²)`` with ``h = d·n``, ``ρ² = |d|² − h²`` (clamped at 0), m.
    """
    h = dx * n0 + dy * n1 + dz * n2
    rho = math.sqrt(max(dx * dx + dy * dy + dz * dz - h * h, 0.0))
    e = rho - major
    return math.sqrt(h * h + e * e)


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def _core_distance_kernel(
    p: FloatArray, c: FloatArray, n: FloatArray, k: NDArray[np.intp], major: float
) -> FloatArray:
    """Distances, m, from points ``p`` (N, 3) to the core circles ``k`` (N,) of ``c``, ``n``.

    Circle ``k[i]`` has centre ``c[k[i]]`` and unit normal ``n[k[i]]`` ((M, 3) each, m) and
    radius ``major`` (m).
    """
    out = np.empty(p.shape[0])
    for i in range(p.shape[0]):
        j = k[i]
        dx, dy, dz = p[i, 0] - c[j, 0], p[i, 1] - c[j, 1], p[i, 2] - c[j, 2]
        out[i] = _circle_distance(dx, dy, dz, n[j, 0], n[j, 1], n[j, 2], major)
    return out


def _coarse_minimiser(
    xyz: tuple[FloatArray, FloatArray, FloatArray],
    start: NDArray[np.intp],
    offsets: NDArray[np.intp],
    c: FloatArray,
    n: FloatArray,
    major: float,
    reach: float,
) -> NDArray[np.intp]:
    """Each pose's search point nearest to its core circle, among a window of the polyline.

    Pose ``i`` searches the points ``start[i] + offsets`` ((N,), (k,) ints, increasing
    offsets), clipped to the polyline ``xyz`` ((M,) contiguous columns each, m): its answer is
    the first least of the distances :func:`_core_distance_kernel` gives on arrays (numpy's
    argmin of them, ties included), compiled (:func:`_coarse_kernel`). ``reach`` (m) bounds the
    distance between the points of two neighbouring offsets (:func:`_search_polyline`).
    Centres and normals ``c``, ``n`` are (N, 3), m (C-contiguous). Returns (N,) indices.
    """
    start = np.ascontiguousarray(start, dtype=np.intp)
    offsets = np.ascontiguousarray(offsets, dtype=np.intp)
    return _coarse_kernel(xyz[0], xyz[1], xyz[2], start, offsets, c, n, major, reach)


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def _coarse_kernel(
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
    start: NDArray[np.intp],
    offsets: NDArray[np.intp],
    c: FloatArray,
    n: FloatArray,
    major: float,
    reach: float,
) -> NDArray[np.intp]:
    """:func:`_coarse_minimiser`'s loop: per pose, the first least core distance's index.

    Each distance is :func:`_circle_distance`'s. Branch and bound, with the
    same answer as the full scan: the middle offset's distance is the first bound; a point
    ``d`` (m) from the circle puts the points of the next ``u`` offsets at least
    ``d − u · reach`` from it (a distance to a set is 1-Lipschitz), so those that cannot come
    within ``_SKIP_MARGIN`` of the best so far are skipped (they are strictly farther: never
    the least, nor a tie). Of equal least distances the first offset wins, as numpy's argmin.
    """
    count = start.shape[0]
    out = np.empty(count, dtype=np.intp)
    last = x.shape[0] - 1
    width = offsets.shape[0]
    mid = width // 2
    # _LANES poses at a time, one step of each in turn: their searches overlap in the CPU
    col = np.empty(_LANES, dtype=np.intp)  # next offset to look at, per lane
    best_col = np.empty(_LANES, dtype=np.intp)
    best_k = np.empty(_LANES, dtype=np.intp)
    best_d = np.empty(_LANES)
    for base in range(0, count, _LANES):
        lanes = min(_LANES, count - base)
        for a in range(lanes):
            i = base + a
            k = min(max(start[i] + offsets[mid], 0), last)
            dx, dy, dz = x[k] - c[i, 0], y[k] - c[i, 1], z[k] - c[i, 2]
            best_d[a] = _circle_distance(dx, dy, dz, n[i, 0], n[i, 1], n[i, 2], major)
            best_k[a], best_col[a], col[a] = k, mid, 0
        busy = lanes
        while busy > 0:
            busy = 0
            for a in range(lanes):
                j = col[a]
                if j >= width:
                    continue
                busy += 1
                if j != mid:
                    i = base + a
                    k = min(max(start[i] + offsets[j], 0), last)
                    dx, dy, dz = x[k] - c[i, 0], y[k] - c[i, 1], z[k] - c[i, 2]
                    d = _circle_distance(dx, dy, dz, n[i, 0], n[i, 1], n[i, 2], major)
                    if d < best_d[a] or (d == best_d[a] and j < best_col[a]):
                        best_k[a], best_col[a], best_d[a] = k, j, d
                    q = (d - best_d[a] - _SKIP_MARGIN) / reach
                    if q >= 1.0:  # the next int(q) offsets stay farther than best_d: skipped
                        j += int(q) if q < width else width
                col[a] = j + 1
        for a in range(lanes):
            out[base + a] = best_k[a]
    return out


def _contact_point(
    p_wire: FloatArray, T_world_ring: FloatArray, ring_cfg: RingConfig, wire_radius: float
) -> tuple[FloatArray, FloatArray]:
    """Clearance (N,), m, and contact points (N, 3), m, for wire points (N, 3) and poses."""
    return _contact_kernel(
        np.ascontiguousarray(p_wire),
        np.ascontiguousarray(T_world_ring),
        ring_cfg.major_radius,
        ring_cfg.minor_radius,
        wire_radius,
    )


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def _contact_kernel(
    p: FloatArray, T: FloatArray, major: float, minor: float, wire_radius: float
) -> tuple[FloatArray, FloatArray]:
    """:func:`_contact_point`'s loop: clearances (N,) and contact points (N, 3), m.

    Per pose (centre ``c``, normal ``n``, wire point ``p``, ``d = p − c``): the height
    ``h = d · n``, the radial direction ``d − h n`` (the ring's x axis when ``p`` is on its
    axis) and its length ``ρ``, the core point ``q = c + R (d − h n) / ρ``, the gap ``q − p``
    (along ``n`` when ``p`` is on the core circle), the clearance ``|q − p| − r − r_w`` and the
    contact point ``p + (gap / |gap|) (r_w + clearance / 2)``.
    """
    count = p.shape[0]
    clearance = np.empty(count)
    p_contact = np.empty((count, 3))
    for i in range(count):
        c0, c1, c2 = T[i, 0, 3], T[i, 1, 3], T[i, 2, 3]
        n0, n1, n2 = T[i, 0, 2], T[i, 1, 2], T[i, 2, 2]
        p0, p1, p2 = p[i, 0], p[i, 1], p[i, 2]
        hi = dot3(p0 - c0, p1 - c1, p2 - c2, n0, n1, n2)
        r0, r1, r2 = (p0 - c0) - hi * n0, (p1 - c1) - hi * n1, (p2 - c2) - hi * n2
        rho = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if rho < _EPS:
            r0, r1, r2, rho = T[i, 0, 0], T[i, 1, 0], T[i, 2, 0], 1.0
        g0 = (c0 + major * r0 / rho) - p0
        g1 = (c1 + major * r1 / rho) - p1
        g2 = (c2 + major * r2 / rho) - p2
        dist = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        cl = dist - minor - wire_radius
        if dist < _EPS:
            g0, g1, g2, dist = n0, n1, n2, 1.0
        scale = wire_radius + 0.5 * cl
        clearance[i] = cl
        p_contact[i, 0] = p0 + g0 / dist * scale
        p_contact[i, 1] = p1 + g1 / dist * scale
        p_contact[i, 2] = p2 + g2 / dist * scale
    return clearance, p_contact


def _refine(
    wire: Wire,
    ring_cfg: RingConfig,
    g: NDArray[np.intp],
    step: int,
    c: FloatArray,
    n: FloatArray,
    scalar: NDArray[np.bool_] | None = None,
) -> FloatArray:
    """Refine coarse minimisers (search indices ``g`` (N,)) for centres/normals (N, 3); s, m.

    ``scalar`` (N,) marks the poses refined one by one with scalar Brent (by default all of
    them when there are at most ``_SCALAR_LIMIT``, where it is cheaper than the array method);
    the others are refined together by one ``find_minimum``. Each pose's result depends only on
    its own inputs and its method (scipy's elementwise solvers iterate each element on its
    own), not on the batch it is refined in. ``c``, ``n`` are C-contiguous.
    """
    s_all = wire.search_arc_length
    pts = wire.search_points
    m = s_all.size
    s_best = s_all[g].copy()
    lo = np.maximum(g - step, 0)
    hi = np.minimum(g + step, m - 1)
    major = ring_cfg.major_radius
    if scalar is None:
        scalar = np.full(g.size, g.size <= _SCALAR_LIMIT)
    for i in np.flatnonzero(scalar).tolist():
        k = np.array([i], dtype=np.intp)

        def one(s: float, k: NDArray[np.intp] = k) -> float:
            return float(_core_distance_kernel(wire.point(s)[None], c, n, k, major)[0])

        res = minimize_scalar(
            one, bounds=(s_all[lo[i]], s_all[hi[i]]), method="bounded", options={"xatol": X_TOL}
        )
        if res.fun <= _core_distance_kernel(pts[g[i : i + 1]], c, n, k, major)[0]:
            s_best[i] = float(res.x)
    inner = np.flatnonzero((g > 0) & (g < m - 1) & ~scalar)
    if inner.size:
        # the minimiser's first calls are at the bracket (lo, g, hi): search points, whose
        # distances are computed here from the search polyline (the spline at those arc lengths)
        brackets = (s_all[lo[inner]], s_best[inner], s_all[hi[inner]])
        known = [
            (x, _core_distance_kernel(pts[j], c, n, inner, major))
            for x, j in zip(brackets, (lo[inner], g[inner], hi[inner]), strict=True)
        ]

        def objective(s: FloatArray, k: NDArray[np.intp]) -> FloatArray:
            # ``k`` shrinks with the still-active elements; it indexes the poses
            for j, (x, f) in enumerate(known):
                if s.shape == x.shape and np.array_equal(s, x) and np.array_equal(k, inner):
                    del known[j]
                    return f
            known.clear()  # past the bracket: every later call is evaluated
            p = wire.points(s.ravel())
            return _core_distance_kernel(p, c, n, k.ravel(), major).reshape(s.shape)

        res = elementwise.find_minimum(
            objective,
            brackets,
            args=(inner,),
            tolerances={"xatol": X_TOL, "xrtol": 0.0, "fatol": 0.0, "frtol": 0.0},
        )
        ok = np.asarray(res.success)
        s_best[inner[ok]] = np.asarray(res.x)[ok]
    return s_best


def _search_polyline(
    wire: Wire, step: int
) -> tuple[tuple[FloatArray, FloatArray, FloatArray], float]:
    """The search polyline's x, y, z columns ((M,) each, contiguous), m, and a reach, m.

    The reach bounds the distance between two search points at most ``step`` indices apart:
    ``step`` times the longest chord of the polyline, widened by ``_REACH_SLACK`` against
    round-off (the triangle inequality does the rest).
    """
    pts = wire.search_points
    chord = float(np.max(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
    reach = step * chord * (1.0 + _REACH_SLACK) + _SKIP_MARGIN
    return (pts[:, 0].copy(), pts[:, 1].copy(), pts[:, 2].copy()), reach


def _chunk_scalar(count: int) -> NDArray[np.bool_]:
    """Which of ``count`` poses :func:`clearances` refines with scalar Brent: (count,).

    Those of a block of at most ``_SCALAR_LIMIT`` poses (the last block of ``_CHUNK``).
    """
    scalar = np.zeros(count, dtype=bool)
    for a in range(0, count, _CHUNK):
        b = min(a + _CHUNK, count)
        scalar[a:b] = b - a <= _SCALAR_LIMIT
    return scalar


def clearances(
    T_world_ring: FloatArray, wire: Wire, ring_cfg: RingConfig
) -> tuple[FloatArray, FloatArray]:
    """Ring–wire clearance for a stack of ring poses (vectorised).

    Only the wire within ``3 (R + r + r_w)`` of arc length around the wire point nearest to each
    ring centre is searched; this finds every contact as long as the wire does not come back
    within ``2 (R + r + r_w)`` of itself farther along (true of any wire with bends wider than
    the ring). Far from the wire the value is an upper bound that stays positive.

    Parameters
    ----------
    T_world_ring : (N, 4, 4)
        Ring poses in world, m.
    wire : Wire
    ring_cfg : RingConfig

    Returns
    -------
    clearance : (N,)
        Clearance, m (negative: overlap depth).
    p_world_contact : (N, 3)
        Contact (closest-approach) points in world, m.
    """
    T = np.asarray(T_world_ring, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_world_ring must be a finite (N, 4, 4) array, got {T.shape}")
    return _clearances(T, wire, ring_cfg, _chunk_scalar(T.shape[0]))


def _clearances(
    T: FloatArray, wire: Wire, ring_cfg: RingConfig, scalar: NDArray[np.bool_]
) -> tuple[FloatArray, FloatArray]:
    """:func:`clearances` of finite poses ``T`` (N, 4, 4), m, refined as ``scalar`` (N,) says."""
    reach = ring_cfg.major_radius + ring_cfg.minor_radius + wire.radius
    step = max(1, int(COARSE_STEP / wire.search_spacing))
    half = math.ceil(WINDOW_FACTOR * reach / wire.search_spacing / step) * step
    offsets = np.arange(-half, half + 1, step)
    c, n = np.ascontiguousarray(T[:, :3, 3]), np.ascontiguousarray(T[:, :3, 2])
    xyz, bound = _search_polyline(wire, step)
    k = wire.nearest_index(c)  # the window's centre: the search point nearest the ring centre
    g = _coarse_minimiser(xyz, k, offsets, c, n, ring_cfg.major_radius, bound)
    s_best = _refine(wire, ring_cfg, g, step, c, n, scalar)  # then all together
    return _contact_point(wire.points(s_best), T, ring_cfg, wire.radius)


def clearance(
    T_world_ring: FloatArray, wire: Wire, ring_cfg: RingConfig
) -> tuple[float, FloatArray]:
    """Exact ring–wire clearance for one ring pose, searching the whole wire.

    Parameters
    ----------
    T_world_ring : (4, 4)
        Ring pose in world, m.
    wire : Wire
    ring_cfg : RingConfig

    Returns
    -------
    clearance : float
        Distance between the torus tube and the wire tube, m (negative: overlap depth).
    p_world_contact : (3,)
        Contact (closest-approach) point in world, m.
    """
    T = np.asarray(T_world_ring, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_world_ring must be a finite (4, 4) array, got {T.shape}")
    step = max(1, int(COARSE_STEP / wire.search_spacing))
    idx = np.arange(0, wire.search_arc_length.size, step)
    idx = np.unique(np.append(idx, wire.search_arc_length.size - 1))
    T = T[None]
    c, n = np.ascontiguousarray(T[:, :3, 3]), np.ascontiguousarray(T[:, :3, 2])
    xyz, reach = _search_polyline(wire, step)
    g = _coarse_minimiser(xyz, np.zeros(1, dtype=np.intp), idx, c, n, ring_cfg.major_radius, reach)
    s_best = _refine(wire, ring_cfg, g, step, c, n)
    cl, p = _contact_point(wire.points(s_best), T, ring_cfg, wire.radius)
    return float(cl[0]), p[0]


def touch_events(
    trajectory: RingPath,
    wire: Wire,
    ring_cfg: RingConfig,
    dt: float = DEFAULT_TOUCH_DT,
) -> TouchReport:
    """Ground-truth touch events of a ring trajectory (see the module docstring for the bound).

    Parameters
    ----------
    trajectory : RingPath
    wire : Wire
    ring_cfg : RingConfig
    dt : float
        Base sampling step, s (> 0).

    Returns
    -------
    TouchReport
    """
    if not math.isfinite(dt) or dt <= 0.0:
        raise ValueError(f"dt must be a positive number of seconds, got {dt}")
    n = math.ceil(trajectory.duration / dt) + 1
    t = np.linspace(0.0, trajectory.duration, n)
    c, p = clearances(trajectory.poses(t), wire, ring_cfg)
    scalar = _chunk_scalar(t.size)  # each sample's refinement method (see _events)
    speed = SPEED_MARGIN * trajectory.max_point_speed(
        t, ring_cfg.major_radius + ring_cfg.minor_radius
    )
    while True:
        gap = np.diff(t)
        suspicious = (np.abs(c[:-1]) + np.abs(c[1:]) < speed * gap) & (
            0.5 * speed * gap > DEPTH_TOL
        )
        if not np.any(suspicious):
            break
        frac = np.arange(1, REFINE) / REFINE
        t_new = (t[:-1][suspicious, None] + gap[suspicious, None] * frac).ravel()
        c_new, p_new = clearances(trajectory.poses(t_new), wire, ring_cfg)
        order = np.argsort(np.concatenate([t, t_new]), kind="stable")
        t = np.concatenate([t, t_new])[order]
        c = np.concatenate([c, c_new])[order]
        p = np.concatenate([p, p_new])[order]
        scalar = np.concatenate([scalar, _chunk_scalar(t_new.size)])[order]
    in_contact = c <= 0.0
    events = _events(trajectory, wire, ring_cfg, t, c, p, in_contact, scalar)
    return TouchReport(events, t, c, in_contact, float(dt), float(speed))


def _events(
    trajectory: RingPath,
    wire: Wire,
    ring_cfg: RingConfig,
    t: FloatArray,
    c: FloatArray,
    p: FloatArray,
    in_contact: NDArray[np.bool_],
    scalar: NDArray[np.bool_],
) -> list[TouchEvent]:
    """Maximal contact runs of the samples, with start/end times root-found together.

    The root finder's first two calls are at the brackets' ends, samples whose clearance is
    known: they are answered from ``c`` when each sample was refined by the method
    (``scalar`` (K,)) that call would use, so a fresh computation would give the same values.
    """
    flag = np.concatenate([[False], in_contact, [False]]).astype(np.int8)
    starts = np.flatnonzero(np.diff(flag) == 1)
    ends = np.flatnonzero(np.diff(flag) == -1) - 1
    # brackets [t_before, t_after] around each sign change (clearance > 0 → ≤ 0 or back)
    rise = starts[starts > 0]
    fall = ends[ends < t.size - 1]
    lo = np.concatenate([t[rise - 1], t[fall]])
    hi = np.concatenate([t[rise], t[fall + 1]])
    roots = np.empty(0)
    if lo.size:
        sampled = [(lo, np.concatenate([rise - 1, fall])), (hi, np.concatenate([rise, fall + 1]))]

        def c_of_t(time: FloatArray) -> FloatArray:
            flat = time.ravel()
            for x, j in sampled:
                if (
                    flat.shape == x.shape
                    and np.array_equal(flat, x)
                    and np.array_equal(scalar[j], _chunk_scalar(x.size))
                ):
                    return c[j].reshape(time.shape)
            return clearances(trajectory.poses(flat), wire, ring_cfg)[0].reshape(time.shape)

        res = elementwise.find_root(c_of_t, (lo, hi), tolerances={"xatol": T_TOL, "xrtol": 0.0})
        # a failed bracket (clearance exactly 0 at a sample) keeps the in-contact sample's time
        fallback = np.concatenate([t[rise], t[fall]])
        roots = np.where(np.asarray(res.success), np.asarray(res.x), fallback)
    t_rise = dict(zip(rise.tolist(), roots[: rise.size].tolist(), strict=True))
    t_fall = dict(zip(fall.tolist(), roots[rise.size :].tolist(), strict=True))
    events = []
    for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
        k = a + int(np.argmin(c[a : b + 1]))
        t0 = t_rise.get(a, float(t[0]))
        t1 = t_fall.get(b, float(t[-1]))
        events.append(TouchEvent(float(t0), float(t1), p[k].copy(), float(c[k])))
    return events


_EPS_DIRECTION = 1e-12  # m, below this a direction is undefined


def contact_normal(
    p_world_contact: ArrayLike, T_world_ring: ArrayLike, major_radius: float
) -> FloatArray:
    """Unit contact normal at a ring–wire contact point, pointing from the wire to the ring.

    The contact point lies on the shortest segment from the wire's centre line to the ring's core
    circle (:mod:`endocam.task.touches`), so the normal is the direction from the point to its
    nearest core-circle point.

    Parameters
    ----------
    p_world_contact : (3,)
        Contact point in world, m.
    T_world_ring : (4, 4)
        Ring pose (z = face normal), m.
    major_radius : float
        Core-circle radius R, m (> 0).

    Returns
    -------
    (3,)
        Unit vector in world.

    Raises
    ------
    ValueError
        If the point is on the ring's axis or on its core circle (normal undefined).
    """
    p = as_vector3(p_world_contact, "p_world_contact")
    T = as_pose(T_world_ring, "T_world_ring")
    if not math.isfinite(major_radius) or major_radius <= 0.0:
        raise ValueError(f"major_radius must be > 0 m, got {major_radius}")
    c, n = T[:3, 3], T[:3, 2]
    d = p - c
    radial = d - (d @ n) * n
    rho = float(np.linalg.norm(radial))
    if rho < _EPS_DIRECTION:
        raise ValueError("p_world_contact lies on the ring's axis: contact normal undefined")
    q = c + major_radius * radial / rho
    u = q - p
    dist = float(np.linalg.norm(u))
    if dist < _EPS_DIRECTION:
        raise ValueError("p_world_contact lies on the ring's core circle: contact normal undefined")
    return u / dist
