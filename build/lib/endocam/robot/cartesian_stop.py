"""The free camera's stop check: whether the camera can still brake to rest inside.

:class:`~endocam.robot.cartesian.CartesianLimiter` accepts a step only if, from the state it
reaches, the camera's position can brake to rest inside the workspace (cone, floor, keep-out
zone). :func:`stop_start` answers most states at once (at rest: the margin; farther inside than
:func:`stop_bound`: yes); the rest ask the braking path itself (:func:`path_inside`: the corners
of the box its profiles span, then, near the keep-out zone or after a brake pre-trajectory,
every control step of it).

Units: m, s (velocities m/s, accelerations m/s², jerks m/s³), world frame.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from endocam.geometry import FloatArray
from endocam.robot.braking import has_brake, path_positions_into, profile_extrema
from endocam.workspace.region import (
    WorkspaceState,
    workspace_all_inside,
    workspace_keep_out_margin,
    workspace_margin,
)

__all__ = [
    "STOP_ASK_PATH",
    "STOP_INSIDE",
    "STOP_OUTSIDE",
    "CartesianState",
    "StopCheck",
    "StopStart",
    "box_corners",
    "path_inside",
    "stop_bound",
    "stop_start",
]

STOP_OUTSIDE, STOP_INSIDE, STOP_ASK_PATH = 0, 1, 2  # StopStart.code: no, yes, ask the path


class StopCheck(NamedTuple):
    """What the stop check reads: the workspace and the position DoFs' per-axis limits.

    Attributes
    ----------
    workspace : WorkspaceState
        ``workspace.region.Workspace.kernel_state``.
    velocity, acceleration, jerk : float
        Per-axis limits of the position DoFs: m/s, m/s², m/s³.
    """

    workspace: WorkspaceState
    velocity: float
    acceleration: float
    jerk: float


class CartesianState(NamedTuple):
    """The camera position's state, world: ``p`` (m), ``v`` (m/s), ``a`` (m/s²), 3 floats each."""

    p: tuple[float, float, float]
    v: tuple[float, float, float]
    a: tuple[float, float, float]


class StopStart(NamedTuple):
    """:func:`stop_start`'s answer: ``code`` (``STOP_*``) and the braking bound (m)."""

    code: int
    bound: float


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def box_corners(rows: FloatArray) -> FloatArray:
    """The eight corners (8, 3), m, of the box a 3-DoF braking path spans.

    ``rows``: the path's :func:`~endocam.robot.braking.profile_rows` (3, 49); per axis its
    lowest and highest position (:func:`~endocam.robot.braking.profile_extrema`, brake part
    not counted), corners in the order ``[[x, y, z] for x in xs for y in ys for z in zs]``.
    """
    ends = np.empty((3, 2))  # per axis: lowest, highest
    for axis in range(3):  # a loop index, not three literal ints: one compiled profile_extrema
        ends[axis, 0], ends[axis, 1] = profile_extrema(rows, axis)
    out = np.empty((8, 3))
    for i in range(2):
        for j in range(2):
            for k in range(2):
                row = 4 * i + 2 * j + k
                out[row, 0], out[row, 1], out[row, 2] = ends[0, i], ends[1, j], ends[2, k]
    return out


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def stop_bound(check: StopCheck, state: CartesianState) -> float:
    """An upper bound of the braking distance from ``state``'s velocity and acceleration, m.

    Per axis (``check``'s limits ``V``, ``A``, ``J``): the speed peaks below
    ``s = min(V, |v| + a²/2J)`` and braking lasts under ``|a|/J + s/A + A/J``, so the axis
    travels less than their product; the bound is the norm of the three.
    """
    V, A, J = check.velocity, check.acceleration, check.jerk
    total = 0.0
    for i in range(3):
        vi, ai = state.v[i], state.a[i]
        s = min(V, abs(vi) + ai * ai / (2.0 * J))
        d = s * (abs(ai) / J + s / A + A / J)
        total += d * d
    return math.sqrt(total)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def stop_start(check: StopCheck, state: CartesianState) -> StopStart:
    """The stop check's start: it can stop inside, it cannot, or ask the braking path.

    At rest, the workspace margin at ``state.p`` decides; farther inside than
    :func:`stop_bound`, yes (``STOP_INSIDE``); else ``STOP_ASK_PATH`` (:func:`path_inside`).
    The bound is returned too (0 at rest).
    """
    x, y, z = state.p
    margin = workspace_margin(check.workspace, x, y, z)
    v, a = state.v, state.a
    if not (v[0] != 0.0 or v[1] != 0.0 or v[2] != 0.0 or a[0] != 0.0 or a[1] != 0.0 or a[2] != 0.0):
        return StopStart(STOP_INSIDE if margin >= 0.0 else STOP_OUTSIDE, 0.0)
    bound = stop_bound(check, state)
    if margin > bound:
        return StopStart(STOP_INSIDE, bound)  # farther inside than any braking can carry it
    return StopStart(STOP_ASK_PATH, bound)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def path_inside(
    ws: WorkspaceState,
    rows: FloatArray,
    duration: float,
    dt: float,
    p: tuple[float, float, float],
    bound: float,
) -> bool:
    """Whether the braking path ``rows`` (3, 49) from ``p`` (m) stays in the workspace ``ws``.

    ``rows``: the path's :func:`~endocam.robot.braking.profile_rows`, ``duration`` its length
    (s), ``dt`` the control period (s), ``bound`` its :func:`stop_bound` (m). The corners of
    the box the path's profiles span must be inside; then a convex region holds the path,
    unless a brake pre-trajectory precedes the profiles; a camera farther from the keep-out
    zone than ``bound`` cannot reach it either; else the path is checked at every control
    step (:func:`~endocam.robot.braking.path_positions_into`).
    """
    if not workspace_all_inside(ws, box_corners(rows)):
        return False
    # The box holds the profiles, not a brake pre-trajectory before them (a state beyond the
    # limits): then the path itself is checked too.
    braked = has_brake(rows)
    if not ws.keep and not braked:
        return True  # a convex region holding the path's box's corners holds the path
    if not braked and (workspace_keep_out_margin(ws, p[0], p[1], p[2]) > bound):
        return True  # farther from the keep-out zone than the braking can carry it
    # a keep-out zone (the wire's) or a brake: the braking path itself, at every control step
    steps = math.ceil(duration / dt - 1e-9)
    points = np.empty((steps, rows.shape[0]))
    path_positions_into(rows, duration, dt, points, steps)
    return workspace_all_inside(ws, points)
