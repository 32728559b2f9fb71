"""The ground-truth touch detection as main ran it before round 7 (tests' reference).

A copy of ``endocam.task.touches`` at main before r7-touch (``_core_distance``, ``_refine``,
``clearances``, ``clearance``, ``touch_events``, ``_events``), its compiled coarse search
replaced by numpy's argmin of ``_core_distance`` (the kernel was pinned to it, first of equal
values included). ``tests/test_task_touches.py`` pins the current detection to it bit for
bit: one ``find_minimum`` / ``find_root`` call per clearance batch, as it was.
"""

# mypy: ignore-errors

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import elementwise, minimize_scalar

from endocam.geometry import FloatArray
from endocam.task.config import RingConfig
from endocam.task.touches import (
    _CHUNK,
    _EPS,
    _SCALAR_LIMIT,
    COARSE_STEP,
    DEFAULT_TOUCH_DT,
    DEPTH_TOL,
    REFINE,
    SPEED_MARGIN,
    T_TOL,
    WINDOW_FACTOR,
    X_TOL,
    TouchEvent,
    TouchReport,
)
from endocam.task.wire import Wire


def _core_distance(p: FloatArray, c: FloatArray, n: FloatArray, major: float) -> FloatArray:
    """Distance, m, from points ``p`` (…, 3) to core circles (centres ``c``, normals ``n``)."""
    dx = p[..., 0] - c[..., 0]  # component-wise: several times faster than reductions on axis -1
    dy = p[..., 1] - c[..., 1]
    dz = p[..., 2] - c[..., 2]
    h = dx * n[..., 0] + dy * n[..., 1] + dz * n[..., 2]
    rho = np.sqrt(np.maximum(dx * dx + dy * dy + dz * dz - h * h, 0.0))
    return np.asarray(np.sqrt(h * h + (rho - major) ** 2), dtype=float)


def _coarse_minimiser(
    xyz: tuple[FloatArray, FloatArray, FloatArray],
    idx: NDArray[np.intp],
    c: FloatArray,
    n: FloatArray,
    major: float,
) -> NDArray[np.intp]:
    """The first least core distance's index in ``idx`` (N, k) per pose (numpy's argmin)."""
    pts = np.column_stack(xyz)
    d = _core_distance(pts[idx], c[:, None, :], n[:, None, :], major)
    return np.asarray(idx[np.arange(idx.shape[0]), np.argmin(d, axis=1)], dtype=np.intp)


