r"""The wire-clearance guard's search for a clear pose (``ClearanceGuard.apply``), compiled.

A pose whose optical centre is closer than the clearance ``c`` to the wire's tube surface is
first moved back along its optical axis (if allowed), else rotated about the pivot it looks at
(the ring centre) by the smallest angle along an escape direction that restores the clearance,
keeping the pivot at the same place in the camera frame and the horizon level
(``control.clearance``'s module docstring gives the iteration).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.geometry import FloatArray
from endocam.kernels import Vec, cross, dot, norm, reject, scaled
from endocam.task.wire import surface_query
from endocam.view import look_at_columns, rotation_columns
from endocam.workspace.keepout import KeepOutState, keep_out_distance, remember
from endocam.workspace.region import WorkspaceState, workspace_margin

AIM_BEYOND = 2.0e-4  # m, a rotated pose aims this far beyond the clearance, so the chord of a
# step (≤ 2 mm) between two such poses stays clear of the zone (sag L²/8R ≈ 0.06 mm, R ≈ 9 mm)
MAX_ESCAPE_ANGLE = math.radians(90.0)  # rad, largest rotation about the pivot that is tried
MIN_ESCAPE_STEP = math.radians(0.5)  # rad, step while the clear pose is infeasible
NEWTON_GAIN = 4.0  # unitless, largest Newton step as a multiple of the conservative one
MAX_ESCAPE_STEPS = 40  # count, queries per direction at most
_EPS = 1e-9  # unitless, shorter directions are degenerate
# clear_pose_into's answers: the pose itself, a backed-off or rotated one, none clear, not finite
APPLY_CLEAR, APPLY_ADJUSTED, APPLY_BLOCKED, APPLY_NOT_FINITE = range(4)
APPLY_INFEASIBLE = 4  # clear_look_at_into: the pose's position is outside the workspace

# The guard's search for a clear pose (``ClearanceGuard.apply``), compiled. ``feasible`` below:
# whether a camera position may be commanded, ``workspace.region.Workspace.margin`` ≥ 0 (the
# cone, the floor and the workspace's own keep-out guard, whose cache it updates), or
# everywhere (``kind`` 0). ``ws``: the cone's constants (9,) (``ConeWorkspace.constants``) and
# the floor, m; ``keep``: whether the workspace has a keep-out zone, then its guard's state.


@register_jitable  # also callable from compiled kernels (the same source)
def _feasible(
    kind: int,
    ws: WorkspaceState,
    pos: Vec,
) -> bool:
    """Whether ``pos`` (m) is feasible: ``Workspace.margin(pos) >= 0`` (``kind`` 1), or True."""
    if kind == 0:
        return True
    return workspace_margin(ws, pos[0], pos[1], pos[2]) >= 0.0


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
        return max(conservative, 1e-7)
    rate = dot(g, velocity) / length
    if rate * NEWTON_GAIN <= speed:
        return max(NEWTON_GAIN * conservative, 1e-7)
    return max(max(short / rate, conservative), 1e-7)  # Python's max of the three


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
def clear_pose(
    zone: KeepOutState,
    T: FloatArray,
    pivot: Vec,
    has_now: bool,
    now: Vec,
    back_off: float,
    escape: FloatArray,
    kind: int,
    ws: WorkspaceState,
) -> tuple[int, FloatArray]:
    """:meth:`ClearanceGuard.apply` of the pose ``T`` (4, 4): ``(APPLY_*, pose (4, 4))``.

    The guard's ``state`` first, then :meth:`~ClearanceGuard.apply`'s arguments: ``pivot``,
    ``now`` (m; read if ``has_now``), ``back_off`` (m); ``escape`` (4,): the remembered
    escape direction (a flag, then the unit direction, world; updated); the workspace
    (``kind``, ``ws``, ``keep`` … ``k_clearance``: :func:`_feasible`'s). ``APPLY_CLEAR``:
    ``T`` itself; ``APPLY_ADJUSTED``: the pose backed off or rotated; ``APPLY_BLOCKED``: no
    clear feasible pose; ``APPLY_NOT_FINITE``: a non-finite pose or pivot. The interpreter's
    floats and queries in its order (docs/conventions.md, "Compiled kernels").
    """
    pts, table, pool, meta, radius, ref, nref, clearance = zone
    c = pivot
    p = (T[0, 3], T[1, 3], T[2, 3])
    if not math.isfinite(p[0] + p[1] + p[2] + (0.0 + c[0] + c[1] + c[2])):
        return APPLY_NOT_FINITE, T
    if keep_out_distance(zone, p[0], p[1], p[2], 0.0) >= (clearance):
        escape[0] = 0.0
        return APPLY_CLEAR, T
    target = clearance + AIM_BEYOND
    if back_off > 0.0:  # back along the optical axis: the camera moves 1:1 with the distance
        z = (T[0, 2], T[1, 2], T[2, 2])
        back = (-z[0], -z[1], -z[2])
        s = 0.0
        for _ in range(MAX_ESCAPE_STEPS):
            pos = (p[0] - s * z[0], p[1] - s * z[1], p[2] - s * z[2])
            k, dist = surface_query(pts, table, pool, meta, pos[0], pos[1], pos[2])
            d = dist - radius
            if d >= target:
                if not _feasible(
                    kind, ws, pos,
                ):  # fmt: skip
                    break
                remember(ref, nref, pos[0], pos[1], pos[2], d)
                out = T.copy()
                for i in range(3):
                    out[i, 3] = pos[i]
                return APPLY_ADJUSTED, out
            s += _newton(pts, target - d, pos, k, back)
            if s > back_off:
                break
    # rotated about the pivot (module docstring)
    x0 = (T[0, 0], T[1, 0], T[2, 0])
    y0 = (T[0, 1], T[1, 1], T[2, 1])
    z0 = (T[0, 2], T[1, 2], T[2, 2])
    rel = (p[0] - c[0], p[1] - c[1], p[2] - c[2])
    r = norm(rel)
    if not r > _EPS:
        return APPLY_BLOCKED, T
    a, b, w = dot(rel, x0), dot(rel, y0), dot(rel, z0)  # camera position in its own frame
    u = scaled(rel, 1.0 / r)
    # the escape directions ⟂ u, best first: the remembered one, else towards the camera
    # now, else the distance's gradient (away from the nearest wire point); then the
    # perpendiculars and the opposite
    k_near, _ = surface_query(pts, table, pool, meta, p[0], p[1], p[2])
    q = (pts[k_near, 0], pts[k_near, 1], pts[k_near, 2])
    candidates = [(p[0] - q[0], p[1] - q[1], p[2] - q[2]), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)]
    if has_now:
        candidates.insert(0, (now[0] - c[0], now[1] - c[1], now[2] - c[2]))
    if escape[0] != 0.0:
        candidates.insert(0, (escape[1], escape[2], escape[3]))
    found = False
    e0 = u
    for cand in candidates:
        e = reject(cand, u)
        length = norm(e)
        if length > 1e-6:
            e0 = scaled(e, 1.0 / length)
            found = True
            break
    if not found:
        return APPLY_BLOCKED, T
    e1 = cross(u, e0)
    for e in (e0, e1, scaled(e1, -1.0), scaled(e0, -1.0)):
        # the smallest angle along e with a clear, feasible pose (conservative advancement)
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
            near, dist = surface_query(pts, table, pool, meta, pos[0], pos[1], pos[2])
            d = dist - radius
            if d >= target and _feasible(
                kind, ws, pos,
            ):  # fmt: skip
                remember(ref, nref, pos[0], pos[1], pos[2], d)
                escape[0], escape[1], escape[2], escape[3] = 1.0, e[0], e[1], e[2]
                out = np.empty((4, 4))
                for i in range(3):
                    out[i, 0], out[i, 1], out[i, 2], out[i, 3] = xc[i], yc[i], zc[i], pos[i]
                out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0
                return APPLY_ADJUSTED, out
            if d < target:  # the camera's velocity per radian: k × (pos − c)
                rel_pos = (pos[0] - c[0], pos[1] - c[1], pos[2] - c[2])
                step = _newton(pts, target - d, pos, near, cross(k_axis, rel_pos))
            else:
                step = MIN_ESCAPE_STEP
            theta += max(step, MIN_ESCAPE_STEP * 0.1)
            if theta > MAX_ESCAPE_ANGLE:
                break
    return APPLY_BLOCKED, T


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def clear_pose_into(
    zone: KeepOutState,
    T: FloatArray,
    pivot: Vec,
    has_now: bool,
    now: Vec,
    back_off: float,
    escape: FloatArray,
    kind: int,
    ws: WorkspaceState,
    out: FloatArray,
) -> int:  # pragma: no cover - compiled
    """:func:`clear_pose` from Python (:meth:`ClearanceGuard.apply`): its answer (``APPLY_*``).

    An adjusted pose is written into ``out`` (4, 4), the caller's array (numba unpickles the
    type of every array it returns, ~1 us a call).
    """
    code, cleared = clear_pose(
        zone, T, pivot, has_now, now, back_off,
        escape, kind, ws,
    )  # fmt: skip
    if code == APPLY_ADJUSTED:
        out[:, :] = cleared
    return code


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def clear_look_at_into(
    zone: KeepOutState,
    p: Vec,
    pivot: Vec,
    fallback: FloatArray,
    previous: FloatArray,
    check: bool,
    has_now: bool,
    now: Vec,
    back_off: float,
    escape: FloatArray,
    kind: int,
    ws: WorkspaceState,
    out: FloatArray,
) -> tuple[int, bool]:  # pragma: no cover - compiled
    """:meth:`ClearanceGuard.apply_look_at`: ``(APPLY_* or APPLY_INFEASIBLE, fallen back)``.

    The pose at ``p`` (m) looking at ``pivot`` (m) with a level horizon, its roll from
    ``previous`` (4, 4) (``view.look_at_unchecked``: ``fallback`` (4, 4) when the two
    points coincide; then "fallen back"); if ``check``, ``APPLY_INFEASIBLE`` when ``p`` is
    not feasible (:func:`_feasible`); then :func:`clear_pose` of the pose (the other
    arguments its). The pose :func:`clear_pose` gives (``APPLY_CLEAR``: the look-at pose,
    unless fallen back; ``APPLY_ADJUSTED``: the cleared one) is written into ``out`` (4, 4),
    the caller's array (numba unpickles the type of every array it returns).
    """
    x_prev = (previous[0, 0], previous[1, 0], previous[2, 0])
    found, x, y, z = look_at_columns(p, pivot, x_prev)
    fell_back = not found
    T = fallback
    if found:
        T = np.empty((4, 4))
        for i in range(3):
            T[i, 0], T[i, 1], T[i, 2], T[i, 3] = x[i], y[i], z[i], p[i]
        T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    if check and not _feasible(kind, ws, p):
        return APPLY_INFEASIBLE, fell_back
    code, cleared = clear_pose(
        zone, T, pivot, has_now, now, back_off,
        escape, kind, ws,
    )  # fmt: skip
    if code == APPLY_ADJUSTED or (code == APPLY_CLEAR and not fell_back):
        out[:, :] = cleared
    return code, fell_back
