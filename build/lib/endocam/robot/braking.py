"""A ruckig trajectory read once, then sampled and bounded by compiled kernels.

The carriers' workspace guards check a braking path at every control step of it
(:meth:`~endocam.robot.arm_guard.BrakingGuard.brakes_inside`, the free camera's
:class:`~endocam.robot.cartesian.CartesianLimiter`). Ruckig's Python binding answers one
``Trajectory.at_time`` per call; :func:`profile_rows` reads the trajectory's per-DoF profiles
once instead, and :func:`path_positions` evaluates them at every step as ruckig's
``Trajectory::at_time`` does (each section a cubic in time, the brake pre-trajectory first).
``tests/test_braking.py`` holds the samples to ruckig's own ``at_time`` within
``AT_TIME_ATOL`` on random states, brakes included. :func:`profile_extrema` is the lowest and
highest position of one profile (the free camera's braking box).

Each profile is a row of 49 floats, SI units of its DoF (m or rad, and per second): the section
start positions ``p`` (8), velocities ``v`` (8), accelerations ``a`` (8), the section jerks ``j``
(7) and durations ``t`` (7, s); then the brake pre-trajectory (a state beyond the limits): its
duration (s), its two parts' durations (s), start positions, velocities, accelerations and
jerks (2 each; all 0 without a brake).
"""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.geometry import FloatArray

__all__ = [
    "float_rows",
    "path_positions",
    "path_positions_into",
    "profile_extrema",
    "profile_rows",
]

# offsets in a profile row (module docstring)
_P, _V, _A, _J, _T = 0, 8, 16, 24, 31
_BRAKE, _BRAKE_T, _BRAKE_P, _BRAKE_V, _BRAKE_A, _BRAKE_J = 38, 39, 41, 43, 45, 47
ROW_LENGTH = 49  # floats per profile row
_NO_BRAKE = [0.0] * (ROW_LENGTH - _BRAKE)
_PACKED: dict[int, struct.Struct] = {}  # native doubles, by count (packing a list is cheap)


def profile_rows(trajectory: object) -> FloatArray:
    """The profiles of a one-section ruckig ``Trajectory`` (n DoFs) as (n, 49) floats.

    Row layout in the module docstring: each profile's lists as the binding returns them, read
    once (one ``Trajectory.at_time`` costs about as much as reading a profile).
    """
    traj: Any = trajectory
    flat: list[float] = []
    for pr in traj.profiles[0]:
        brake = pr.brake
        flat += pr.p
        flat += pr.v
        flat += pr.a
        flat += pr.j
        flat += pr.t
        if brake.duration > 0.0:
            flat += [brake.duration, *brake.t, *brake.p, *brake.v, *brake.a, *brake.j]
        else:
            flat += _NO_BRAKE
    return float_rows(flat, ROW_LENGTH)


def float_rows(flat: list[float], width: int) -> FloatArray:
    """Python floats as a writable (len(flat) / width, width) array.

    Packed as native doubles (cheaper than ``np.array`` or ``np.fromiter`` of a list).
    """
    n = len(flat)
    packed = _PACKED.get(n) or _PACKED.setdefault(n, struct.Struct(f"{n}d"))
    return np.frombuffer(bytearray(packed.pack(*flat))).reshape(-1, width)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def has_brake(rows: FloatArray) -> bool:
    """Whether any profile of ``rows`` (n, 49) starts with a brake pre-trajectory.

    ruckig brakes first from a state beyond its limits; :func:`profile_extrema` does not count
    that part, :func:`path_positions` does.
    """
    for k in range(rows.shape[0]):
        if rows[k, _BRAKE] > 0.0:
            return True
    return False


@register_jitable  # compiled into path_positions_into (no entry of its own)
def _t_sums(rows: FloatArray) -> FloatArray:
    """Each profile's running sums of its section durations (n, 7), s."""
    out = np.empty((rows.shape[0], 7))
    for k in range(rows.shape[0]):
        total = rows[k, _T]
        out[k, 0] = total
        for i in range(1, 7):
            total = total + rows[k, _T + i]
            out[k, i] = total
    return out


