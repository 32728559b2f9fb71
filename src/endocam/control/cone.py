"""The cone workspace's signed margin (paper Sec. III-C): one source, interpreted and compiled.

Its own module so that both :mod:`endocam.control.safety` (the cone, the workspace) and
:mod:`endocam.control.clearance` (whose compiled search checks the workspace's feasibility)
import it without importing each other; ``control.safety.cone_margin`` is the same function.
"""

from __future__ import annotations

import math

from numba.extending import register_jitable

from endocam.geometry import FloatArray
from endocam.kernels import py_min

__all__ = ["cone_floor_margin", "cone_margin"]


@register_jitable  # also callable from compiled kernels (the same source)
def cone_margin(
    x: float,
    y: float,
    z: float,
    apex: tuple[float, ...],
    axis: tuple[float, ...],
    tan_half: float,
    cos_half: float,
    height: float,
) -> float:
    """:meth:`ConeWorkspace.margin` of the point ``(x, y, z)``, world, m: > 0 inside, m.

    ``apex`` (3,) world, m; ``axis`` (3,) unit, world; ``tan_half``, ``cos_half``: of the
    half-angle; ``height`` m. NaN for a non-finite point.
    """
    a = apex
    k = axis
    d0, d1, d2 = x - a[0], y - a[1], z - a[2]
    h = d0 * k[0] + d1 * k[1] + d2 * k[2]
    r0, r1, r2 = d0 - h * k[0], d1 - h * k[1], d2 - h * k[2]
    radial = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    lateral = (h * tan_half - radial) * cos_half
    if not math.isfinite(h + radial):
        return math.nan
    return py_min(py_min(lateral, height - h), h)  # Python's min(lateral, height - h, h)


@register_jitable  # also callable from compiled kernels (the same source)
def cone_floor_margin(x: float, y: float, z: float, cone: FloatArray, floor: float) -> float:
    """``Workspace.margin`` without its keep-out zone: Python's ``min(cone margin, z − floor)``, m.

    ``(x, y, z)``: the point, world, m; ``cone`` (≥ 9,): ``ConeWorkspace.constants`` (apex,
    unit axis, tan and cos of the half-angle, height); ``floor``: the lowest z, world, m. NaN
    for a non-finite point.
    """
    apex = (cone[0], cone[1], cone[2])
    axis = (cone[3], cone[4], cone[5])
    return py_min(cone_margin(x, y, z, apex, axis, cone[6], cone[7], cone[8]), z - floor)
