"""The ``endocam`` tracker's compiled step: checks, distance, prediction, side, view, twist."""

from __future__ import annotations

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.control.checks import OBS_OK, observed
from endocam.control.clearance import cleared_move
from endocam.control.goal import goal_columns
from endocam.control.predictor import ring_predict, ring_push
from endocam.control.safety import (
    adjusted_distance,
    window_code_of,
)
from endocam.control.side_view import (
    _AIM_FLOOR,
    _CMD_FLOOR,
    _CONE,
    _D_MAX,
    _D_MIN,
    _D_STEP,
    _HALF_B,
    _HYSTERESIS,
    _JUMP,
    _KEEP_SIDE,
    _MIN_HEIGHT,
    _PORT_RULE,
    _RCM,
    _SHORTEN,
    _SIDE_ANGLE,
    _WINDOW,
    choose_of,
    pose_of,
    rows_of,
    shortened_of,
    twist_of,
    view_of,
)
from endocam.geometry import FloatArray
from endocam.kernels import (
    dist3,
    dot,
    unit_checked,
)
from endocam.workspace.cone import cone_at, cone_margin
from endocam.workspace.keepout import KeepOutState

_NO_PREDICTIONS = np.zeros(0)  # plan_kernel predicts itself

# plan_kernel's scalar results (``out``), by index
_OUT_D, _OUT_FOUND, _OUT_SIDE, _OUT_MARGIN, _OUT_TWIST = range(5)
_OUT_P, _OUT_N, _OUT_U = 5, 8, 11  # ring centre (m), normal, view direction: 3 each
_OUT_CLEARED, _OUT_DETOUR, _OUT_VIA = 14, 15, 16  # the guard's answers on the plain path
_OUT_CAM = 19  # m, the observed camera position (3)
_OUT_CHECK = 22  # the observation's checks (``policies.observed``: OBS_*)
_OUT_INSIDE = 23  # the last gate on the view: inside the cone and above the command floor
_N_OUT = 24


