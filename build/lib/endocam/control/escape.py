r"""The wire-clearance guard's search for a clear pose (``ClearanceGuard.apply``), compiled.

A pose whose optical centre is closer than the clearance ``c`` to the wire's tube surface is
first moved back along its optical axis (if the caller allows it), else rotated about the pivot
it looks at (the ring centre) by the smallest angle along an escape direction that restores the
clearance, keeping the pivot at the same place in the camera frame and the horizon level
(``control.clearance``'s module docstring gives the iteration). A pose is accepted only if its
position is also feasible: inside the workspace the guard is given (the cone, the floor and the
workspace's own keep-out zone), or anywhere without one.

The search takes the guard's state as one :class:`GuardState` (the zone, the remembered escape
direction, the workspace) and what it is asked as one :class:`ClearRequest`; it answers a
:class:`Cleared` (an ``APPLY_*`` code and the pose).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import NDArray

from endocam.geometry import FloatArray
from endocam.kernels import Vec, copy_into, cross, dot, norm, reject, scaled
from endocam.view import look_at_columns, rotation_columns
from endocam.workspace.keepout import KeepOutState, keep_out_distance, keep_out_nearest, remember
from endocam.workspace.region import WorkspaceState, workspace_margin

AIM_BEYOND = 2.0e-4  # m, a rotated pose aims this far beyond the clearance, so the chord of a
# step (≤ 2 mm) between two such poses stays clear of the zone (sag L²/8R ≈ 0.06 mm, R ≈ 9 mm)
MAX_ESCAPE_ANGLE = math.radians(90.0)  # rad, largest rotation about the pivot that is tried
MIN_ESCAPE_STEP = math.radians(0.5)  # rad, step while the clear pose is infeasible
NEWTON_GAIN = 4.0  # unitless, largest Newton step as a multiple of the conservative one
MAX_ESCAPE_STEPS = 40  # count, queries per direction at most
MIN_STEP = 1e-7  # m or rad (the search's parameter), the smallest Newton step taken
_EPS = 1e-9  # unitless, shorter directions are degenerate
# Cleared.code: the pose itself, a backed-off or rotated one, none clear, not finite; and
# (clear_look_at_into only) the look-at pose's position is outside the workspace
APPLY_CLEAR, APPLY_ADJUSTED, APPLY_BLOCKED, APPLY_NOT_FINITE, APPLY_INFEASIBLE = range(5)

ESCAPE_MEMORY = np.dtype(
    [
        ("held", np.bool_),  # whether a direction is remembered
        ("direction", np.float64, (3,)),  # the unit escape direction, world
    ],
    align=True,
)
"""The direction of the guard's last rotation, kept between steps (a (1,) array, in place).

The next search tries it first, so the camera does not chatter between two sides of a symmetric
wire; a pose that passes unchanged forgets it. A structured array: one array to dispatch.
"""

EscapeMemory = NDArray[np.void]  # a (1,) array of ESCAPE_MEMORY


class GuardState(NamedTuple):
    """The guard's state as its compiled search reads it (``ClearanceGuard``'s)."""

    zone: KeepOutState  # the wire's keep-out zone (its Lipschitz cache is updated)
    escape: EscapeMemory  # the remembered escape direction (a (1,) ESCAPE_MEMORY, updated)
    bounded: bool  # whether a position must lie in ``workspace`` (else anywhere will do)
    workspace: WorkspaceState  # where a camera position may be commanded (read if bounded)


class ClearRequest(NamedTuple):
    """What ``ClearanceGuard.apply`` is asked besides the pose.

    It reaches the compiled entry points as a plain tuple of these fields, named on arrival
    (``ClearRequest(*asked)``): numba dispatches a plain tuple in C, a NamedTuple through
    Python's ``typeof`` (~2 us a call, thousands of calls an episode).
    """

    pivot: Vec  # the point the pose looks at (the ring centre), world, m
    has_now: bool  # whether ``now`` is known
    now: Vec  # where the camera is now, world, m: turn towards it first
    back_off: float  # m, how far the pose may first move back along its optical axis


class Cleared(NamedTuple):
    """:func:`clear_pose`'s answer."""

    code: int  # APPLY_CLEAR, APPLY_ADJUSTED, APPLY_BLOCKED or APPLY_NOT_FINITE
    pose: FloatArray  # (4, 4): the pose asked (CLEAR, BLOCKED, NOT_FINITE) or the adjusted one


