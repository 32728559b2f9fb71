r"""The camera–wire clearance: no commanded camera pose closer than ``wire_clearance`` to the wire.

The orientation goal looks along the ring normal, which is nearly the wire's tangent, so the
on-normal goal sits on the wire's continuation. :class:`ClearanceGuard` filters every pose a
moving policy commands (goal, way-point, orbit): a pose whose optical centre is at least the
clearance ``c`` from the wire's tube surface passes unchanged; a closer one is rotated about the
pivot it looks at (the ring centre) by the smallest angle along an escape direction that restores
the clearance, keeping the pivot at the same place in the camera frame (ring centred, same look
distance) and the horizon level:

.. math::

    u(\theta) = \cos\theta\,u + \sin\theta\,e, \qquad
    \theta_{k+1} = \theta_k + \frac{c + \delta - d(\theta_k)}{r}

``u`` is the unit direction from the pivot to the camera, ``r`` their distance, ``e ⟂ u`` the
escape direction, ``d`` the surface distance and ``δ = AIM_BEYOND``. The distance is 1-Lipschitz
in position and the camera moves at most ``r Δθ`` along the arc, so this conservative
advancement never steps over the first angle clear by ``δ`` (which keeps the chord between two
successive poses clear too). The escape direction is the one remembered from the previous step
(no chatter between two sides of a symmetric wire), else towards where the camera is now (it
need not cross the wire), else the distance's gradient (away from the nearest wire point), each
projected perpendicular to ``u``; then the perpendiculars and the opposite are tried. An angle
is accepted only if the pose is also feasible (inside the workspace, above the floor). If no
direction clears within ``MAX_ESCAPE_ANGLE`` the guard returns ``None`` and the policy holds its
last command, which passed the guard (the wire does not move).

Paths: a command may be clear while the straight move to it is not (the camera on one side of
the wire, the goal on the other). :meth:`ClearanceGuard.detour` sphere-traces that move and, if
it is blocked, gives a way-point that slides along the zone's surface; the policies command it
(state ``planning``). The carriers keep the camera itself out of the zone
(``workspace.region.Workspace.keep_out``), braking like at the cone and the floor.

Cost: the distance is 1-Lipschitz, so a pose within ``d_ref − c`` of the last queried position
``p_ref`` (distance ``d_ref``) is clear without a query; only then is
:meth:`~endocam.task.wire.Wire.nearest_surface` asked (one query), and the search runs only
when too close.

The wire reaches the controller through :class:`~endocam.control.types.PolicyContext` as a
pre-operative model of the structure (its centre line and radius), as a real system would have
from planning images; the ring's pose is still only what the controller observes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.camera import SCOPE_RADIUS
from endocam.geometry import FloatArray
from endocam.kernels import Vec, cross, dot, norm, reject, scaled, unit_checked
from endocam.task.wire import Wire, surface_query
from endocam.view import look_at_columns, rotation_columns
from endocam.workspace.keepout import (
    CACHE_SIZE,
    KeepOutState,
    keep_out_distance,
    keep_out_first_outside,
    remember,
)
from endocam.workspace.region import NO_WORKSPACE, Workspace, WorkspaceState, workspace_margin

CLEARANCE_MARGIN = 2.0e-3  # m, beyond the scope's radius: the carriers' tracking deviation
WIRE_CLEARANCE = SCOPE_RADIUS + CLEARANCE_MARGIN  # m, ControllerConfig.wire_clearance default
AIM_BEYOND = 2.0e-4  # m, a rotated pose aims this far beyond the clearance, so the chord of a
# step (≤ 2 mm) between two such poses stays clear of the zone (sag L²/8R ≈ 0.06 mm, R ≈ 9 mm)
MAX_ESCAPE_ANGLE = math.radians(90.0)  # rad, largest rotation about the pivot that is tried
MIN_ESCAPE_STEP = math.radians(0.5)  # rad, step while the clear pose is infeasible
NEWTON_GAIN = 4.0  # unitless, largest Newton step as a multiple of the conservative one
MAX_ESCAPE_STEPS = 40  # count, queries per direction at most
DETOUR_STEP = 0.005  # m, how far along the zone's surface a detour way-point leads
SAME_SIDE_ANGLE = math.radians(30.0)  # rad, a command within this angle about the wire's axis
# of the edge point is on its side: the detour slides straight on, else it goes round the wire
DETOUR_PUSH = 1.0e-3  # m, a detour way-point sits this far outside the zone
DETOUR_SCALES = (1.0, 0.5, 0.25)  # unitless, fractions of the slide tried, longest first
DETOUR_TOL = 1.0e-5  # m, a traced segment closer than this to the zone is blocked
DETOUR_CREEP = 2.0e-4  # m, trace step from the zone's edge when the segment leaves it
_EPS = 1e-9  # unitless, shorter directions are degenerate
# _apply_kernel's answers: the pose itself, a backed-off or rotated one, none clear, not finite
APPLY_CLEAR, APPLY_ADJUSTED, APPLY_BLOCKED, APPLY_NOT_FINITE = range(4)
APPLY_INFEASIBLE = 4  # _look_at_kernel: the pose's position is outside the workspace


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
def _trace(
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
    for _ in range(MAX_ESCAPE_STEPS):
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
def _lifted(
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
def _detour(
    zone: KeepOutState,
    a: Vec,
    b: Vec,
) -> tuple[bool, Vec]:
    """:meth:`ClearanceGuard.detour` from ``a`` to ``b`` (m): ``(True, way-point)``, m.

    ``(False, a)`` when the straight move keeps the clearance.
    """
    pts, table, pool, meta, radius, _, _, clearance = zone
    blocked, x = _trace(zone, a, b)
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
        ok, via = _lifted(pts, table, pool, meta, radius, clearance, p)
        if ok:
            blocked, _ = _trace(zone, a, via)
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
    """:meth:`ClearanceGuard.apply`'s check of a pose at ``p`` and :meth:`~ClearanceGuard.detour`.

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
    found, via = _detour(zone, now, p)
    return True, found, via


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
def _apply_kernel(
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
def _look_at_kernel(
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


class ClearanceGuard:
    """Keeps commanded camera positions ``clearance`` from the wire's surface (module docstring).

    Parameters
    ----------
    wire : Wire
        The structure to avoid (its centre line and tube radius), world, m.
    clearance : float
        Smallest distance from the camera's optical centre to the tube's surface, m (≥ 0).
    """

    def __init__(self, wire: Wire, clearance: float) -> None:
        if not (math.isfinite(clearance) and clearance >= 0.0):
            raise ValueError(f"clearance must be ≥ 0 m, got {clearance}")
        self.wire = wire
        self.clearance = float(clearance)
        self._ref = np.zeros((CACHE_SIZE, 4))  # the last queries: point (m), distance (m)
        self._nref = np.zeros(1, dtype=np.int64)  # rows of _ref in use, newest first
        self._state = KeepOutState(
            *wire.query_state, wire.radius, self._ref, self._nref, self.clearance
        )
        self._escape = np.zeros(4)  # the direction of the last rotation: flag, unit (3,), world
        self._workspace: Workspace | None = None  # the last workspace given to apply()
        self._workspace_args: tuple[int, WorkspaceState] = (0, NO_WORKSPACE)  # _apply_kernel's
        self.adjusted = 0  # poses rotated this episode
        self.blocked = 0  # poses with no clear, feasible rotation this episode

    def reset(self) -> None:
        """Forget the cached query and the escape direction (a new episode)."""
        self._nref[0] = 0
        self._escape[0] = 0.0
        self.adjusted = 0
        self.blocked = 0

    def distance(self, p_world: Sequence[float], exact_below: float = 0.0) -> float:
        """Surface distance of a camera position (3,), world, m; one nearest-point query at most.

        The distance is 1-Lipschitz: while ``d_ref − ‖p − p_ref‖`` (the last queries' distance
        less how far the point moved) is at least ``clearance + exact_below`` (m), that lower
        bound is returned without a query. NaN for a non-finite position. Compiled
        (:func:`_distance`).
        """
        return keep_out_distance(self._state, p_world[0], p_world[1], p_world[2], exact_below)

    @property
    def refs(self) -> list[tuple[list[float], float]]:
        """The cached queries, newest first: (point (3,), world, m; surface distance, m)."""
        return [(row[:3], row[3]) for row in self._ref[: self._nref[0]].tolist()]

    def margin(self, p_world: Sequence[float]) -> float:
        """Signed clearance of a camera position (3,), world, m: ≥ 0 clear (``Workspace``).

        Exact when negative, else possibly a lower bound (:meth:`distance`): a carrier that
        compares it with a braking distance then checks its braking path point by point.
        """
        return self.distance(p_world) - self.clearance

    def first_outside(self, p_world: FloatArray, count: int) -> int:
        """The first of ``p_world[:count]`` whose :meth:`margin` is < 0 (or NaN), else ``count``.

        ``p_world`` (N, 3): camera positions, world, m. :meth:`margin` on each in turn, in
        one compiled call (:func:`_first_outside`): the cache ends as those calls leave it.
        """
        p = np.ascontiguousarray(p_world, dtype=float).reshape(-1, 3)
        return keep_out_first_outside(self._state, p, count)

    def is_clear(self, p_world: list[float]) -> bool:
        """Whether a camera position (3,), world, m, keeps the clearance (NaN: not clear)."""
        return self.distance(p_world) >= self.clearance

    def apply(
        self,
        T_world_cam: FloatArray,
        p_world_pivot: Vec,
        workspace: Workspace | None = None,
        p_world_now: Vec | None = None,
        back_off: float = 0.0,
    ) -> FloatArray | None:
        """The commanded pose, or the nearest clear one rotated about the pivot; ``None``: none.

        One compiled call (:func:`_apply_kernel`).

        Parameters
        ----------
        T_world_cam : (4, 4)
            Commanded camera pose, optical frame, world, m.
        p_world_pivot : 3-tuple
            The point the pose looks at (the ring centre), world, m: it keeps its place in the
            camera frame.
        workspace : Workspace or None
            Where a camera position may be commanded (``Workspace.margin(p) >= 0``: the cone,
            the floor and its own keep-out guard, whose cache the checks update); ``None``:
            everywhere.
        p_world_now : 3-tuple or None
            Where the camera is now, world, m: without a remembered escape direction the pose
            turns towards it first (the camera need not cross the wire to reach it).
        back_off : float
            How far the pose may first move back along its optical axis, m (the look distance
            grows, the view's direction is kept); it turns only if that does not clear.

        Returns
        -------
        (4, 4) or None
            ``T_world_cam`` itself when clear; a rotated, clear and feasible pose; or ``None``
            (non-finite input, or no clear feasible rotation up to ``MAX_ESCAPE_ANGLE``).
        """
        c, now = p_world_pivot, p_world_now
        T = np.empty((4, 4))  # the adjusted pose, if any (a new array: the caller keeps it)
        code = _apply_kernel(
            self._state,
            np.asarray(T_world_cam, dtype=float),
            (float(c[0]), float(c[1]), float(c[2])),
            now is not None,
            (0.0, 0.0, 0.0) if now is None else (float(now[0]), float(now[1]), float(now[2])),
            float(back_off),
            self._escape,
            *self._feasible_args(workspace),
            T,
        )
        if code == APPLY_CLEAR:
            return T_world_cam
        if code == APPLY_ADJUSTED:
            self.adjusted += 1
            return T
        if code == APPLY_BLOCKED:
            self.blocked += 1
        return None

    def apply_look_at(
        self,
        p_world: Vec,
        p_world_pivot: Vec,
        fallback: FloatArray,
        previous: FloatArray,
        workspace: Workspace,
        p_world_now: Vec | None = None,
        back_off: float = 0.0,
        check: bool = True,
    ) -> FloatArray | None:
        """:meth:`apply` of the pose at ``p_world`` looking at the pivot, if it is feasible.

        The pose: ``view.look_at_unchecked(p_world, p_world_pivot, fallback, previous)`` (a
        level horizon, the roll kept from ``previous`` (4, 4) near the vertical; ``fallback``
        (4, 4) itself when the two points coincide). ``None`` when ``p_world`` (3,), world,
        m, is outside the ``workspace`` (``Workspace.margin < 0``; asked only if ``check``),
        else :meth:`apply`'s answer. One compiled call (:func:`_look_at_kernel`).
        """
        p, c, now = p_world, p_world_pivot, p_world_now
        T = np.empty((4, 4))  # the pose, if any (a new array: the caller keeps it)
        code, fell_back = _look_at_kernel(
            self._state,
            (float(p[0]), float(p[1]), float(p[2])),
            (float(c[0]), float(c[1]), float(c[2])),
            fallback,
            previous,
            check,
            now is not None,
            (0.0, 0.0, 0.0) if now is None else (float(now[0]), float(now[1]), float(now[2])),
            float(back_off),
            self._escape,
            *self._feasible_args(workspace),
            T,
        )
        if code == APPLY_CLEAR:
            return fallback if fell_back else T
        if code == APPLY_ADJUSTED:
            self.adjusted += 1
            return T
        if code == APPLY_BLOCKED:
            self.blocked += 1
        return None

    def _feasible_args(self, workspace: Workspace | None) -> tuple[int, WorkspaceState]:
        """:func:`_apply_kernel`'s workspace arguments: ``kind`` (0: none, 1: asked), the state."""
        if workspace is None:
            return (0, NO_WORKSPACE)
        if workspace is not self._workspace:
            if type(workspace) is not Workspace:  # a subclass's own margin would go unasked
                raise TypeError(
                    "workspace: the guard's feasibility check is compiled for a "
                    f"workspace.region.Workspace, got {type(workspace).__name__}"
                )
            keep_out = workspace.keep_out
            if keep_out is not None and not isinstance(keep_out, ClearanceGuard):
                raise TypeError("a workspace's keep-out zone must be a ClearanceGuard")
            self._workspace = workspace
            self._workspace_args = (1, workspace.kernel_state)
        return self._workspace_args

    @property
    def kernel_state(self) -> KeepOutState:
        """The arguments compiled callers pass to :func:`_distance` / :func:`_detour` first.

        ``Wire.query_state``'s arrays, the tube radius (m), the Lipschitz cache (``ref``
        (CACHE_SIZE, 4), ``nref`` (1,)) and the clearance (m); the cache is shared, so a
        caller's queries are this guard's.
        """
        return self._state

    def passed(self, T_world_cam: FloatArray) -> FloatArray:
        """:meth:`apply`'s answer for a pose found clear by a compiled caller: the pose itself.

        The caller made :meth:`apply`'s finite check and query (:func:`_distance`, the same
        cache); this records the pass (no escape direction is remembered).
        """
        self._escape[0] = 0.0
        return T_world_cam

    def detour(self, p_world_now: Sequence[float], p_world_cmd: Sequence[float]) -> Vec | None:
        """A way-point around the wire when the straight move to the command would cross it.

        The segment from the camera ``p_world_now`` to the commanded position ``p_world_cmd``
        (both (3,), world, m) is sphere-traced: from a point at surface distance ``d`` the next
        ``d − clearance`` of the segment cannot enter the zone (1-Lipschitz), so one query
        clears a short move. If the trace stops at the zone's edge before the command, the
        way-point slides from there along the zone's surface: the remaining direction with its
        component into the wire removed, ``DETOUR_STEP`` long, pushed ``DETOUR_PUSH`` out.
        One compiled call (:func:`_detour`).

        Returns
        -------
        3-tuple or None
            The way-point, world, m; ``None`` when the straight move keeps the clearance (or
            an end is not finite).
        """
        a, b = p_world_now, p_world_cmd
        found, via = _detour(
            self._state,
            (float(a[0]), float(a[1]), float(a[2])),
            (float(b[0]), float(b[1]), float(b[2])),
        )
        return via if found else None

    def step_out(self, p_world: Sequence[float]) -> Vec | None:
        """``p_world`` (3,), m, moved straight away from the wire to ``DETOUR_PUSH`` past the zone.

        ``None`` when it already lies that far out (or the direction is undefined). The way
        out for a camera standing on the zone's edge: a carrier at rest there may refuse every
        slide along the surface, whose braking path grazes the zone.
        """
        p = (float(p_world[0]), float(p_world[1]), float(p_world[2]))
        pts, table, pool, meta = self.wire.query_state
        ok, lifted = _lifted(pts, table, pool, meta, self.wire.radius, self.clearance, p)
        return lifted if ok and lifted != p else None


def clear_pose_or_none(
    guard: ClearanceGuard | None, T: FloatArray, pivot: Vec, workspace: Workspace | None = None
) -> FloatArray | None:
    """``guard.apply(T, pivot, workspace)``, or ``T`` when there is no guard (no wire model)."""
    return T if guard is None else guard.apply(T, pivot, workspace)


__all__ = ["CLEARANCE_MARGIN", "WIRE_CLEARANCE", "ClearanceGuard", "clear_pose_or_none"]
