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
from typing import NamedTuple

from numba import njit

from endocam.kernels import Vec, copy_into, cross, dot, norm, reject, scaled, unit_checked
from endocam.workspace.keepout import KeepOutState, keep_out_distance, keep_out_nearest

MAX_TRACE_STEPS = 40  # count, queries along one traced segment at most
DETOUR_STEP = 0.005  # m, how far along the zone's surface a detour way-point leads
SAME_SIDE_ANGLE = math.radians(30.0)  # rad, a command within this angle about the wire's axis
# of the edge point is on its side: the detour slides straight on, else it goes round the wire
DETOUR_PUSH = 1.0e-3  # m, a detour way-point sits this far outside the zone
DETOUR_SCALES = (1.0, 0.5, 0.25)  # unitless, fractions of the slide tried, longest first
DETOUR_TOL = 1.0e-5  # m, a traced segment closer than this to the zone is blocked
DETOUR_CREEP = 2.0e-4  # m, trace step from the zone's edge when the segment leaves it
_EPS = 1e-9  # unitless, shorter directions are degenerate


class Traced(NamedTuple):
    """:func:`trace`'s answer."""

    blocked: bool  # whether the segment enters the zone
    at: Vec  # the first point entering it, world, m (the segment's start when not blocked)


class Waypoint(NamedTuple):
    """A point the camera may be sent to (:func:`lifted`, :func:`detour_waypoint`)."""

    found: bool  # whether there is one (else ``point`` is the input, unchanged)
    point: Vec  # world, m


