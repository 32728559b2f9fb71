r"""The orientation-aware goal pose (paper Sec. III-B) and the look-at rule it is built from.

The camera looks at the feature centre ``p_c`` along the feature normal ``n`` from the working
distance ``d_f``, with a level horizon:

.. math::

    p_g = p_c + s\,d_f\,n, \qquad z = -s\,n, \qquad x = \frac{z \times u}{\lVert z \times u \rVert},
    \qquad y = z \times x

where ``u`` is world up and ``s = ±1`` keeps the camera above the tissue (``s n·u ≥ 0``). The
paper writes ``x = u × n`` for its normal pointing at the camera; with ``z = −n`` that is the same
axis. ``y·u ≤ 0`` keeps the image upright (image "down" points down in the world).

A camera that enters through a port (an RCM arm) may instead take the side facing the port,
``s n·(p_port − p_c) ≥ 0``: it then looks away from its port, as a wrist of limited bend must
(``SideRule.PORT`` in the controller; ``port=`` here).

Two places need care:

* **Side hysteresis.** For a near-horizontal normal the side sign would flip with noise. Given
  ``previous`` (the last goal or the current camera pose), the previous side is kept until the
  normal tips more than ``side_hysteresis`` below the horizontal on that side.
* **Horizon singularity.** When ``n ∥ u`` the horizon is undefined. The roll is expressed as an
  angle ``φ`` from the level horizon and clamped to ``|φ| ≤ φ_max(c)``, with ``c = ‖z × u‖`` and
  ``φ_max`` falling smoothly from π (for ``c ≤ sin ROLL_HOLD_ANGLE``: the roll of ``previous`` is
  kept) to 0 (for ``c ≥ sin ROLL_LEVEL_ANGLE``: the horizon is level). The roll picked is the one
  closest to ``previous``, so the goal is continuous: there is no NaN and no sudden 180° roll;
  the roll unwinds by at most about ``π / (ROLL_LEVEL_ANGLE − ROLL_HOLD_ANGLE)`` radians per radian
  of tilt. With no ``previous`` the horizon is level and upright wherever it is defined; exactly
  at ``n ∥ up`` the default roll keeps the world x axis pointing right in the image.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from endocam.geometry import UP, FloatArray, as_vector3, unit_vector

ROLL_HOLD_ANGLE = math.radians(2.0)  # rad, tilt of z from vertical below which roll is held
ROLL_LEVEL_ANGLE = math.radians(20.0)  # rad, tilt above which the horizon is exactly level
SIDE_HYSTERESIS = math.radians(10.0)  # rad, default tip below horizontal before a side change
_SIN_HOLD = math.sin(ROLL_HOLD_ANGLE)
_SIN_LEVEL = math.sin(ROLL_LEVEL_ANGLE)
_SIN_SIDE = math.sin(SIDE_HYSTERESIS)
_EPS = 1e-9  # unitless, a projected direction shorter than this is degenerate


def _smoothstep(x: float) -> float:
    """Cubic smoothstep on [0, 1]: 0 below 0, 1 above 1, C¹ in between."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


Vec = tuple[float, float, float]