def _contact_point(
    p_wire: FloatArray, T_world_ring: FloatArray, ring_cfg: RingConfig, wire_radius: float
) -> tuple[FloatArray, FloatArray]:
    """Clearance (N,), m, and contact points (N, 3), m, for wire points (N, 3) and poses."""
    c = T_world_ring[:, :3, 3]
    n = T_world_ring[:, :3, 2]
    d = p_wire - c
    h = np.einsum("ij,ij->i", d, n)
    radial = d - h[:, None] * n
    rho = np.linalg.norm(radial, axis=1)
    on_axis = rho < _EPS
    radial[on_axis] = T_world_ring[on_axis, :3, 0]
    rho[on_axis] = 1.0
    q = c + ring_cfg.major_radius * radial / rho[:, None]
    gap = q - p_wire
    dist = np.linalg.norm(gap, axis=1)
    on_core = dist < _EPS
    gap[on_core] = n[on_core]
    dist[on_core] = 1.0
    clearance = np.linalg.norm(q - p_wire, axis=1) - ring_cfg.minor_radius - wire_radius
    p_contact = p_wire + gap / dist[:, None] * (wire_radius + 0.5 * clearance)[:, None]
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
    the others are refined together. Each pose's result depends only on its own inputs.
    """
    s_all = wire.search_arc_length
    m = s_all.size
    s_best = s_all[g].copy()
    lo = np.maximum(g - step, 0)
    hi = np.minimum(g + step, m - 1)
    major = ring_cfg.major_radius
    if scalar is None:
        scalar = np.full(g.size, g.size <= _SCALAR_LIMIT)
    for i in np.flatnonzero(scalar).tolist():
        res = minimize_scalar(
            lambda s, i=i: float(_core_distance(wire.point(s), c[i], n[i], major)),
            bounds=(s_all[lo[i]], s_all[hi[i]]),
            method="bounded",
            options={"xatol": X_TOL},
        )
        if res.fun <= _core_distance(wire.search_points[g[i]], c[i], n[i], major):
            s_best[i] = float(res.x)
    inner = np.flatnonzero((g > 0) & (g < m - 1) & ~scalar)
    if inner.size:

        def objective(s: FloatArray, k: NDArray[np.intp]) -> FloatArray:
            # ``k`` shrinks with the still-active elements; it indexes the poses
            p = wire.points(s.ravel()).reshape(*s.shape, 3)
            return _core_distance(p, c[k], n[k], major)

        res = elementwise.find_minimum(
            objective,
            (s_all[lo[inner]], s_best[inner], s_all[hi[inner]]),
            args=(inner,),
            tolerances={"xatol": X_TOL, "xrtol": 0.0, "fatol": 0.0, "frtol": 0.0},
        )
        ok = np.asarray(res.success)
        s_best[inner[ok]] = np.asarray(res.x)[ok]
    return s_best


def _columns(wire: Wire) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The search polyline's x, y, z columns ((M,) each, contiguous), m."""
    pts = wire.search_points
    return pts[:, 0].copy(), pts[:, 1].copy(), pts[:, 2].copy()


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
    reach = ring_cfg.major_radius + ring_cfg.minor_radius + wire.radius
    step = max(1, int(COARSE_STEP / wire.search_spacing))
    half = math.ceil(WINDOW_FACTOR * reach / wire.search_spacing / step) * step
    m = wire.search_arc_length.size
    offsets = np.arange(-half, half + 1, step)
    c, n = T[:, :3, 3], T[:, :3, 2]
    xyz = _columns(wire)
    g = np.empty(T.shape[0], dtype=np.intp)
    scalar = np.zeros(T.shape[0], dtype=bool)
    for a in range(0, T.shape[0], _CHUNK):  # the coarse search in blocks (bounded memory)
        b = min(a + _CHUNK, T.shape[0])
        k = np.searchsorted(wire.search_arc_length, wire.nearest_s(c[a:b]))
        idx = np.clip(k[:, None] + offsets, 0, m - 1)
        g[a:b] = _coarse_minimiser(xyz, idx, c[a:b], n[a:b], ring_cfg.major_radius)
        scalar[a:b] = b - a <= _SCALAR_LIMIT  # a small block's poses: scalar Brent
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
    idx = np.unique(np.append(idx, wire.search_arc_length.size - 1))[None, :]
    T = T[None]
    c, n = T[:, :3, 3], T[:, :3, 2]
    g = _coarse_minimiser(_columns(wire), idx, c, n, ring_cfg.major_radius)
    s_best = _refine(wire, ring_cfg, g, step, c, n)
    cl, p = _contact_point(wire.points(s_best), T, ring_cfg, wire.radius)
    return float(cl[0]), p[0]


def touch_events(
    trajectory,
    wire: Wire,
    ring_cfg: RingConfig,
    dt: float = DEFAULT_TOUCH_DT,
) -> TouchReport:
    """Ground-truth touch events of a ring trajectory (see the module docstring for the bound).

    Parameters
    ----------
    trajectory : RingTrajectory
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
    in_contact = c <= 0.0
    events = _events(trajectory, wire, ring_cfg, t, c, p, in_contact)
    return TouchReport(events, t, c, in_contact, float(dt), float(speed))


def _events(
    trajectory,
    wire: Wire,
    ring_cfg: RingConfig,
    t: FloatArray,
    c: FloatArray,
    p: FloatArray,
    in_contact: NDArray[np.bool_],
) -> list[TouchEvent]:
    """Maximal contact runs of the samples, with start/end times root-found together."""
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

        def c_of_t(time: FloatArray) -> FloatArray:
            return clearances(trajectory.poses(time.ravel()), wire, ring_cfg)[0].reshape(time.shape)

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