class ClearedMove(NamedTuple):
    """:func:`cleared_move`'s answer."""

    clear: bool  # the pose keeps the clearance (``ClearanceGuard.apply`` passes it unchanged)
    detoured: bool  # the straight move to it does not: go to ``via`` first
    via: Vec  # the detour's way-point, world, m (the camera's position when not detoured)


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def trace(zone: KeepOutState, a: Vec, b: Vec) -> Traced:
    """The first point of the segment ``a → b`` (world, m) entering the zone, if it does.

    Sphere tracing (module docstring); a start on the zone's edge moving out (away from its
    nearest wire point) creeps on.
    """
    seg = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    length = norm(seg)
    if not math.isfinite(length) or length <= _EPS:
        return Traced(False, a)
    t = 0.0
    x = a
    for _ in range(MAX_TRACE_STEPS):
        free = keep_out_distance(zone, x[0], x[1], x[2], 0.0) - zone.clearance
        if not free > DETOUR_TOL:
            if not free >= -DETOUR_TOL:
                return Traced(True, x)
            k = keep_out_nearest(zone, x[0], x[1], x[2]).row
            q = zone.points[k]
            if not dot((x[0] - q[0], x[1] - q[1], x[2] - q[2]), seg) > 0.0:  # not leaving
                return Traced(True, x)
            free = DETOUR_CREEP  # on the edge, moving out: creep on and trace again
        t += free / length
        if t >= 1.0:
            return Traced(False, a)
        x = (a[0] + t * seg[0], a[1] + t * seg[1], a[2] + t * seg[2])
    return Traced(False, a)  # converging onto the edge without entering


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def lifted(zone: KeepOutState, p: Vec) -> Waypoint:
    """``p`` (world, m) moved straight out to ``DETOUR_PUSH`` beyond the zone if it is closer.

    ``p`` itself (found) when it already lies that far out; not found on the centre line
    (no way out).
    """
    near = keep_out_nearest(zone, p[0], p[1], p[2])
    want = zone.clearance + DETOUR_PUSH
    if near.surface >= want:
        return Waypoint(True, p)
    q = zone.points[near.row]
    ok, out = unit_checked((p[0] - q[0], p[1] - q[1], p[2] - q[2]))
    if not ok:
        return Waypoint(False, p)
    lift = want - near.surface
    return Waypoint(True, (p[0] + lift * out[0], p[1] + lift * out[1], p[2] + lift * out[2]))


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def detour_waypoint(zone: KeepOutState, a: Vec, b: Vec) -> Waypoint:
    """``ClearanceGuard.detour`` from ``a`` to ``b`` (world, m): a way-point round the wire.

    Not found when the straight move keeps the clearance.
    """
    traced = trace(zone, a, b)
    if not traced.blocked:
        return Waypoint(False, a)
    x = traced.at
    pts = zone.points
    k = keep_out_nearest(zone, x[0], x[1], x[2]).row
    q = (pts[k, 0], pts[k, 1], pts[k, 2])
    hi, lo = min(k + 1, pts.shape[0] - 1), max(k - 1, 0)
    has_out, out = unit_checked((x[0] - q[0], x[1] - q[1], x[2] - q[2]))
    has_tangent, tangent = unit_checked(
        (pts[hi, 0] - pts[lo, 0], pts[hi, 1] - pts[lo, 1], pts[hi, 2] - pts[lo, 2])
    )
    if not (has_out and has_tangent):
        return Waypoint(False, a)
    # Around the wire, not along it: the command's angle about the wire's axis, seen from
    # the edge point, picks the way round (over the top when it is straight behind).
    around = cross(tangent, out)
    g = reject((b[0] - q[0], b[1] - q[1], b[2] - q[2]), tangent)
    phi = math.atan2(dot(g, around), dot(g, out))
    rest = (b[0] - x[0], b[1] - x[1], b[2] - x[2])
    step = min(norm(rest), DETOUR_STEP)
    if abs(phi) < SAME_SIDE_ANGLE:  # the same side: straight on along the surface
        ok, slide = unit_checked(reject(rest, out))
        move = scaled(slide if ok else out, step)
    else:
        sign = 1.0 if phi > 0.0 else -1.0
        if abs(phi) > math.pi - SAME_SIDE_ANGLE:  # straight behind: over the top
            sign = 1.0 if around[2] >= 0.0 else -1.0
        along = max(-step, min(dot(rest, tangent), step))
        move = (
            sign * step * around[0] + along * tangent[0],
            sign * step * around[1] + along * tangent[1],
            sign * step * around[2] + along * tangent[2],
        )
    for scale in DETOUR_SCALES:  # shorter steps where the zone's surface curves away
        p = (x[0] + scale * move[0], x[1] + scale * move[1], x[2] + scale * move[2])
        via = lifted(zone, p)
        if via.found and not trace(zone, a, via.point).blocked:
            return via
    # no clear slide: straight out of the zone, away from the wire
    short = zone.clearance - keep_out_distance(zone, x[0], x[1], x[2], 0.0)
    lift = DETOUR_PUSH + max(short, 0.0)
    return Waypoint(True, (x[0] + lift * out[0], x[1] + lift * out[1], x[2] + lift * out[2]))


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def detour_fields(zone: KeepOutState, a: Vec, b: Vec) -> tuple[bool, Vec]:  # pragma: no cover
    """:func:`detour_waypoint` from Python: its fields as a plain tuple (found, point).

    numba returns a plain tuple cheaper than a NamedTuple (built by calling its class).
    """
    via = detour_waypoint(zone, a, b)
    return via.found, via.point


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def cleared_move(zone: KeepOutState, p: Vec, pivot: Vec, now: Vec) -> ClearedMove:
    """``ClearanceGuard.apply``'s check of a pose at ``p`` and ``ClearanceGuard.detour``.

    For a compiled step whose command is that pose: clear when ``p`` (world, m) keeps the
    clearance (``apply`` would return the pose itself; its finite check includes the
    ``pivot``, m), then :func:`detour_waypoint`'s answer for the move from ``now`` (m) to
    it; else not clear, the zone's cache left as it was (the caller asks ``apply`` itself).
    """
    if not math.isfinite(p[0] + p[1] + p[2] + (pivot[0] + pivot[1] + pivot[2])):
        return ClearedMove(False, False, now)
    saved, n_saved = zone.ref.copy(), zone.nref[0]
    surface = keep_out_distance(zone, p[0], p[1], p[2], 0.0)
    if not surface >= zone.clearance:
        copy_into(saved, zone.ref)
        zone.nref[0] = n_saved
        return ClearedMove(False, False, now)
    via = detour_waypoint(zone, now, p)
    return ClearedMove(True, via.found, via.point)
