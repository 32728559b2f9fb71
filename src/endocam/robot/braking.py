"""A ruckig trajectory read once, then sampled and bounded by compiled kernels.

The carriers' workspace guards check a braking path at every control step of it
(:meth:`~endocam.robot.camera_arm.CameraArm._brakes_inside`, the free camera's
:class:`~endocam.robot.cartesian.CartesianLimiter`). Ruckig's Python binding answers one
``Trajectory.at_time`` per call; :func:`profile_rows` reads the trajectory's per-DoF profiles
once instead, and :func:`path_positions` evaluates them at every step with ruckig's own
arithmetic (``Trajectory::at_time`` and ``integrate`` of ruckig 0.19, compiled without FMA
contraction), so the positions are the same floats. :func:`profile_extrema` is the lowest and
highest position of one profile (the free camera's braking box).

Each profile is a block (8, 8) of floats, SI units of its DoF (m or rad, and per second): the
section start positions ``p`` (8), velocities ``v`` (8), accelerations ``a`` (8), then the
section jerks ``j`` (7), durations ``t`` (7, s) and their running sums ``t_sum`` (7, s); then
the brake pre-trajectory (a state beyond the limits): its two parts' start positions, velocities,
accelerations and jerks (``p0 p1 v0 v1 a0 a1 j0 j1``), and its duration and parts' durations
(s); rows padded with 0.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from endocam.geometry import FloatArray

__all__ = ["path_positions", "profile_extrema", "profile_rows"]

_P, _V, _A, _J, _T, _TSUM, _BRAKE, _BRAKE_T = 0, 1, 2, 3, 4, 5, 6, 7  # rows of a profile block


def profile_rows(trajectory: object) -> FloatArray:
    """The profiles of a one-section ruckig ``Trajectory`` (n DoFs) as (n, 8, 8) floats.

    Block layout in the module docstring; ``t_sum`` is summed as ruckig's ``Profile::check``
    sums it (``t_sum[i] = t_sum[i − 1] + t[i]``).
    """
    traj: Any = trajectory
    profiles = traj.profiles[0]
    out = np.zeros((len(profiles), 8, 8))
    for k, pr in enumerate(profiles):
        brake = pr.brake
        duration = brake.duration
        if duration > 0.0:
            out[k, _BRAKE, 0:2] = brake.p
            out[k, _BRAKE, 2:4] = brake.v
            out[k, _BRAKE, 4:6] = brake.a
            out[k, _BRAKE, 6:8] = brake.j
            out[k, _BRAKE_T, 1:3] = brake.t
        out[k, _BRAKE_T, 0] = duration
        out[k, _P] = pr.p
        out[k, _V] = pr.v
        out[k, _A] = pr.a
        out[k, _J, :7] = pr.j
        out[k, _T, :7] = pr.t
    _fill_t_sum(out)
    return out


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _fill_t_sum(rows: FloatArray) -> None:
    """Write each profile's running sum of its section durations, s (as ruckig sums them)."""
    for k in range(rows.shape[0]):
        total = rows[k, _T, 0]
        rows[k, _TSUM, 0] = total
        for i in range(1, 7):
            total = total + rows[k, _T, i]
            rows[k, _TSUM, i] = total


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _integrate_position(t: float, p0: float, v0: float, a0: float, j: float) -> float:
    """Ruckig's ``integrate``, position only: ``p0 + t (v0 + t (a0/2 + t j/6))``."""
    return p0 + t * (v0 + t * (a0 / 2.0 + t * j / 6.0))


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _position_at(rows: FloatArray, k: int, time: float, duration: float) -> float:
    """``Trajectory.at_time(time)[0][k]`` of a one-section trajectory (ruckig's steps)."""
    t_end = rows[k, _TSUM, 6]
    t_brake = rows[k, _BRAKE_T, 0]
    if time >= duration:  # past the end: ruckig keeps the last acceleration
        return _integrate_position(
            time - (t_brake + t_end), rows[k, _P, 7], rows[k, _V, 7], rows[k, _A, 7], 0.0
        )
    if t_brake > 0.0:
        if time < t_brake:  # on the brake pre-trajectory
            b = rows[k, _BRAKE]
            part = 0 if time < rows[k, _BRAKE_T, 1] else 1
            t = time - rows[k, _BRAKE_T, 1] if part > 0 else time
            return _integrate_position(t, b[part], b[2 + part], b[4 + part], b[6 + part])
        time = time - t_brake
    if time >= t_end:
        return _integrate_position(
            time - t_end, rows[k, _P, 7], rows[k, _V, 7], rows[k, _A, 7], 0.0
        )
    index = 0  # std::upper_bound: the first section whose running sum exceeds time
    while index < 7 and not time < rows[k, _TSUM, index]:
        index += 1
    t = time - rows[k, _TSUM, index - 1] if index > 0 else time
    return _integrate_position(
        t, rows[k, _P, index], rows[k, _V, index], rows[k, _A, index], rows[k, _J, index]
    )


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def path_positions(rows: FloatArray, duration: float, dt: float, steps: int) -> FloatArray:
    """Positions at every control step of a trajectory: (steps, n), the DoFs' units.

    Row ``i − 1`` is ``Trajectory.at_time(min(i · dt, duration))[0]`` for ``i`` in
    ``1 … steps`` (the same floats). ``rows``: :func:`profile_rows` of the trajectory;
    ``duration``: its ``duration``, s; ``dt``: the control period, s.
    """
    n = rows.shape[0]
    out = np.empty((steps, n))
    for i in range(1, steps + 1):
        t = i * dt
        time = duration if duration < t else t  # Python's min(i * dt, duration)
        for k in range(n):
            out[i - 1, k] = _position_at(rows, k, time, duration)
    return out


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def profile_extrema(rows: FloatArray, k: int) -> tuple[float, float]:
    """Lowest and highest position of profile ``k`` of ``rows`` (its brake part is empty).

    Each section is a cubic in time; its extremes lie at its ends or where its velocity, a
    quadratic, crosses zero inside it. Python's ``min``/``max`` order of comparisons.
    """
    p, v, a, j, t = rows[k, _P], rows[k, _V], rows[k, _A], rows[k, _J], rows[k, _T]
    lo = hi = p[0]
    for i in range(7):
        x = p[i + 1]
        lo = x if x < lo else lo
        hi = x if x > hi else hi
        T = t[i]
        if not T > 0.0:
            continue
        count, r0, r1 = _roots(0.5 * j[i], a[i], v[i])
        for m in range(count):
            s = r0 if m == 0 else r1
            if 0.0 < s < T:
                x = p[i] + s * (v[i] + s * (0.5 * a[i] + s * j[i] / 6.0))
                lo = x if x < lo else lo
                hi = x if x > hi else hi
    return lo, hi


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _roots(c2: float, c1: float, c0: float) -> tuple[int, float, float]:
    """Real roots of ``c2 s² + c1 s + c0`` (a line when ``c2`` is 0): their count and them."""
    if c2 == 0.0:
        if c1 != 0.0:
            return 1, -c0 / c1, 0.0
        return 0, 0.0, 0.0
    disc = c1 * c1 - 4.0 * c2 * c0
    if disc < 0.0:
        return 0, 0.0, 0.0
    r = math.sqrt(disc)
    return 2, (-c1 - r) / (2.0 * c2), (-c1 + r) / (2.0 * c2)