class LookAt(NamedTuple):
    """The pose ``clear_look_at_into`` builds: at ``position``, looking at the request's pivot.

    Passed as a plain tuple of these fields, as :class:`ClearRequest`.
    """

    position: Vec  # world, m
    fallback: FloatArray  # (4, 4): the pose when ``position`` is the pivot
    previous: FloatArray  # (4, 4): the pose whose roll is kept near the vertical
    check: bool  # whether to refuse a position outside the workspace first


class LookedAt(NamedTuple):
    """:func:`clear_look_at_into`'s answer."""

    code: int  # an APPLY_* code (APPLY_INFEASIBLE: the position is outside the workspace)
    fell_back: bool  # the position was the pivot: the pose is ``LookAt.fallback``


@register_jitable  # also callable from compiled kernels (the same source)
def _feasible(guard: GuardState, pos: Vec) -> bool:
    """Whether ``pos`` (world, m) may be commanded: ``Workspace.margin(pos) >= 0``, or True."""
    if not guard.bounded:
        return True
    return workspace_margin(guard.workspace, pos[0], pos[1], pos[2]) >= 0.0


@register_jitable  # also callable from compiled kernels (the same source)
def _newton(pts: FloatArray, short: float, pos: Vec, k: int, velocity: Vec) -> float:
    """Parameter step that adds ``short`` (m) to the distance, the point moving at ``velocity``.

    The distance's gradient at ``pos`` (m) is the unit vector from the nearest wire point
    (``pts[k]``, m); its rate along ``velocity`` (m per unit parameter) gives a Newton step,
    bounded by ``[1, NEWTON_GAIN]`` times the conservative step ``short / ‖velocity‖`` (the
    distance to a line along a line is convex: the step lands at or just past the clear value).
    """
    g = (pos[0] - pts[k, 0], pos[1] - pts[k, 1], pos[2] - pts[k, 2])
    speed = norm(velocity)
    conservative = short / speed if speed > _EPS else short
    length = norm(g)
    if not length > _EPS:
        return max(conservative, MIN_STEP)
    rate = dot(g, velocity) / length
    if rate * NEWTON_GAIN <= speed:
        return max(NEWTON_GAIN * conservative, MIN_STEP)
    return max(short / rate, conservative, MIN_STEP)


@register_jitable  # also callable from compiled kernels (the same source)
def _rotate(v: Vec, k: Vec, c: float, s: float) -> Vec:
    """``v`` rotated about the unit axis ``k`` by the angle with cosine ``c`` and sine ``s``."""
    kv = cross(k, v)
    kd = dot(k, v) * (1.0 - c)
    return (
        v[0] * c + kv[0] * s + k[0] * kd,
        v[1] * c + kv[1] * s + k[1] * kd,
        v[2] * c + kv[2] * s + k[2] * kd,
    )


@register_jitable  # also callable from compiled kernels (the same source)
def _pose(x: Vec, y: Vec, z: Vec, p: Vec) -> FloatArray:
    """The (4, 4) pose with rotation columns ``x``, ``y``, ``z`` and position ``p`` (m)."""
    out = np.empty((4, 4))
    for i in range(3):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x[i], y[i], z[i], p[i]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0
    return out


@register_jitable  # also callable from compiled kernels (the same source)
def _backed_off(guard: GuardState, T: FloatArray, back_off: float, target: float) -> Cleared:
    """``T`` moved back along its optical axis up to ``back_off`` (m) to ``target`` (m) out.

    The camera moves 1:1 with the look distance, the view's direction is kept. Blocked when
    that does not clear within ``back_off``, or the clear position is not feasible.
    """
    zone = guard.zone
    p = (T[0, 3], T[1, 3], T[2, 3])
    z = (T[0, 2], T[1, 2], T[2, 2])
    back = (-z[0], -z[1], -z[2])
    s = 0.0
    for _ in range(MAX_ESCAPE_STEPS):
        pos = (p[0] - s * z[0], p[1] - s * z[1], p[2] - s * z[2])
        near = keep_out_nearest(zone, pos[0], pos[1], pos[2])
        if near.surface >= target:
            if not _feasible(guard, pos):
                break
            remember(zone.ref, zone.nref, pos[0], pos[1], pos[2], near.surface)
            out = T.copy()
            for i in range(3):
                out[i, 3] = pos[i]
            return Cleared(APPLY_ADJUSTED, out)
        s += _newton(zone.points, target - near.surface, pos, near.row, back)
        if s > back_off:
            break
    return Cleared(APPLY_BLOCKED, T)


