r"""The level-horizon look-at shared by the goal, the way-points and an arm's conceded view.

Paper Sec. III-B.

A camera whose optical axis is ``z`` gets ``x = (z × u) / ‖z × u‖`` and ``y = z × x`` (``u``
world up), so its horizon is level and its image upright (``y·u ≤ 0``). When ``z ∥ u`` the
horizon is undefined: the roll is expressed as an angle ``φ`` from the level horizon and clamped
to ``|φ| ≤ φ_max(c)``, with ``c = ‖z × u‖`` and ``φ_max`` falling smoothly from π (for
``c ≤ sin ROLL_HOLD_ANGLE``: the roll of ``previous`` is kept) to 0 (for
``c ≥ sin ROLL_LEVEL_ANGLE``: the horizon is level). The roll picked is the one closest to
``previous``, so the rotation is continuous: no NaN and no sudden 180° roll. With no
``previous`` the horizon is level and upright wherever it is defined; exactly at ``z ∥ up`` the
default roll keeps the world x axis pointing right in the image.

The functions run in the control loop on plain floats (:mod:`endocam.kernels`);
:func:`look_at_pose` and :func:`rotation_looking_along` are the checked numpy API.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import ArrayLike

from endocam.geometry import UP, FloatArray, as_vector3, unit_vector
from endocam.kernels import Vec, cross, dot, dot3, norm, reject, scaled

__all__ = [
    "MIN_LOOK_M",
    "ROLL_HOLD_ANGLE",
    "ROLL_LEVEL_ANGLE",
    "look_at_columns",
    "look_at_pose",
    "look_at_unchecked",
    "look_distance",
    "pose_from_columns",
    "rotation_columns",
    "rotation_looking_along",
    "vec",
]

ROLL_HOLD_ANGLE = math.radians(2.0)  # rad, tilt of z from vertical below which roll is held
ROLL_LEVEL_ANGLE = math.radians(20.0)  # rad, tilt above which the horizon is exactly level
_SIN_HOLD = math.sin(ROLL_HOLD_ANGLE)
_SIN_LEVEL = math.sin(ROLL_LEVEL_ANGLE)
_EPS = 1e-9  # unitless, a projected direction shorter than this is degenerate


@register_jitable  # also callable from compiled kernels (the same source)
def _smoothstep(x: float) -> float:
    """Cubic smoothstep on [0, 1]: 0 below 0, 1 above 1, C¹ in between."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


@register_jitable  # also callable from compiled kernels (the same source)
def _default_roll_reference(z: Vec) -> Vec:
    """Documented default roll when there is no ``previous``: world x projected, else world y."""
    for ref in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)):
        x = reject(ref, z)
        length = norm(x)
        if length > 0.1:
            return scaled(x, 1.0 / length)
    raise AssertionError("unreachable: world x and y cannot both be parallel to z")


@register_jitable  # also callable from compiled kernels (the same source)
def rotation_columns(z: Vec, up: Vec, x_prev: Vec | None) -> tuple[Vec, Vec, Vec]:
    """Columns (x, y, z) of ``R_world_cam`` for the unit optical axis ``z``; see the module doc.

    ``z``, ``up`` (unit) and ``x_prev`` (the previous pose's x axis, or ``None``) in world.
    Compiled kernels call it with ``x_prev`` either a 3-tuple or ``None`` (each its own
    specialisation: the ``is None`` branch is resolved at compile time).
    """
    x_level = cross(z, up)
    c = norm(x_level)
    has_ref = False  # a reference roll to keep (``x_ref`` is then its unit x axis)
    x_ref = x_level
    if x_prev is not None:
        x_ref = reject(x_prev, z)
        n_ref = norm(x_ref)
        if n_ref > _EPS:
            x_ref = scaled(x_ref, 1.0 / n_ref)
            has_ref = True
    if not has_ref:
        if c > _EPS:  # nothing to keep: the level, upright horizon
            return scaled(x_level, 1.0 / c), cross(z, scaled(x_level, 1.0 / c)), z
        x_ref = _default_roll_reference(z)

    if c >= _SIN_LEVEL:
        x = scaled(x_level, 1.0 / c)
    elif c <= _EPS:
        x = x_ref
    else:
        x_level = scaled(x_level, 1.0 / c)
        # Signed roll φ from the level horizon to the reference, about z.
        phi = math.atan2(dot(cross(x_level, x_ref), z), dot(x_level, x_ref))
        phi_max = math.pi * (1.0 - _smoothstep((c - _SIN_HOLD) / (_SIN_LEVEL - _SIN_HOLD)))
        phi = min(max(phi, -phi_max), phi_max)
        y_level = cross(z, x_level)
        cp, sp = math.cos(phi), math.sin(phi)
        x = (
            cp * x_level[0] + sp * y_level[0],
            cp * x_level[1] + sp * y_level[1],
            cp * x_level[2] + sp * y_level[2],
        )
    return x, cross(z, x), z


