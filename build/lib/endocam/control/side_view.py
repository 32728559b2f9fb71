"""The ``endocam`` tracker's views of the ring: feasibility, side choice, shortening, twist.

The camera looks at the ring centre ``p_c`` from side ``s = ±1`` (position ``p_c + s d u``),
kept above ``aim_floor`` and inside the cone (``tracker.py``'s module docstring, items 1 and 6).
Every function here is ``register_jitable``: plain Python from Python (the oracle's plan), and
compiled inside the tracker's step (:func:`endocam.control.plan.plan_step`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from endocam.control.goal import DistanceRange, PreviousAxes, SideChoice, goal_columns
from endocam.control.windows import window_code_of
from endocam.geometry import FloatArray
from endocam.kernels import Vec, cross, dot, norm
from endocam.workspace.cone import Cone, cone_margin

__all__ = [
    "MIN_DIRECTION",
    "SideView",
    "View",
    "ViewRule",
    "angle",
    "choose_of",
    "pose_of",
    "rows_of",
    "shortened_of",
    "twist_of",
    "view_of",
]

MIN_DIRECTION = 1e-9  # unitless: shorter directions are degenerate
_UP = (0.0, 0.0, 1.0)  # world up

Grid = Sequence[Sequence[float]] | FloatArray  # rows of a matrix: lists, tuples or an array


class ViewRule(NamedTuple):
    """The kept side's view settings for an episode.

    Attributes
    ----------
    aim_floor : float
        The lowest camera height a view aims at, m (``min_camera_height + floor_clearance``).
    half_b : float
        The left eye's offset along the camera's x axis, m (0: the midpoint is centred).
    side_angle : float
        ``side_change_angle``, rad.
    cone : Cone
        The cone workspace's constants (``cone_at``).
    """

    aim_floor: float
    half_b: float
    side_angle: float
    cone: Cone


class View(NamedTuple):
    """A viewing direction on one side.

    ``found``: feasible; unit ``u`` (ring centre to camera); its ``error`` to ``s n``, rad; the
    camera's cone ``margin``, m.
    """

    found: bool
    u: Vec
    error: float
    margin: float


class SideView(NamedTuple):
    """The side chosen (``found``: a feasible one), ``side`` ±1 and its unit direction ``u``."""

    found: bool
    side: float
    u: Vec


@register_jitable  # also callable from compiled kernels (the same source)
def angle(a: Vec, b: Vec) -> float:
    """Angle between two unit vectors, rad (atan2 form: accurate near 0 and π)."""
    return math.atan2(norm(cross(a, b)), dot(a, b))


@register_jitable  # also callable from compiled kernels (the same source)
def view_of(rule: ViewRule, p_c: Vec, n: Vec, s: float, d: float) -> View:
    """The feasible view of ``p_c`` (world, m; unit normal ``n``) on side ``s`` from ``d`` m.

    ``u = s n`` when that camera is at least ``rule.aim_floor`` high, else the nearest direction
    that keeps it there (not found if none does).
    """
    u: Vec = (s * n[0], s * n[1], s * n[2])
    c = (rule.aim_floor - p_c[2]) / d
    err = 0.0
    if u[2] < c:
        if c > 1.0:
            return View(False, u, err, 0.0)
        horiz = math.hypot(u[0], u[1])
        if not horiz > MIN_DIRECTION:
            return View(False, u, err, 0.0)
        k = math.sqrt(1.0 - c * c) / horiz
        u_c = (u[0] * k, u[1] * k, c)
        err = angle(u, u_c)
        u = u_c
    a, axis, tan_half, cos_half, height = rule.cone
    margin = cone_margin(
        p_c[0] + d * u[0], p_c[1] + d * u[1], p_c[2] + d * u[2], a, axis, tan_half, cos_half, height
    )
    return View(True, u, err, margin)


@register_jitable  # also callable from compiled kernels (the same source)
def pose_of(
    p_c: Vec, u: Vec, r: float, previous: PreviousAxes, half_b: float
) -> tuple[Vec, Vec, Vec, Vec]:
    """Look at ``p_c`` from ``p_c + r u`` with a level horizon: columns x, y, z and position.

    ``p_c`` world, m; ``u`` unit; ``r`` m; ``previous``: the previous pose's axes, for the
    roll near the vertical; the left eye, ``half_b`` (m) left of the centre, on the axis.
    """
    # ``toward = u`` makes the goal take the side of ``u`` itself: position p_c + r u,
    # optical axis −u, roll from the previous pose near the vertical.
    x, y, z, p = goal_columns(p_c, u, r, previous, SideChoice(_UP, 0.0, -math.inf, True, u))
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
    b0, b1, b2, a0, a1, a2 = b[0], b[1], b[2], a[0], a[1], a[2]
    # m_ij = R_b[i] · R_a[j]
    m21 = b2[0] * a1[0] + b2[1] * a1[1] + b2[2] * a1[2]
    m12 = b1[0] * a2[0] + b1[1] * a2[1] + b1[2] * a2[2]
    m02 = b0[0] * a2[0] + b0[1] * a2[1] + b0[2] * a2[2]
    m20 = b2[0] * a0[0] + b2[1] * a0[1] + b2[2] * a0[2]
    m10 = b1[0] * a0[0] + b1[1] * a0[1] + b1[2] * a0[2]
    m01 = b0[0] * a1[0] + b0[1] * a1[1] + b0[2] * a1[2]
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
def choose_of(rule: ViewRule, p_c: Vec, n: Vec, d: float, side: float, planned: float) -> SideView:
    """Side and viewing direction, keeping the side while its view is feasible.

    ``side`` the kept side (0: none yet: the paper's, above the feature); ``planned`` a side
    taken first while its view is feasible (0: none; the oracle's plan). The kept side changes
    when its view turns more than ``rule.side_angle`` from the normal (or is infeasible) and
    the other side's is better. Not found: no feasible view.
    """
    if planned != 0.0:
        view = view_of(rule, p_c, n, planned, d)
        if view.found and view.margin >= 0.0:
            return SideView(True, planned, view.u)
    s = side if side != 0.0 else (1.0 if n[2] >= 0.0 else -1.0)  # none yet: above the feature
    kept = view_of(rule, p_c, n, s, d)
    kept_ok = kept.found and kept.margin >= 0.0
    if kept_ok and (kept.error <= rule.side_angle or side == 0.0):
        return SideView(True, s, kept.u)
    other = view_of(rule, p_c, n, -s, d)
    worse = not kept.found or kept.margin < 0.0 or other.error < kept.error
    if other.found and other.margin >= 0.0 and worse:
        return SideView(True, -s, other.u)
    if kept_ok:
        return SideView(True, s, kept.u)  # over the angle, but the other side is no better
    return SideView(False, s, kept.u)


@register_jitable  # also callable from compiled kernels (the same source)
def shortened_of(
    rule: ViewRule,
    distance: DistanceRange,
    windows: Sequence[float],
    p_c: Vec,
    n: Vec,
    d: float,
    side: float,
    previous: Grid,
    tips: Grid,
) -> float:
    """Look distance one ``distance.step`` shorter if the kept view is height-limited, else ``d``.

    Height-limited: the camera on side ``s`` at ``d`` (m) would sit below ``rule.aim_floor``
    (``s n·up < (h − p_c·up) / d``), so it is turned off the normal. A shorter look distance
    lowers the camera's drop below ``p_c`` and lets it turn back. The step is taken only if it
    turns the view towards the normal and every tip (``tips`` (K, 3), world, m) stays inside
    the outer window (``windows``: ``WindowGeometry.constants``) of the shortened goal.
    ``previous`` (4, 4) rows: the last goal or command.
    """
    s = side if side != 0.0 else (1.0 if n[2] >= 0.0 else -1.0)  # none yet: above the feature
    if not s * n[2] * d < rule.aim_floor - p_c[2]:
        return d
    d_next = d - distance.step
    if d_next < distance.d_min:
        return d
    shorter = view_of(rule, p_c, n, s, d_next)
    now = view_of(rule, p_c, n, s, d)
    if not shorter.found or (now.found and not shorter.error < now.error):
        return d  # shorter only where it turns the view towards the normal
    axes = PreviousAxes(
        True,
        (previous[0][2], previous[1][2], previous[2][2]),
        (previous[0][0], previous[1][0], previous[2][0]),
    )
    x, y, z, p = pose_of(p_c, shorter.u, d_next, axes, rule.half_b)
    goal = (
        (x[0], y[0], z[0], p[0]),
        (x[1], y[1], z[1], p[1]),
        (x[2], y[2], z[2], p[2]),
    )
    return d if window_code_of(goal, tips, windows) == 0 else d_next