@register_jitable  # also callable from compiled kernels (the same source)
def _escape_direction(guard: GuardState, p: Vec, u: Vec, request: ClearRequest) -> Vec:
    """The first escape direction to try, a unit vector ⟂ ``u``; the zero vector if none.

    Best first: the remembered one, else towards the camera now (it need not cross the wire),
    else the distance's gradient at ``p`` (m; away from the nearest wire point), then the
    vertical and the x axis; each projected perpendicular to ``u``.
    """
    zone, escape, c = guard.zone, guard.escape[0], request.pivot
    k = keep_out_nearest(zone, p[0], p[1], p[2]).row
    q = zone.points[k]
    candidates = [(p[0] - q[0], p[1] - q[1], p[2] - q[2]), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)]
    if request.has_now:
        now = request.now
        candidates.insert(0, (now[0] - c[0], now[1] - c[1], now[2] - c[2]))
    if escape.held:
        d = escape.direction
        candidates.insert(0, (d[0], d[1], d[2]))
    for cand in candidates:
        e = reject(cand, u)
        length = norm(e)
        if length > 1e-6:
            return scaled(e, 1.0 / length)
    return (0.0, 0.0, 0.0)


@register_jitable  # also callable from compiled kernels (the same source)
def _rotated(guard: GuardState, T: FloatArray, request: ClearRequest, target: float) -> Cleared:
    """``T`` rotated about the pivot by the smallest angle that clears ``target`` (m).

    Conservative advancement along the first escape direction (:func:`_escape_direction`),
    then its perpendiculars and its opposite, each up to ``MAX_ESCAPE_ANGLE``; the pivot keeps
    its place in the camera frame and the horizon stays level. The direction that clears is
    remembered.
    """
    zone, c = guard.zone, request.pivot
    p = (T[0, 3], T[1, 3], T[2, 3])
    x0 = (T[0, 0], T[1, 0], T[2, 0])
    y0 = (T[0, 1], T[1, 1], T[2, 1])
    z0 = (T[0, 2], T[1, 2], T[2, 2])
    rel = (p[0] - c[0], p[1] - c[1], p[2] - c[2])
    r = norm(rel)
    if not r > _EPS:
        return Cleared(APPLY_BLOCKED, T)
    a, b, w = dot(rel, x0), dot(rel, y0), dot(rel, z0)  # camera position in its own frame
    u = scaled(rel, 1.0 / r)
    e0 = _escape_direction(guard, p, u, request)
    if e0 == (0.0, 0.0, 0.0):
        return Cleared(APPLY_BLOCKED, T)
    e1 = cross(u, e0)
    for e in (e0, e1, scaled(e1, -1.0), scaled(e0, -1.0)):
        k_axis = cross(u, e)  # rotation axis: u turns towards e
        theta = 0.0
        for _ in range(MAX_ESCAPE_STEPS):
            ct, st = math.cos(theta), math.sin(theta)
            z = _rotate(z0, k_axis, ct, st)
            x_prev = _rotate(x0, k_axis, ct, st)
            xc, yc, zc = rotation_columns(z, (0.0, 0.0, 1.0), x_prev)
            pos = (
                c[0] + a * xc[0] + b * yc[0] + w * zc[0],
                c[1] + a * xc[1] + b * yc[1] + w * zc[1],
                c[2] + a * xc[2] + b * yc[2] + w * zc[2],
            )
            near = keep_out_nearest(zone, pos[0], pos[1], pos[2])
            if near.surface >= target and _feasible(guard, pos):
                remember(zone.ref, zone.nref, pos[0], pos[1], pos[2], near.surface)
                memory = guard.escape[0]
                memory.held = True
                for i in range(3):
                    memory.direction[i] = e[i]
                return Cleared(APPLY_ADJUSTED, _pose(xc, yc, zc, pos))
            if near.surface < target:  # the camera's velocity per radian: k × (pos − c)
                rel_pos = (pos[0] - c[0], pos[1] - c[1], pos[2] - c[2])
                velocity = cross(k_axis, rel_pos)
                step = _newton(zone.points, target - near.surface, pos, near.row, velocity)
            else:
                step = MIN_ESCAPE_STEP
            theta += max(step, MIN_ESCAPE_STEP * 0.1)
            if theta > MAX_ESCAPE_ANGLE:
                break
    return Cleared(APPLY_BLOCKED, T)


