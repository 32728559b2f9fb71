r"""The wire-clearance guard's path search: is the straight move clear, else a way-point round.

A command may be clear while the straight move to it is not (the camera on one side of the
wire, the goal on the other). :func:`detour_waypoint` sphere-traces that move: from a point at
surface distance ``d`` the next ``d − clearance`` of the segment cannot enter the zone (the
distance is 1-Lipschitz), so one query clears a short move. If the trace stops at the zone's
edge before the command, the way-point slides from there along the zone's surface (straight on
when the command lies on the same side of the wire, round the wire otherwise), pushed
``DETOUR_PUSH`` out of the zone. ``control.clearance.ClearanceGuard.detour`` asks it from
Python, the policies' compiled steps through :func:`cleared_move`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from endocam.geometry import FloatArray
from endocam.kernels import Vec, cross, dot, norm, reject, scaled, unit_checked
from endocam.task.wire import surface_query
from endocam.workspace.keepout import KeepOutState, keep_out_distance

MAX_TRACE_STEPS = 40  # count, queries along one traced segment at most
DETOUR_STEP = 0.005  # m, how far along the zone's surface a detour way-point leads
SAME_SIDE_ANGLE = math.radians(30.0)  # rad, a command within this angle about the wire's axis
# of the edge point is on its side: the detour slides straight on, else it goes round the wire
DETOUR_PUSH = 1.0e-3  # m, a detour way-point sits this far outside the zone
DETOUR_SCALES = (1.0, 0.5, 0.25)  # unitless, fractions of the slide tried, longest first
DETOUR_TOL = 1.0e-5  # m, a traced segment closer than this to the zone is blocked
DETOUR_CREEP = 2.0e-4  # m, trace step from the zone's edge when the segment leaves it
_EPS = 1e-9  # unitless, shorter directions are degenerate


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _wire_point(
    pts: FloatArray,
    table: np.ndarray,
    pool: np.ndarray,
    meta: np.ndarray,
    x: float,
    y: float,
    z: float,
) -> Vec:
    """The search point nearest to ``(x, y, z)``, m (:meth:`Wire.nearest_surface`'s), m."""
    k, _ = surface_query(pts, table, pool, meta, x, y, z)
    return (pts[k, 0], pts[k, 1], pts[k, 2])


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def trace(
    zone: KeepOutState,
    a: Vec,
    b: Vec,
) -> tuple[bool, Vec]:
    """The first point of the segment ``a → b`` (m) entering the zone: ``(True, x)``, m.

    ``(False, a)`` when it does not enter. Sphere tracing (module docstring); a start on the
    zone's edge moving out (away from its nearest wire point) creeps on.
    """
    pts, table, pool, meta, _, _, _, clearance = zone
    seg = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    length = norm(seg)
    if not math.isfinite(length) or length <= _EPS:
        return False, a
    t = 0.0
    x = a
    for _ in range(MAX_TRACE_STEPS):
        free = keep_out_distance(zone, x[0], x[1], x[2], 0.0) - clearance
        if not free > DETOUR_TOL:
            if not free >= -DETOUR_TOL:
                return True, x
            q = _wire_point(pts, table, pool, meta, x[0], x[1], x[2])
            if not dot((x[0] - q[0], x[1] - q[1], x[2] - q[2]), seg) > 0.0:  # not leaving
                return True, x
            free = DETOUR_CREEP  # on the edge, moving out: creep on and trace again
        t += free / length
        if t >= 1.0:
            return False, a
        x = (a[0] + t * seg[0], a[1] + t * seg[1], a[2] + t * seg[2])
    return False, a  # converging onto the edge without entering


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def lifted(
    pts: FloatArray,
    table: np.ndarray,
    pool: np.ndarray,
    meta: np.ndarray,
    radius: float,
    clearance: float,
    p: Vec,
) -> tuple[bool, Vec]:
    """``p`` (m) moved out to ``DETOUR_PUSH`` beyond the zone if it is closer, else ``p``.

    ``(False, p)``: no way out (on the centre line).
    """
    k, dist = surface_query(pts, table, pool, meta, p[0], p[1], p[2])
    d = dist - radius
    want = clearance + DETOUR_PUSH
    if d >= want:
        return True, p
    ok, out = unit_checked((p[0] - pts[k, 0], p[1] - pts[k, 1], p[2] - pts[k, 2]))
    if not ok:
        return False, p
    lift = want - d
    return True, (p[0] + lift * out[0], p[1] + lift * out[1], p[2] + lift * out[2])


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def detour_waypoint(
    zone: KeepOutState,
    a: Vec,
    b: Vec,
) -> tuple[bool, Vec]:
    """:meth:`ClearanceGuard.detour` from ``a`` to ``b`` (m): ``(True, way-point)``, m.

    ``(False, a)`` when the straight move keeps the clearance.
    """
    pts, table, pool, meta, radius, _, _, clearance = zone
    blocked, x = trace(zone, a, b)
    if not blocked:
        return False, a
    k, _ = surface_query(pts, table, pool, meta, x[0], x[1], x[2])
    q = (pts[k, 0], pts[k, 1], pts[k, 2])
    hi, lo = min(k + 1, pts.shape[0] - 1), max(k - 1, 0)
    has_out, out = unit_checked((x[0] - q[0], x[1] - q[1], x[2] - q[2]))
    has_tangent, tangent = unit_checked(
        (pts[hi, 0] - pts[lo, 0], pts[hi, 1] - pts[lo, 1], pts[hi, 2] - pts[lo, 2])
    )
    if not (has_out and has_tangent):
        return False, a
    # Around the wire, not along it: the command's angle about the wire's axis, seen from
    # the edge point, picks the way round (over the top when it is straight behind).
    around = cross(tangent, out)
    g = reject((b[0] - q[0], b[1] - q[1], b[2] - q[2]), tangent)
    phi = math.atan2(dot(g, around), dot(g, out))
    rest = (b[0] - x[0], b[1] - x[1], b[2] - x[2])
    n_rest = norm(rest)
    step = n_rest if n_rest < DETOUR_STEP else DETOUR_STEP  # Python's min(DETOUR_STEP, n_rest)
    if abs(phi) < SAME_SIDE_ANGLE:  # the same side: straight on along the surface
        ok, slide = unit_checked(reject(rest, out))
        move = scaled(slide if ok else out, step)
    else:
        sign = 1.0 if phi > 0.0 else -1.0
        if abs(phi) > math.pi - SAME_SIDE_ANGLE:  # straight behind: over the top
            sign = 1.0 if around[2] >= 0.0 else -1.0
        r_t = dot(rest, tangent)
        inner = r_t if r_t < step else step  # Python's min(step, r_t)
        along = inner if inner > -step else -step  # Python's max(-step, inner)
        move = (
            sign * step * around[0] + along * tangent[0],
            sign * step * around[1] + along * tangent[1],
            sign * step * around[2] + along * tangent[2],
        )
    for scale in DETOUR_SCALES:  # shorter steps where the zone's surface curves away
        p = (x[0] + scale * move[0], x[1] + scale * move[1], x[2] + scale * move[2])
        ok, via = lifted(pts, table, pool, meta, radius, clearance, p)
        if ok:
            blocked, _ = trace(zone, a, via)
            if not blocked:
                return True, via
    # no clear slide: straight out of the zone, away from the wire
    short = clearance - keep_out_distance(zone, x[0], x[1], x[2], 0.0)
    lift = DETOUR_PUSH + (short if short > 0.0 else 0.0)  # Python's max(0.0, short)
    return True, (x[0] + lift * out[0], x[1] + lift * out[1], x[2] + lift * out[2])


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def cleared_move(
    zone: KeepOutState,
    p: Vec,
    pivot: Vec,
    now: Vec,
) -> tuple[bool, bool, Vec]:
    """``ClearanceGuard.apply``'s check of a pose at ``p`` and ``ClearanceGuard.detour``.

    For a compiled step whose command is that pose: ``(True, found, via)`` when ``p`` (m)
    keeps the clearance (``apply`` would return the pose itself; its finite check includes
    the ``pivot``, m) with ``detour``'s answer for the move from ``now`` (m) to it; else
    ``(False, False, now)``, the cache left as it was (the caller asks ``apply`` itself).
    """
    _, _, _, _, _, ref, nref, clearance = zone
    if not math.isfinite(p[0] + p[1] + p[2] + (pivot[0] + pivot[1] + pivot[2])):
        return False, False, now
    saved, n_saved = ref.copy(), nref[0]
    surface = keep_out_distance(zone, p[0], p[1], p[2], 0.0)
    if not surface >= clearance:
        ref[:, :] = saved
        nref[0] = n_saved
        return False, False, now
    found, via = detour_waypoint(zone, now, p)
    return True, found, via
