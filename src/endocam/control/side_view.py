"""The ``endocam`` tracker's views of the ring: feasibility, side choice, shortening, twist."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba.extending import register_jitable

from endocam.control.goal import goal_columns
from endocam.control.safety import (
    window_code_of,
)
from endocam.geometry import FloatArray
from endocam.kernels import (
    Vec,
    cross,
    dot,
    norm,
)
from endocam.workspace.cone import Cone, cone_margin

MIN_DIRECTION = 1e-9  # unitless: shorter directions are degenerate

# plan_kernel's parameters (``EndocamPolicy._params``), by index
(
    _AIM_FLOOR,  # m, goals keep the camera this high
    _HALF_B,  # m, the left eye's offset (0: centred)
    _D_MIN,
    _D_MAX,
    _D_STEP,  # m, the working distance's range and step
    _SIDE_ANGLE,  # rad, side_change_angle
    _MIN_HEIGHT,  # m, min_camera_height
    _HYSTERESIS,  # rad, side_hysteresis
    _KEEP_SIDE,
    _SHORTEN,
    _PORT_RULE,  # 1.0 / 0.0 flags: keep_side, shorten_when_low, SideRule.PORT
    _WINDOW,  # 9 constants of window_code
) = range(12)
_CONE = _WINDOW + 9  # apex (3), axis (3), tan_half, cos_half, height
_RCM = _CONE + 9  # m, the camera arm's RCM (3)
_JUMP = _RCM + 3  # m, jump_threshold
_CMD_FLOOR = _JUMP + 1  # m, the lowest commanded camera height (the last gate's floor)
_N_PARAMS = _CMD_FLOOR + 1


@register_jitable  # also callable from compiled kernels (the same source)
def angle(a: Vec, b: Vec) -> float:
    """Angle between two unit vectors, rad (atan2 form: accurate near 0 and π)."""
    return math.atan2(norm(cross(a, b)), dot(a, b))


# The goal, view and twist of one step (EndocamPolicy's maths), callable from Python and
# compiled inside ``plan_kernel``. ``cone`` is the cone workspace's constants: apex (3,),
# world, m; unit axis (3,); tan and cos of the half-angle; height, m (``ConeWorkspace``).

Grid = Sequence[Sequence[float]] | FloatArray  # rows of a matrix: lists, tuples or an array


@register_jitable  # also callable from compiled kernels (the same source)
def view_of(
    p_c: Vec, n: Vec, s: float, d: float, aim_floor: float, cone: Cone
) -> tuple[bool, Vec, float, float]:
    """Feasible viewing direction on side ``s``: (found, unit ``u``, angle to ``s n``, margin).

    The angle in rad, the margin in m.

    ``p_c`` ring centre, world, m; ``n`` unit normal; ``d`` look distance, m; ``aim_floor``
    the lowest camera height aimed at, m. ``u`` points from the ring centre to the camera;
    not found if no direction keeps the camera ``aim_floor`` high. The margin is the
    camera's to the cone, m.
    """
    u: Vec = (s * n[0], s * n[1], s * n[2])
    c = (aim_floor - p_c[2]) / d
    err = 0.0
    if u[2] < c:
        if c > 1.0:
            return False, u, err, 0.0
        horiz = math.hypot(u[0], u[1])
        if not horiz > MIN_DIRECTION:
            return False, u, err, 0.0
        k = math.sqrt(1.0 - c * c) / horiz
        u_c = (u[0] * k, u[1] * k, c)
        err = angle(u, u_c)
        u = u_c
    a, axis, tan_half, cos_half, height = cone
    margin = cone_margin(
        p_c[0] + d * u[0], p_c[1] + d * u[1], p_c[2] + d * u[2], a, axis, tan_half, cos_half, height
    )
    return True, u, err, margin


@register_jitable  # also callable from compiled kernels (the same source)
def pose_of(
    p_c: Vec, u: Vec, r: float, has_previous: bool, z_prev: Vec, x_prev: Vec, half_b: float
) -> tuple[Vec, Vec, Vec, Vec]:
    """Look at ``p_c`` from ``p_c + r u`` with a level horizon: columns x, y, z and position.

    ``p_c`` world, m; ``u`` unit; ``r`` m; ``z_prev``, ``x_prev``: the previous pose's axes
    (read if ``has_previous``), for the roll near the vertical; the left eye, ``half_b`` (m)
    left of the centre, on the axis when it is non-zero.
    """
    # ``toward = u`` makes the goal take the side of ``u`` itself: position p_c + r u,
    # optical axis −u, roll from the previous pose near the vertical.
    x, y, z, p = goal_columns(
        p_c, u, r, (0.0, 0.0, 1.0), has_previous, z_prev, x_prev, 0.0, -math.inf, True, u
    )
    if half_b:
        p = (p[0] + half_b * x[0], p[1] + half_b * x[1], p[2] + half_b * x[2])
    return x, y, z, p


@register_jitable  # also callable from compiled kernels (the same source)
def twist_of(a: Grid, b: Grid, delta: float) -> tuple[float, float, float, float, float, float]:
    """Velocity from pose ``a`` to ``b`` (rows, (4, 4)) over ``delta`` s: linear m/s, angular rad/s.

    World frame. ``R_b R_a^T ≈ I + [ω δ]×``: its skew part gives ω (small angle over one
    control period).
    """
    inv = 1.0 / delta
    # m_ij = R_b[i] · R_a[j]; ``0.0 +`` first, as ``sum`` starts (the same float, signed zeros too)
    b0, b1, b2, a0, a1, a2 = b[0], b[1], b[2], a[0], a[1], a[2]
    m21 = 0.0 + b2[0] * a1[0] + b2[1] * a1[1] + b2[2] * a1[2]
    m12 = 0.0 + b1[0] * a2[0] + b1[1] * a2[1] + b1[2] * a2[2]
    m02 = 0.0 + b0[0] * a2[0] + b0[1] * a2[1] + b0[2] * a2[2]
    m20 = 0.0 + b2[0] * a0[0] + b2[1] * a0[1] + b2[2] * a0[2]
    m10 = 0.0 + b1[0] * a0[0] + b1[1] * a0[1] + b1[2] * a0[2]
    m01 = 0.0 + b0[0] * a1[0] + b0[1] * a1[1] + b0[2] * a1[2]
    return (
        (b0[3] - a0[3]) * inv,
        (b1[3] - a1[3]) * inv,
        (b2[3] - a2[3]) * inv,
        0.5 * (m21 - m12) * inv,
        0.5 * (m02 - m20) * inv,
        0.5 * (m10 - m01) * inv,
    )


@register_jitable  # also callable from compiled kernels (the same source)
def rows_of(x: Vec, y: Vec, z: Vec, p: Vec) -> FloatArray:
    """``pose_from_columns`` in a compiled kernel: (4, 4) from columns and position."""
    T = np.empty((4, 4))
    for i in range(3):
        T[i, 0], T[i, 1], T[i, 2], T[i, 3] = x[i], y[i], z[i], p[i]
    T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    return T


@register_jitable  # also callable from compiled kernels (the same source)
def choose_of(
    p_c: Vec,
    n: Vec,
    d: float,
    side: float,
    planned: float,
    limit: float,
    aim_floor: float,
    cone: Cone,
) -> tuple[bool, float, Vec]:
    """Side and viewing direction (keep the side while feasible): (found, ``s``, unit ``u``).

    ``side`` the kept side (0: none yet: the paper's, above the feature); ``planned`` a side
    taken first while its view is feasible (0: none; the oracle's plan); ``limit``
    ``side_change_angle``, rad; the rest as :func:`view_of`'s. Not found: no feasible view.
    """
    if planned != 0.0:
        ok, u, _, margin = view_of(p_c, n, planned, d, aim_floor, cone)
        if ok and margin >= 0.0:
            return True, planned, u
    s = side if side != 0.0 else (1.0 if n[2] >= 0.0 else -1.0)  # Python's ``side or …``
    ok, u, err, margin = view_of(p_c, n, s, d, aim_floor, cone)
    if ok and margin >= 0.0 and (err <= limit or side == 0.0):
        return True, s, u
    ok_o, u_o, err_o, margin_o = view_of(p_c, n, -s, d, aim_floor, cone)
    if ok_o and margin_o >= 0.0:
        if not ok or margin < 0.0 or err_o < err:
            return True, -s, u_o
    if ok and margin >= 0.0:
        return True, s, u  # over the angle, but the other side is no better
    return False, s, u


@register_jitable  # also callable from compiled kernels (the same source)
def shortened_of(
    p_c: Vec,
    n: Vec,
    d: float,
    side: float,
    previous: Grid,
    tips: Grid,
    params: Sequence[float] | FloatArray,
    cone: Cone,
) -> float:
    """Look distance one ``d_f_step`` shorter if the kept view is height-limited, else ``d`` (m).

    Height-limited: the camera on side ``s`` at ``d`` would sit below ``min_camera_height``
    (``s n·up < (h_min − p_c·up) / d``), so it is turned off the normal. A shorter look
    distance lowers the camera's drop below ``p_c`` and lets it turn back. The step is
    taken only if every tip (``tips`` (K, 3), world, m) stays inside the outer window of the
    shortened goal (the window rule keeps priority: the caller shortens only while every tip
    is between the windows). ``previous`` (4, 4) rows: the last goal or command;
    ``params``: :func:`plan_kernel`'s.
    """
    prm = params
    aim_floor = prm[_AIM_FLOOR]
    s = side if side != 0.0 else (1.0 if n[2] >= 0.0 else -1.0)  # Python's ``side or …``
    if not s * n[2] * d < aim_floor - p_c[2]:
        return d
    d_next = d - prm[_D_STEP]
    if d_next < prm[_D_MIN]:
        return d
    ok, u, err, _ = view_of(p_c, n, s, d_next, aim_floor, cone)
    ok_now, _, err_now, _ = view_of(p_c, n, s, d, aim_floor, cone)
    if not ok or (ok_now and not err < err_now):
        return d  # shorter only where it turns the view towards the normal
    z_prev = (previous[0][2], previous[1][2], previous[2][2])
    x_prev = (previous[0][0], previous[1][0], previous[2][0])
    x, y, z, p = pose_of(p_c, u, d_next, True, z_prev, x_prev, prm[_HALF_B])
    goal = (
        (x[0], y[0], z[0], p[0]),
        (x[1], y[1], z[1], p[1]),
        (x[2], y[2], z[2], p[2]),
    )
    code = window_code_of(goal, tips, prm[_WINDOW : _WINDOW + 9])
    return d if code == 0 else d_next