def _cross(a: Vec, b: Vec) -> Vec:
    """Cross product of two 3-tuples (plain floats: the control loop runs at 1 kHz)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(a: Vec) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _scaled(a: Vec, k: float) -> Vec:
    return (a[0] * k, a[1] * k, a[2] * k)


def _reject(a: Vec, z: Vec) -> Vec:
    """Component of ``a`` perpendicular to the unit vector ``z``."""
    k = _dot(a, z)
    return (a[0] - k * z[0], a[1] - k * z[1], a[2] - k * z[2])


def _default_roll_reference(z: Vec) -> Vec:
    """Documented default roll when there is no ``previous``: world x projected, else world y."""
    for ref in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)):
        x = _reject(ref, z)
        norm = _norm(x)
        if norm > 0.1:
            return _scaled(x, 1.0 / norm)
    raise AssertionError("unreachable: world x and y cannot both be parallel to z")


def _rotation_columns(z: Vec, up: Vec, x_prev: Vec | None) -> tuple[Vec, Vec, Vec]:
    """Columns (x, y, z) of ``R_world_cam`` for the unit optical axis ``z``; see the module doc."""
    x_level = _cross(z, up)
    c = _norm(x_level)
    x_ref: Vec | None = None
    if x_prev is not None:
        x_ref = _reject(x_prev, z)
        n_ref = _norm(x_ref)
        x_ref = _scaled(x_ref, 1.0 / n_ref) if n_ref > _EPS else None
    if x_ref is None:
        if c > _EPS:  # nothing to keep: the level, upright horizon
            return _scaled(x_level, 1.0 / c), _cross(z, _scaled(x_level, 1.0 / c)), z
        x_ref = _default_roll_reference(z)

    if c >= _SIN_LEVEL:
        x = _scaled(x_level, 1.0 / c)
    elif c <= _EPS:
        x = x_ref
    else:
        x_level = _scaled(x_level, 1.0 / c)
        # Signed roll φ from the level horizon to the reference, about z.
        phi = math.atan2(_dot(_cross(x_level, x_ref), z), _dot(x_level, x_ref))
        phi_max = math.pi * (1.0 - _smoothstep((c - _SIN_HOLD) / (_SIN_LEVEL - _SIN_HOLD)))
        phi = min(max(phi, -phi_max), phi_max)
        y_level = _cross(z, x_level)
        cp, sp = math.cos(phi), math.sin(phi)
        x = (
            cp * x_level[0] + sp * y_level[0],
            cp * x_level[1] + sp * y_level[1],
            cp * x_level[2] + sp * y_level[2],
        )
    return x, _cross(z, x), z


def _pose(x: Vec, y: Vec, z: Vec, p: Vec) -> FloatArray:
    return np.array(
        [
            [x[0], y[0], z[0], p[0]],
            [x[1], y[1], z[1], p[1]],
            [x[2], y[2], z[2], p[2]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _vec(a: FloatArray) -> Vec:
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
    x_prev = None if previous_R is None else _vec(previous_R[:, 0])
    x, y, zz = _rotation_columns(_vec(z), _vec(up), x_prev)
    return np.array(_pose(x, y, zz, (0.0, 0.0, 0.0))[:3, :3])


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
    x_prev = None if previous is None else _vec(previous[:3, 0])
    x, y, zz = _rotation_columns(_vec(z), _vec(up_u), x_prev)
    return _pose(x, y, zz, _vec(p))


def look_at_unchecked(
    p_cam: FloatArray, p_target: FloatArray, fallback: FloatArray, previous: FloatArray | None
) -> FloatArray:
    """:func:`look_at_pose` without validation, for the control loop.

    Returns ``fallback`` (4, 4) when the two points coincide (no direction to look along).
    """
    p = _vec(p_cam)
    d = _vec(p_target)
    d = (d[0] - p[0], d[1] - p[1], d[2] - p[2])
    norm = _norm(d)
    if not norm > 1e-9:
        return fallback
    x_prev = None if previous is None else _vec(previous[:3, 0])
    x, y, z = _rotation_columns(_scaled(d, 1.0 / norm), (0.0, 0.0, 1.0), x_prev)
    return _pose(x, y, z, p)


def choose_side(n: Vec, up: Vec, z_prev: Vec | None, sin_hysteresis: float = _SIN_SIDE) -> float:
    """Sign ``s`` (±1) so the camera at ``p_c + s d_f n`` faces the reference side, with hysteresis.

    Parameters
    ----------
    n : 3-tuple
        Unit feature normal in world.
    up : 3-tuple
        Unit reference direction in world: world up for the paper's "above the tissue" rule,
        or the direction from the feature to the camera arm's port (``SideRule.PORT``).
    z_prev : 3-tuple or None
        Optical axis of the previous ``T_world_cam`` in world; the side it looked from is kept
        while ``s n·up ≥ −sin_hysteresis``.
    sin_hysteresis : float
        Sine of how far past perpendicular to ``up`` the normal may tip before the side
        changes (≥ 0).
    """
    n_up = _dot(n, up)
    default = 1.0 if n_up >= 0.0 else -1.0
    if z_prev is None:
        return default
    along = -_dot(z_prev, n)  # > 0: the previous camera looked from the +n side
    if abs(along) < _EPS:
        return default
    s_prev = 1.0 if along > 0.0 else -1.0
    if s_prev * n_up >= -sin_hysteresis:
        return s_prev
    return default


def goal_pose_unchecked(
    p_c: Vec,
    n: Vec,
    d_f: float,
    up: Vec,
    previous: FloatArray | None,
    side_hysteresis: float = SIDE_HYSTERESIS,
    min_height: float = -math.inf,
    toward: Vec | None = None,
) -> FloatArray:
    """:func:`goal_pose` without validation, for the control loop; ``n``, ``up`` unit.

    ``toward`` is the unit direction from ``p_c`` to the port (``None``: the paper's side rule).
    """
    ref = up if toward is None else toward
    sin_h = math.sin(side_hysteresis)
    if min_height > -math.inf and toward is None:
        # Keeping the previous side may not take the camera below ``min_height``.
        sin_h = max(0.0, min(sin_h, (_dot(p_c, up) - min_height) / d_f))
    if previous is None:
        s = choose_side(n, ref, None)
        x_prev = None
    else:
        R = previous[:3, :3].tolist()
        s = choose_side(n, ref, (R[0][2], R[1][2], R[2][2]), sin_h)
        x_prev = (R[0][0], R[1][0], R[2][0])
    if toward is not None and min_height > -math.inf:
        # the port side may never put the camera below ``min_height`` when the other side is higher
        h_c, n_up = _dot(p_c, up), _dot(n, up)
        if h_c + s * d_f * n_up < min_height and s * n_up < 0.0:
            s = -s
    z = _scaled(n, -s)
    x, y, zz = _rotation_columns(z, up, x_prev)
    p = (p_c[0] - d_f * z[0], p_c[1] - d_f * z[1], p_c[2] - d_f * z[2])
    return _pose(x, y, zz, p)


def goal_pose(
    p_c: ArrayLike,
    n: ArrayLike,
    d_f: float,
    *,
    up: ArrayLike = UP,
    previous: ArrayLike | None = None,
    side_hysteresis: float = SIDE_HYSTERESIS,
    min_height: float = -math.inf,
    port: ArrayLike | None = None,
) -> FloatArray:
    r"""Camera goal pose on the feature normal, looking at the feature (paper Sec. III-B).

    Parameters
    ----------
    p_c : (3,)
        Feature (ring) centre in world, m.
    n : (3,)
        Feature normal in world, any non-zero length; its sign does not matter.
    d_f : float
        Working distance from the feature, m (> 0).
    up : (3,)
        World up direction; default +z.
    previous : (4, 4) or None
        The last goal or the current camera pose ``T_world_cam``. Gives hysteresis to the side
        choice and the roll to keep at the horizon singularity (see the module docstring).
    side_hysteresis : float
        How far below horizontal (rad, in [0, π/2)) the normal may tip before the camera
        changes side.
    min_height : float
        Lowest camera height along ``up`` (m, e.g. the board plus a margin) at which the
        hysteresis may keep the previous side; below it the camera changes side at once.
    port : (3,) or None
        Where the camera enters the body (the camera arm's RCM) in world, m. ``None`` (the
        paper's rule): the camera takes the side above the feature (``s n·up ≥ 0``). Given a
        port, it takes the side facing the port (``s n·(port − p_c) ≥ 0``, same hysteresis),
        so a camera on an RCM arm looks away from its port, never back at it; a side whose
        camera would be below ``min_height`` is left for the other when that is higher.

    Returns
    -------
    (4, 4)
        ``T_world_cam``: position ``p_c + s d_f n``, optical axis ``z = −s n`` through ``p_c``,
        level horizon ``x = normalize(z × up)``, ``y = z × x``.

    Raises
    ------
    ValueError
        If ``p_c``, ``n``, ``up`` or ``port`` is not a finite 3-vector, ``n`` or ``up`` is
        zero, ``port`` is at ``p_c``,
        ``d_f`` is not a positive finite number, or ``previous`` is not a finite (4, 4) array.
    """
    p = as_vector3(p_c, "p_c")
    n_u = unit_vector(n, "n")
    up_u = unit_vector(up, "up")
    if not isinstance(d_f, int | float | np.floating | np.integer) or not math.isfinite(d_f):
        raise ValueError(f"d_f must be a finite number of metres, got {d_f!r}")
    if d_f <= 0.0:
        raise ValueError(f"d_f must be > 0 m, got {d_f}")
    prev = None
    if previous is not None:
        prev = np.asarray(previous, dtype=float)
        if prev.shape != (4, 4) or not np.all(np.isfinite(prev)):
            raise ValueError("previous must be a finite (4, 4) pose")
    if not 0.0 <= side_hysteresis < 0.5 * math.pi:
        raise ValueError(f"side_hysteresis must be in [0, π/2) rad, got {side_hysteresis}")
    if math.isnan(min_height):
        raise ValueError("min_height must be a number of metres or -inf")
    toward = None
    if port is not None:
        toward = _vec(unit_vector(as_vector3(port, "port") - p, "port - p_c"))
    return goal_pose_unchecked(
        _vec(p), _vec(n_u), float(d_f), _vec(up_u), prev, side_hysteresis, min_height, toward
    )