@register_jitable  # also callable from compiled kernels (the same source)
def _identity_into(T: FloatArray, twist: FloatArray) -> None:  # pragma: no cover - compiled
    """Set ``T`` (4, 4) to the identity and ``twist`` (6,) to zero, in place."""
    for i in range(4):
        for j in range(4):
            T[i, j] = 1.0 if i == j else 0.0
    for i in range(6):
        twist[i] = 0.0


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def plan_kernel(
    T_cam: FloatArray,
    T_ring: FloatArray,
    tips: FloatArray,
    previous: FloatArray,
    t: float,
    check: bool,
    has_t_ring: bool,
    t_ring: float,
    given: FloatArray,
    d_f: float,
    fresh: bool,
    side: float,
    planned: float,
    plain: bool,
    release: float,
    view_out: FloatArray,
    twist_out: FloatArray,
    buf: FloatArray,
    count: np.ndarray,
    spacing: int,
    max_age: float,
    gate: FloatArray,
    bounds: FloatArray,
    horizon: float,
    dt: float,
    feedforward: bool,
    params: FloatArray,
    out: FloatArray,
    has_guard: bool,
    zone: KeepOutState,
) -> None:  # pragma: no cover - compiled
    """:meth:`EndocamPolicy.step` from the input checks to the view and its twist.

    If ``check``: the input checks and the ring gate first (``policies.observed`` at ``t`` s,
    the ring captured at ``t_ring`` s unless not ``has_t_ring``, ``max_age`` s, the gate's
    ``state`` and ``bounds``), and an observation they refuse ends the step there with
    ``out[_OUT_CHECK]`` its reason. Then working distance (the windows), prediction, shortening,
    side and view, the view's pose and (speculatively) its feed-forward twist, with the
    interpreter's operations in its order (docs/conventions.md, "Compiled kernels").

    ``T_cam``, ``T_ring`` (4, 4): camera and (checked) ring poses, world, m; ``tips`` (K, 3)
    world, m; ``previous`` (4, 4) the last goal or command. ``buf`` (L, 7), ``count`` (1,),
    ``spacing``: the :class:`RingPredictor`, which gets the ring pose at ``t`` (s) and
    predicts ``horizon`` s ahead (and ``horizon + dt`` for the twist, if ``feedforward``) —
    unless ``given`` (12,) holds those two predictions (centre m, normal; the oracle's;
    else (0,)). ``d_f`` m; ``side`` the kept side (0: none yet); ``planned`` a side to take
    while feasible (0: none); ``params`` (``_N_PARAMS``,) the policy's constants.

    On the step's plain path (``plain``: no transfer under way; the view's margin at least
    ``release``, m; no side change; not a far first goal, ``fresh``: no goal before) it also
    asks the wire's guard (``has_guard``; ``pts`` … ``clearance``: ``ClearanceGuard._state``)
    what the interpreter would ask next: whether the view is clear (``ClearanceGuard.apply``'s
    query) and, if so, whether the move from the camera to it needs a detour
    (``ClearanceGuard.detour``). A view not clear leaves the guard's cache as it was.

    Fills ``out`` (``_N_OUT``,): the new working distance (m), whether a view was found,
    its side, its pose's cone margin (m), whether a twist was computed, the predicted ring
    centre (m) and normal, the view direction, whether the guard found the view clear,
    whether the move needs a detour and its way-point (m), the camera's position (m), the
    checks' answer, and the step's last gate on the view (:func:`inside_of`: inside the cone,
    at or above ``params[_CMD_FLOOR]``), which the step reads when the view is the command.
    Writes the view's pose into ``view_out`` (4, 4) and the goal's twist from
    the view to the next step's into ``twist_out`` (6,): m/s, rad/s, world (meaningful when
    found, and when computed; else the identity and zeros). The caller's arrays, not returned
    ones: numba unpickles the type of every array it returns (~1 us a call).
    """
    prm = params
    cone = cone_at(prm, _CONE)
    out[_OUT_CHECK] = OBS_OK
    if check:
        answer = observed(T_cam, T_ring, t, has_t_ring, t_ring, max_age, gate, bounds, cone, True)
        if answer != OBS_OK:
            out[_OUT_CHECK] = answer
            _identity_into(view_out, twist_out)
            return
    for i in range(3):
        out[_OUT_CAM + i] = T_cam[i, 3]
    code = window_code_of(T_cam, tips, prm[_WINDOW : _WINDOW + 9])
    d_f = adjusted_distance(d_f, code, prm[_D_MIN], prm[_D_MAX], prm[_D_STEP])
    if given.shape[0] == 0:
        _, n_obs = unit_checked((T_ring[0, 2], T_ring[1, 2], T_ring[2, 2]))
        ring_push(buf, count, t, (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3]), n_obs)
        p_c, n = ring_predict(buf, count, spacing, horizon)
    else:
        p_c, n = (given[0], given[1], given[2]), (given[3], given[4], given[5])
    aim_floor, half_b = prm[_AIM_FLOOR], prm[_HALF_B]
    keep_side = prm[_KEEP_SIDE] != 0.0
    if code == 1 and keep_side and prm[_SHORTEN] != 0.0:
        d_f = shortened_of(p_c, n, d_f, side, previous, tips, prm, cone)
    d = d_f
    z_prev = (previous[0, 2], previous[1, 2], previous[2, 2])
    x_prev = (previous[0, 0], previous[1, 0], previous[2, 0])
    if keep_side:
        found, s, u = choose_of(p_c, n, d, side, planned, prm[_SIDE_ANGLE], aim_floor, cone)
    else:  # the orientation policy's side rule
        has_toward, toward = False, n
        if prm[_PORT_RULE] != 0.0:
            has_toward, toward = unit_checked(
                (prm[_RCM] - p_c[0], prm[_RCM + 1] - p_c[1], prm[_RCM + 2] - p_c[2])
            )
        _, _, zz, _ = goal_columns(
            p_c,
            n,
            d,
            (0.0, 0.0, 1.0),
            True,
            z_prev,
            x_prev,
            prm[_HYSTERESIS],
            prm[_MIN_HEIGHT],
            has_toward,
            toward,
        )
        s = -1.0 if dot(zz, n) > 0.0 else 1.0
        found, u = True, (s * n[0], s * n[1], s * n[2])
    out[_OUT_D] = d
    out[_OUT_FOUND] = 1.0 if found else 0.0
    out[_OUT_SIDE] = s
    out[_OUT_TWIST] = out[_OUT_CLEARED] = out[_OUT_DETOUR] = out[_OUT_INSIDE] = 0.0
    for i in range(3):
        out[_OUT_P + i], out[_OUT_N + i], out[_OUT_U + i] = p_c[i], n[i], u[i]
    if not found:
        _identity_into(view_out, twist_out)
        return
    x, y, z, p = pose_of(p_c, u, d, True, z_prev, x_prev, half_b)
    view = view_out
    for i in range(3):
        view[i, 0], view[i, 1], view[i, 2], view[i, 3] = x[i], y[i], z[i], p[i]
    view[3, 0], view[3, 1], view[3, 2], view[3, 3] = 0.0, 0.0, 0.0, 1.0
    for i in range(6):
        twist_out[i] = 0.0
    # the last gate on the view, as the step asks it of a command (inside_kernel's test)
    out[_OUT_INSIDE] = 1.0 if inside_of(view, prm, prm[_CMD_FLOOR]) else 0.0
    out[_OUT_MARGIN] = margin = cone_margin(
        p[0], p[1], p[2], cone[0], cone[1], cone[2], cone[3], cone[4]
    )
    p_cam = (T_cam[0, 3], T_cam[1, 3], T_cam[2, 3])
    if (
        has_guard
        and plain
        and margin >= release
        and not (side != 0.0 and s != side)
        and not (fresh and dist3(p[0], p[1], p[2], p_cam[0], p_cam[1], p_cam[2]) > prm[_JUMP])
    ):
        # The step's plain path (no transfer under way or starting, no freeze): the view is
        # the command unless the guard turns it. ``ClearanceGuard.apply``'s check, then (if
        # clear) ``detour``'s trace from the camera; not clear: the cache is put back, the
        # interpreter asks again.
        cleared, found_via, via = cleared_move(zone, p, p_c, p_cam)
        out[_OUT_CLEARED] = 1.0 if cleared else 0.0
        out[_OUT_DETOUR] = 1.0 if found_via else 0.0
        for i in range(3):
            out[_OUT_VIA + i] = via[i]
    if not feedforward:
        return
    if given.shape[0] == 0:
        p2, n2 = ring_predict(buf, count, spacing, horizon + dt)
    else:
        p2, n2 = (given[6], given[7], given[8]), (given[9], given[10], given[11])
    if keep_side:
        has_u2, u2, _, _ = view_of(p2, n2, s, d, aim_floor, cone)
    else:
        k = 1.0 if dot(u, n) >= 0.0 else -1.0  # ``n2`` signed like ``u`` is relative to ``n``
        has_u2, u2 = True, (k * n2[0], k * n2[1], k * n2[2])
    if has_u2:  # the next goal, its roll from this one
        x2, y2, z2, p2_cam = pose_of(p2, u2, d, True, z, x, half_b)
        v = twist_of(view, rows_of(x2, y2, z2, p2_cam), dt)
        for i in range(6):
            twist_out[i] = v[i]
        out[_OUT_TWIST] = 1.0


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def inside_kernel(T: FloatArray, params: FloatArray, floor: float) -> bool:  # pragma: no cover
    """Whether the pose ``T`` (4, 4), world, m, is inside the cone and at or above ``floor`` (m).

    ``ConeWorkspace.margin(p) >= 0`` (the cone stored in ``params``, :func:`plan_kernel`'s)
    and ``p[2] >= floor`` for its position ``p`` (:func:`inside_of`).
    """
    return inside_of(T, params, floor)


@register_jitable  # also callable from compiled kernels (the same source)
def inside_of(T: FloatArray, params: FloatArray, floor: float) -> bool:  # pragma: no cover
    """:func:`inside_kernel`'s test; :func:`plan_kernel` makes it on its view too."""
    a, axis, tan_half, cos_half, height = cone_at(params, _CONE)
    p = (T[0, 3], T[1, 3], T[2, 3])
    return cone_margin(p[0], p[1], p[2], a, axis, tan_half, cos_half, height) >= 0.0 and (
        p[2] >= floor
    )