@register_jitable  # also callable from compiled kernels (the same source)
def clear_pose(guard: GuardState, T: FloatArray, request: ClearRequest) -> Cleared:
    """:meth:`ClearanceGuard.apply` of the pose ``T`` (4, 4), world, m.

    ``APPLY_CLEAR``: ``T`` itself (the remembered escape direction is forgotten);
    ``APPLY_ADJUSTED``: the pose backed off (if ``request.back_off`` > 0) or rotated about
    the pivot; ``APPLY_BLOCKED``: no clear feasible pose; ``APPLY_NOT_FINITE``: a non-finite
    pose position or pivot. The zone's cache and the escape memory are updated.
    """
    zone, c = guard.zone, request.pivot
    p = (T[0, 3], T[1, 3], T[2, 3])
    if not math.isfinite(p[0] + p[1] + p[2] + (c[0] + c[1] + c[2])):
        return Cleared(APPLY_NOT_FINITE, T)
    if keep_out_distance(zone, p[0], p[1], p[2], 0.0) >= zone.clearance:
        guard.escape[0].held = False
        return Cleared(APPLY_CLEAR, T)
    target = zone.clearance + AIM_BEYOND
    if request.back_off > 0.0:
        backed = _backed_off(guard, T, request.back_off, target)
        if backed.code == APPLY_ADJUSTED:
            return backed
    return _rotated(guard, T, request, target)


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def clear_pose_into(
    guard: GuardState, T: FloatArray, asked: tuple[Vec, bool, Vec, float], out: FloatArray
) -> int:  # pragma: no cover - compiled
    """:func:`clear_pose` from Python (:meth:`ClearanceGuard.apply`): its ``APPLY_*`` code.

    ``asked``: a :class:`ClearRequest`'s fields. An adjusted pose is written into ``out``
    (4, 4), the caller's array (numba unpickles the type of every array it returns, ~1 us a
    call).
    """
    cleared = clear_pose(guard, T, ClearRequest(*asked))
    if cleared.code == APPLY_ADJUSTED:
        copy_into(cleared.pose, out)
    return cleared.code


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def clear_look_at_into(
    guard: GuardState,
    look_at: tuple[Vec, FloatArray, FloatArray, bool],
    asked: tuple[Vec, bool, Vec, float],
    out: FloatArray,
) -> LookedAt:  # pragma: no cover - compiled
    """:meth:`ClearanceGuard.apply_look_at`: :func:`clear_pose` of a look-at pose.

    ``look_at``: a :class:`LookAt`'s fields, ``asked``: a :class:`ClearRequest`'s.

    The pose at ``look.position`` looking at ``request.pivot`` with a level horizon, its roll
    from ``look.previous`` (``view.look_at_unchecked``; ``look.fallback`` when the two points
    coincide: fallen back). If ``look.check``, ``APPLY_INFEASIBLE`` when the position is not
    feasible (the guard's workspace); else :func:`clear_pose`'s code. The pose it gives
    (``APPLY_CLEAR``: the look-at pose, unless fallen back; ``APPLY_ADJUSTED``: the cleared
    one) is written into ``out`` (4, 4), the caller's array.
    """
    look, request = LookAt(*look_at), ClearRequest(*asked)
    p, previous = look.position, look.previous
    x_prev = (previous[0, 0], previous[1, 0], previous[2, 0])
    found, x, y, z = look_at_columns(p, request.pivot, x_prev)
    T = _pose(x, y, z, p) if found else look.fallback
    if look.check and not _feasible(guard, p):
        return LookedAt(APPLY_INFEASIBLE, not found)
    cleared = clear_pose(guard, T, request)
    if cleared.code == APPLY_ADJUSTED or (cleared.code == APPLY_CLEAR and found):
        copy_into(cleared.pose, out)
    return LookedAt(cleared.code, not found)
