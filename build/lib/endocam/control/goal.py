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
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable
from numpy.typing import ArrayLike

from endocam.geometry import UP, FloatArray, as_vector3, unit_vector
from endocam.kernels import Vec, dot, scaled
from endocam.view import pose_from_columns, rotation_columns, vec

SIDE_HYSTERESIS = math.radians(25.0)  # rad, tip below horizontal before a side change
_SIN_SIDE = math.sin(SIDE_HYSTERESIS)
_EPS = 1e-9  # unitless, a projected direction shorter than this is degenerate


@register_jitable  # also callable from compiled kernels (the same source)
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
    n_up = dot(n, up)
    default = 1.0 if n_up >= 0.0 else -1.0
    if z_prev is None:
        return default
    along = -dot(z_prev, n)  # > 0: the previous camera looked from the +n side
    if abs(along) < _EPS:
        return default
    s_prev = 1.0 if along > 0.0 else -1.0
    if s_prev * n_up >= -sin_hysteresis:
        return s_prev
    return default


class DistanceRange(NamedTuple):
    """The working distance's range and its change per control step, m (the windows' rule)."""

    d_min: float
    d_max: float
    step: float


class PreviousAxes(NamedTuple):
    """The previous pose's optical axis ``z`` and x axis ``x``, world (read when ``known``)."""

    known: bool
    z: Vec
    x: Vec


class SideChoice(NamedTuple):
    """How :func:`goal_columns` picks the camera's side (see the module docstring).

    Attributes
    ----------
    up : 3-tuple
        World up, unit.
    hysteresis : float
        ``side_hysteresis``, rad.
    min_height : float
        Lowest camera height along ``up`` the hysteresis may keep, m (``-inf``: none).
    has_toward : bool
        Whether to take the side facing the port (``SideRule.PORT``).
    toward : 3-tuple
        The unit direction from the ring centre to the port (read when ``has_toward``).
    """

    up: Vec
    hysteresis: float
    min_height: float
    has_toward: bool
    toward: Vec


@register_jitable  # also callable from compiled kernels (the same source)
def goal_columns(
    p_c: Vec, n: Vec, d_f: float, previous: PreviousAxes, rule: SideChoice
) -> tuple[Vec, Vec, Vec, Vec]:
    """:func:`goal_pose_unchecked` as rotation columns ``x, y, z`` and position ``p`` (m).

    ``p_c`` the ring centre, world, m; ``n`` its unit normal; ``d_f`` the working distance, m;
    ``previous`` the previous pose's axes (hysteresis and roll); ``rule`` the side rule.
    """
    up, toward, has_toward = rule.up, rule.toward, rule.has_toward
    has_previous, z_prev, x_prev = previous
    side_hysteresis, min_height = rule.hysteresis, rule.min_height
    ref = toward if has_toward else up
    sin_h = math.sin(side_hysteresis)
    if min_height > -math.inf and not has_toward:
        # Keeping the previous side may not take the camera below ``min_height``.
        sin_h = max(0.0, min(sin_h, (dot(p_c, up) - min_height) / d_f))
    if has_previous:
        s = choose_side(n, ref, z_prev, sin_h)
    else:
        s = choose_side(n, ref, None)
    if has_toward and min_height > -math.inf:
        # the port side may never put the camera below ``min_height`` when the other side is higher
        h_c, n_up = dot(p_c, up), dot(n, up)
        if h_c + s * d_f * n_up < min_height and s * n_up < 0.0:
            s = -s
    z = scaled(n, -s)
    if has_previous:
        x, y, zz = rotation_columns(z, up, x_prev)
    else:
        x, y, zz = rotation_columns(z, up, None)
    p = (p_c[0] - d_f * z[0], p_c[1] - d_f * z[1], p_c[2] - d_f * z[2])
    return x, y, zz, p


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
    z_prev = x_prev = up  # unread without a previous pose
    if previous is not None:
        R = previous[:3, :3].tolist()
        z_prev = (R[0][2], R[1][2], R[2][2])
        x_prev = (R[0][0], R[1][0], R[2][0])
    rule = SideChoice(
        up, side_hysteresis, min_height, toward is not None, up if toward is None else toward
    )
    x, y, z, p = goal_columns(p_c, n, d_f, PreviousAxes(previous is not None, z_prev, x_prev), rule)
    return pose_from_columns(x, y, z, p)


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
        toward = vec(unit_vector(as_vector3(port, "port") - p, "port - p_c"))
    return goal_pose_unchecked(
        vec(p), vec(n_u), float(d_f), vec(up_u), prev, side_hysteresis, min_height, toward
    )