@register_jitable  # compiled into path_positions_into (no entry of its own)
def _integrate_position(t: float, p0: float, v0: float, a0: float, j: float) -> float:
    """Ruckig's ``integrate``, position only: ``p0 + t (v0 + t (a0/2 + t j/6))``."""
    return p0 + t * (v0 + t * (a0 / 2.0 + t * j / 6.0))


@register_jitable  # compiled into path_positions_into (no entry of its own)
def _position_at(
    rows: FloatArray, t_sum: FloatArray, k: int, time: float, duration: float
) -> float:
    """``Trajectory.at_time(time)[0][k]`` of a one-section trajectory, DoF ``k``.

    ``t_sum``: :func:`_t_sums` of ``rows``; ``time``, ``duration``: s.
    """
    r = rows[k]
    t_end = t_sum[k, 6]
    t_brake = r[_BRAKE]
    if time >= duration:  # past the end: ruckig keeps the last acceleration
        return _integrate_position(time - (t_brake + t_end), r[_P + 7], r[_V + 7], r[_A + 7], 0.0)
    if t_brake > 0.0:
        if time < t_brake:  # on the brake pre-trajectory
            part = 0 if time < r[_BRAKE_T] else 1
            t = time - r[_BRAKE_T] if part > 0 else time
            return _integrate_position(
                t, r[_BRAKE_P + part], r[_BRAKE_V + part], r[_BRAKE_A + part], r[_BRAKE_J + part]
            )
        time = time - t_brake
    if time >= t_end:
        return _integrate_position(time - t_end, r[_P + 7], r[_V + 7], r[_A + 7], 0.0)
    index = 0  # std::upper_bound: the first section whose running sum exceeds time
    while index < 7 and not time < t_sum[k, index]:
        index += 1
    t = time - t_sum[k, index - 1] if index > 0 else time
    return _integrate_position(t, r[_P + index], r[_V + index], r[_A + index], r[_J + index])


def path_positions(rows: FloatArray, duration: float, dt: float, steps: int) -> FloatArray:
    """Positions at every control step of a trajectory: (steps, n), the DoFs' units.

    Row ``i − 1`` is ``Trajectory.at_time(min(i · dt, duration))[0]`` for ``i`` in
    ``1 … steps`` (:func:`path_positions_into`).
    """
    out = np.empty((steps, rows.shape[0]))
    path_positions_into(rows, duration, dt, out, steps)
    return out


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def path_positions_into(
    rows: FloatArray, duration: float, dt: float, out: FloatArray, steps: int
) -> None:
    """:func:`path_positions` into the first ``steps`` rows of ``out`` (≥ steps, n).

    Row ``i − 1`` of ``out`` is ``Trajectory.at_time(min(i · dt, duration))[0]`` for ``i`` in
    ``1 … steps`` (a braking guard writes the stop into the row after them). ``rows``:
    :func:`profile_rows` of the trajectory; ``duration``: its ``duration``, s; ``dt``: the
    control period, s.
    """
    n = rows.shape[0]
    t_sum = _t_sums(rows)
    for i in range(1, steps + 1):
        t = i * dt
        time = min(t, duration)
        for k in range(n):
            out[i - 1, k] = _position_at(rows, t_sum, k, time, duration)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def profile_extrema(rows: FloatArray, k: int) -> tuple[float, float]:
    """Lowest and highest position of profile ``k`` of ``rows`` (its brake part not counted).

    Each section is a cubic in time; its extremes lie at its ends or where its velocity, a
    quadratic, crosses zero inside it.
    """
    r = rows[k]
    lo = hi = r[_P]
    for i in range(7):
        x = r[_P + i + 1]
        lo = x if x < lo else lo
        hi = x if x > hi else hi
        T = r[_T + i]
        if not T > 0.0:
            continue
        p, v, a, j = r[_P + i], r[_V + i], r[_A + i], r[_J + i]
        count, r0, r1 = _roots(0.5 * j, a, v)
        for m in range(count):
            s = r0 if m == 0 else r1
            if 0.0 < s < T:
                x = p + s * (v + s * (0.5 * a + s * j / 6.0))
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
