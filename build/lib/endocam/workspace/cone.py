"""The cone workspace around the RCM (paper Sec. III-C): the checked object and its compiled margin.

The camera may only be driven autonomously inside a solid cone whose tip is the remote centre of
motion (RCM) and whose axis points at the feature's initial position. :class:`ConeWorkspace` is
the checked numpy-facing object; :func:`cone_margin` and :func:`cone_floor_margin` are the same
maths for compiled callers (``register_jitable``: one source).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import ArrayLike

from endocam.geometry import FloatArray, as_vector3, unit_vector

__all__ = [
    "CONE_BASE_RADIUS",
    "CONE_HEIGHT",
    "ConeWorkspace",
    "cone_at",
    "cone_first_outside",
    "cone_floor_margin",
    "cone_margin",
]

CONE_HEIGHT = 0.30  # m, the PSM-held camera's reach, slightly under the instrument (paper III-C)
CONE_BASE_RADIUS = 0.25  # m; the paper chose 0.10 m for its farther port (docs/world.md)


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
    return min(min(lateral, height - h), h)


@register_jitable  # also callable from compiled kernels (the same source)
def cone_floor_margin(x: float, y: float, z: float, cone: FloatArray, floor: float) -> float:
    """``Workspace.margin`` without its keep-out zone: ``min(cone margin, z − floor)``, m.

    ``(x, y, z)``: the point, world, m; ``cone`` (≥ 9,): ``ConeWorkspace.constants`` (apex,
    unit axis, tan and cos of the half-angle, height); ``floor``: the lowest z, world, m. NaN
    for a non-finite point.
    """
    apex = (cone[0], cone[1], cone[2])
    axis = (cone[3], cone[4], cone[5])
    return min(cone_margin(x, y, z, apex, axis, cone[6], cone[7], cone[8]), z - floor)


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def cone_first_outside(
    p: FloatArray,
    apex: tuple[float, ...],
    axis: tuple[float, ...],
    tan_half: float,
    cos_half: float,
    height: float,
    floor: float,
) -> int:
    """The first row of ``p`` (N, 3), world, m, outside the cone or below ``floor`` (m); N if none.

    A row is outside when ``min(ConeWorkspace.margin(row), row[2] − floor) >= 0`` fails (a
    non-finite row: the cone's margin is NaN), the margin by :func:`cone_margin`.
    """
    for i in range(p.shape[0]):
        x, y, z = p[i, 0], p[i, 1], p[i, 2]
        margin = cone_margin(x, y, z, apex, axis, tan_half, cos_half, height)
        if not min(margin, z - floor) >= 0.0:
            return i
    return p.shape[0]


Cone = tuple[tuple[float, float, float], tuple[float, float, float], float, float, float]


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def _cone_margin_kernel(constants: FloatArray, x: float, y: float, z: float) -> float:
    """:func:`cone_margin` of ``(x, y, z)``, world, m, with the cone's ``constants`` (9,), m."""
    apex, axis, tan_half, cos_half, height = cone_at(constants, 0)
    return cone_margin(x, y, z, apex, axis, tan_half, cos_half, height)


@register_jitable  # also callable from compiled kernels (the same source)
def cone_at(values: Sequence[float] | FloatArray, i: int) -> Cone:
    """The cone's constants stored from ``values[i]`` (:attr:`ConeWorkspace.constants`).

    Apex (3,), world, m; unit axis (3,); tan and cos of the half-angle; height, m.
    """
    v = values
    return (v[i], v[i + 1], v[i + 2]), (v[i + 3], v[i + 4], v[i + 5]), v[i + 6], v[i + 7], v[i + 8]


@dataclass(frozen=True)
class ConeWorkspace:
    """A solid cone: tip at the RCM, fixed axis, height and base radius (paper Sec. III-C).

    Attributes
    ----------
    apex : (3,)
        Cone tip = RCM position in world, m.
    axis : (3,)
        Unit axis in world, from the tip towards the base.
    height : float
        Distance from the tip to the base along the axis, m (slightly less than the instrument
        length).
    base_radius : float
        Radius of the base disc, m.
    """

    apex: FloatArray
    axis: FloatArray
    height: float
    base_radius: float = CONE_BASE_RADIUS
    _apex: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _axis: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _tan_half: float = field(init=False, repr=False, compare=False)
    _cos_half: float = field(init=False, repr=False, compare=False)
    _constants: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # Plain-float copies for the control loop (endocam.kernels rule).
        tan_half = self.base_radius / self.height
        object.__setattr__(self, "_apex", tuple(np.asarray(self.apex, dtype=float).tolist()))
        object.__setattr__(self, "_axis", tuple(np.asarray(self.axis, dtype=float).tolist()))
        object.__setattr__(self, "_tan_half", tan_half)
        object.__setattr__(self, "_cos_half", 1.0 / math.sqrt(1.0 + tan_half * tan_half))
        object.__setattr__(self, "_constants", np.array(self.constants))

    @classmethod
    def from_rcm(
        cls,
        p_world_rcm: ArrayLike,
        p_world_feature: ArrayLike,
        height: float,
        base_radius: float = CONE_BASE_RADIUS,
    ) -> ConeWorkspace:
        """Cone from the RCM towards the feature's initial position; the axis is fixed after this.

        Parameters
        ----------
        p_world_rcm : (3,)
            RCM position in world, m.
        p_world_feature : (3,)
            The feature's position at initialisation, m.
        height, base_radius : float
            Cone height and base radius, m (both > 0).
        """
        apex = as_vector3(p_world_rcm, "p_world_rcm")
        axis = unit_vector(as_vector3(p_world_feature, "p_world_feature") - apex, "feature - rcm")
        if not (math.isfinite(height) and height > 0):
            raise ValueError(f"height must be > 0 m, got {height}")
        if not (math.isfinite(base_radius) and base_radius > 0):
            raise ValueError(f"base_radius must be > 0 m, got {base_radius}")
        return cls(apex, axis, float(height), float(base_radius))

    def margin(self, p_world: FloatArray | Sequence[float]) -> float:
        """Signed clearance of a point to the cone surface, m: > 0 inside, < 0 outside.

        The margin is the smaller of the distance to the lateral surface (measured perpendicular
        to the axis, scaled to the surface normal) and the distance to the base plane; points
        behind the tip are outside.

        Parameters
        ----------
        p_world : (3,)
            Point in world, m.

        Compiled (:func:`cone_margin`).
        """
        p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
        return float(_cone_margin_kernel(self._constants, p[0], p[1], p[2]))

    @property
    def constant_array(self) -> FloatArray:
        """:attr:`constants` as a (9,) array, for compiled callers (:func:`cone_at` reads it)."""
        return self._constants

    @property
    def constants(self) -> list[float]:
        """Apex (3,), world, m; unit axis (3,); tan and cos of the half-angle; height, m.

        The order :func:`cone_at` reads (compiled kernels keep them in a parameter array).
        """
        return [*self._apex, *self._axis, self._tan_half, self._cos_half, self.height]

    def first_outside(self, p_world: FloatArray, floor: float = -math.inf) -> int:
        """The first point of ``p_world`` (N, 3), world, m, outside the cone or below ``floor``.

        As ``min(margin(p), p[2] − floor) >= 0`` decides it for each point in turn (compiled:
        :func:`cone_first_outside`); N if none.
        """
        p = np.ascontiguousarray(p_world, dtype=float).reshape(-1, 3)
        return int(
            cone_first_outside(
                p, self._apex, self._axis, self._tan_half, self._cos_half, self.height, floor
            )
        )

    def contains(self, p_world: FloatArray | Sequence[float]) -> bool:
        """Whether a point (3,) in world, m, is inside the cone or on its surface."""
        margin = self.margin(p_world)
        return math.isfinite(margin) and margin >= 0.0