def pose_from_columns(x: Vec, y: Vec, z: Vec, p: Vec) -> FloatArray:
    """``T`` (4, 4) with rotation columns ``x, y, z`` and translation ``p``."""
    return np.array(
        [
            [x[0], y[0], z[0], p[0]],
            [x[1], y[1], z[1], p[1]],
            [x[2], y[2], z[2], p[2]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def vec(a: FloatArray) -> Vec:
    """A (3,) array as a 3-tuple of floats."""
    v = a.tolist()
    return (v[0], v[1], v[2])


def rotation_looking_along(
    z: FloatArray, up: FloatArray, previous_R: FloatArray | None
) -> FloatArray:
    """Camera rotation ``R_world_cam`` (3, 3) whose optical axis is ``z``, with a level horizon.

    Parameters
    ----------
    z : (3,)
        Unit optical axis in world (from the camera towards the scene).
    up : (3,)
        Unit world up.
    previous_R : (3, 3) or None
        Previous camera rotation in world; its roll is kept near the singularity ``z ∥ up``.

    Returns
    -------
    (3, 3)
        Columns x (right), y (down), z (forward) of the OpenCV optical frame in world.
    """
    x_prev = None if previous_R is None else vec(previous_R[:, 0])
    x, y, zz = rotation_columns(vec(z), vec(up), x_prev)
    return np.array(pose_from_columns(x, y, zz, (0.0, 0.0, 0.0))[:3, :3])


def look_at_pose(
    p_cam: ArrayLike,
    p_target: ArrayLike,
    *,
    up: ArrayLike = UP,
    previous: FloatArray | None = None,
) -> FloatArray:
    """Pose at ``p_cam`` looking at ``p_target`` with a level horizon (paper Sec. III-B, IWPs).

    Parameters
    ----------
    p_cam : (3,)
        Camera position in world, m.
    p_target : (3,)
        Point to look at in world, m; must differ from ``p_cam``.
    up : (3,)
        World up direction (normalised here).
    previous : (4, 4) or None
        Previous ``T_world_cam``; only its rotation is used, for the roll near the singularity.

    Returns
    -------
    (4, 4)
        ``T_world_cam`` in the OpenCV optical frame.
    """
    p = as_vector3(p_cam, "p_cam")
    z = unit_vector(as_vector3(p_target, "p_target") - p, "p_target - p_cam")
    up_u = unit_vector(up, "up")
    x_prev = None if previous is None else vec(previous[:3, 0])
    x, y, zz = rotation_columns(vec(z), vec(up_u), x_prev)
    return pose_from_columns(x, y, zz, vec(p))


@register_jitable  # also callable from compiled kernels (the same source)
def look_at_columns(p: Vec, target: Vec, x_prev: Vec | None) -> tuple[bool, Vec, Vec, Vec]:
    """:func:`look_at_unchecked`'s rotation: ``(found, x, y, z)``, the columns of ``R_world_cam``.

    ``p``, ``target``: the camera and the point it looks at, world, m; ``x_prev``: the previous
    pose's x axis (world) or ``None``. ``found`` is False (and the columns meaningless) when the
    two points coincide (no direction to look along). Compiled kernels call it too (e.g. an
    arm's conceded view, ``robot.camera_arm``): the same source.
    """
    d = (target[0] - p[0], target[1] - p[1], target[2] - p[2])
    length = norm(d)
    if not length > 1e-9:
        return False, d, d, d
    x, y, z = rotation_columns(scaled(d, 1.0 / length), (0.0, 0.0, 1.0), x_prev)
    return True, x, y, z


def look_at_unchecked(
    p_cam: FloatArray, p_target: FloatArray, fallback: FloatArray, previous: FloatArray | None
) -> FloatArray:
    """:func:`look_at_pose` without validation, for the control loop.

    Returns ``fallback`` (4, 4) when the two points coincide (no direction to look along).
    """
    p = vec(p_cam)
    x_prev = None if previous is None else vec(previous[:3, 0])
    found, x, y, z = look_at_columns(p, vec(p_target), x_prev)
    if not found:
        return fallback
    return pose_from_columns(x, y, z, p)


MIN_LOOK_M = 1e-3  # m: a ring closer than this along the optical axis gives no look-at point


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def look_distance(
    T_world_cmd: FloatArray, T_world_ring: FloatArray, d_f: float
) -> float:  # pragma: no cover - compiled
    """Depth of the (sensed) ring centre along a commanded optical axis, m; else ``d_f``.

    The nearest feasible view of a command turns about the point the command looks at: the
    ring centre for the tracking goal (at ``d_f``) and for the way-point poses (farther).
    ``T_world_cmd``, ``T_world_ring`` (4, 4), world, m. The depth is
    ``(T_world_ring[:3, 3] - T_world_cmd[:3, 3]) · T_world_cmd[:3, 2]``; a depth below
    ``MIN_LOOK_M`` or not finite gives ``d_f``.
    """
    R, C = T_world_ring, T_world_cmd
    depth = dot3(R[0, 3] - C[0, 3], R[1, 3] - C[1, 3], R[2, 3] - C[2, 3], C[0, 2], C[1, 2], C[2, 2])
    return depth if depth > MIN_LOOK_M and math.isfinite(depth) else d_f
