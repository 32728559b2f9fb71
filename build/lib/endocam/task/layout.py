"""Where things are in the wire-chaser task: its centre, the whole-task view, the instrument tips.

Pure geometry of the task config (no simulator): the episode runner, the scene builder and the
study all take the task's layout from here.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize
from scipy.spatial import ConvexHull

from endocam.camera import StereoCamera
from endocam.geometry import UP, FloatArray, as_vector3, make_pose, unit_vector
from endocam.task.config import InstrumentConfig, RingConfig, TaskConfig, Vec3, WireConfig
from endocam.task.wire import Wire
from endocam.view import rotation_looking_along

__all__ = [
    "VIEW_MARGIN",
    "FramingError",
    "image_fraction",
    "overview_camera_pose",
    "port_view",
    "psm1_tip_in_ring",
    "psm2_pose",
    "task_centre",
    "task_points",
]

VIEW_MARGIN = 0.1  # unitless: spare fraction of each image half-size around the whole task


class FramingError(ValueError):
    """The configured port cannot give a start view of the whole task (a config problem)."""


_FRAMING_TOL_M = 1e-4  # m: the port view's distance from the port is resolved to 0.1 mm
_NO_IMAGE = 1e3  # unitless: the optimiser's finite stand-in for a point without an image
_FRAMING_TOL_RAD = 1e-4  # rad: and its look direction to 0.1 mrad (0.05 px at 415 px/rad)


def psm1_tip_in_ring(ring: RingConfig, instruments: InstrumentConfig) -> FloatArray:
    """(3,) PSM1 tool tip (jaw tips, gripping the handle's end) in the ring frame, m."""
    return np.array([ring.major_radius + ring.handle_length - instruments.jaw_length, 0.0, 0.0])


def psm2_pose(instruments: InstrumentConfig, p_world_tip: ArrayLike | None = None) -> FloatArray:
    """(4, 4) ``T_world_psm2``: origin at the PSM2 tip, +x up its shaft, y horizontal.

    ``p_world_tip`` (3,) is the tip in world, m (default ``instruments.psm2_tip``); the shaft
    keeps ``instruments.psm2_direction`` wherever the tip is (``EpisodeLog.p_world_tips[:, 1]``).
    """
    x = unit_vector(instruments.psm2_direction, "psm2_direction")
    y = np.cross(UP, x)
    y = np.array([0.0, 1.0, 0.0]) if np.linalg.norm(y) < 1e-9 else y / np.linalg.norm(y)
    z = np.cross(x, y)
    tip = instruments.psm2_tip if p_world_tip is None else as_vector3(p_world_tip, "p_world_tip")
    return make_pose(np.column_stack([x, y, z]), tip)


def task_points(task_cfg: TaskConfig) -> FloatArray:
    """(N, 3) points the whole-task view must show: wire, post bases, PSM2's tip, m."""
    return _layout_points(task_cfg.wire, task_cfg.instruments.psm2_tip)


@functools.lru_cache(maxsize=16)
def _layout_points(wire_cfg: WireConfig, psm2_tip: Vec3) -> FloatArray:
    """:func:`task_points` of a wire and a tip (read-only, cached).

    Building the wire's splines costs milliseconds, and every episode asks for its layout
    several times (the centre, the overview) with the same wire.
    """
    wire = Wire(wire_cfg)
    pts = np.vstack([wire.polyline(), wire.post_bases, np.asarray(psm2_tip, dtype=float)])
    pts.setflags(write=False)
    return pts


def task_centre(task_cfg: TaskConfig) -> FloatArray:
    """(3,) centre of the bounding box of the wire, its posts and PSM2's tip, world, m."""
    return _box_centre(task_points(task_cfg))


def _box_centre(pts: FloatArray) -> FloatArray:
    """(3,) centre of the bounding box of points (N, 3), m."""
    return np.asarray(0.5 * (pts.min(axis=0) + pts.max(axis=0)), dtype=float)


def overview_camera_pose(
    task_cfg: TaskConfig,
    camera: StereoCamera,
    elevation: float = math.radians(50.0),
    margin: float = VIEW_MARGIN,
) -> FloatArray:
    """Fixed whole-task camera pose: horizon level, looking down at the wire from the front.

    The optical axis points along +y (towards the back of the board) and down by
    ``elevation``; the camera's x axis is world x (level horizon). It is placed on the line
    through the centre of the wire's bounding box, at the smallest distance that keeps the wire,
    its posts and PSM2's tip inside the image with ``margin`` (fraction of each half-size) spare.

    Parameters
    ----------
    task_cfg : TaskConfig
    camera : StereoCamera
    elevation : float
        Downward tilt of the optical axis below horizontal, rad, in (0, π/2].
    margin : float
        Spare fraction of the image half-size, in [0, 1).

    Returns
    -------
    (4, 4)
        ``T_world_cam`` (optical frame), m.
    """
    if not 0.0 < elevation <= 0.5 * math.pi:
        raise ValueError(f"elevation must be in (0, π/2] rad, got {elevation}")
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"margin must be in [0, 1), got {margin}")
    pts = task_points(task_cfg)
    centre = task_centre(task_cfg)
    z = np.array([0.0, math.cos(elevation), -math.sin(elevation)])
    x = np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    k = camera.intrinsics
    tan_x = (1.0 - margin) * 0.5 * k.width / k.fx
    tan_y = (1.0 - margin) * 0.5 * k.height / k.fy
    d = pts - centre
    dist = np.max(np.maximum(np.abs(d @ x) / tan_x, np.abs(d @ y) / tan_y) - d @ z)
    return make_pose(np.column_stack([x, y, z]), centre - dist * z)


def image_fraction(camera: StereoCamera, T_world_cam: FloatArray, p_world: FloatArray) -> float:
    """How much of the image the points need: the largest offset from the principal point.

    Each point's offset in each eye is divided by the principal point's distance to the image
    edge it heads for (u and v separately); the largest is returned. ``≤ 1``: every point is
    in both eyes' images; ``≤ 1 − margin``: with ``margin`` of each half-size spare.

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (4, 4) ndarray
        Camera (centre) pose, world, optical frame, m.
    p_world : (N, 3) ndarray
        Points, world, m.

    Returns
    -------
    float
        Unitless; ``inf`` when a point has no image (at or behind an eye's image plane).
    """
    k = camera.intrinsics
    worst = 0.0
    for eye in ("left", "right"):
        uv = camera.project(T_world_cam, p_world, eye)
        du, dv = uv[:, 0] - k.cx, uv[:, 1] - k.cy
        fu = np.where(du >= 0.0, du / (k.width - k.cx), -du / k.cx)
        fv = np.where(dv >= 0.0, dv / (k.height - k.cy), -dv / k.cy)
        f = np.maximum(fu, fv)
        if np.isnan(f).any():
            return math.inf
        worst = max(worst, float(f.max()))
    return worst


def _port_pose(p_port: FloatArray, yaw: float, pitch: float, s: float, roll: float) -> FloatArray:
    """(4, 4) camera ``s`` m from the port along its optical axis, world, m.

    The axis has azimuth ``yaw`` and depression ``pitch`` (rad); the image is turned by ``roll``
    (rad) about it from the level horizon.
    """
    cp = math.cos(pitch)
    z = np.array([cp * math.cos(yaw), cp * math.sin(yaw), -math.sin(pitch)])
    R = rotation_looking_along(z, UP, None)
    c, sn = math.cos(roll), math.sin(roll)
    R = R @ np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    return make_pose(R, p_port + s * z)


def port_view(
    task_cfg: TaskConfig,
    camera: StereoCamera,
    p_world_port: Vec3,
    gap: float,
    margin: float = VIEW_MARGIN,
    roll: float = 0.0,
) -> tuple[FloatArray, float]:
    """The closest view from a port that frames the whole task, as a surgeon aims a scope.

    The camera looks along a line through the port (the optical axis of a scope in its
    cannula), at least ``gap`` beyond it; the horizon is level, turned by ``roll``. Among
    these views it takes the one nearest to the task (largest distance ``s`` from the port)
    that still shows every task point (:func:`task_points`) in both eyes with ``margin``
    spare: at each ``s`` the look direction minimising :func:`image_fraction` (Nelder–Mead
    from the direction of the task centre), and a bisection over ``s``, along which that
    minimum only grows (moving the camera forward along its axis moves every offset outwards).
    The optimisation uses the convex hull's vertices of the task points: a perspective
    projection's extremes over a convex set lie at its vertices.

    Parameters
    ----------
    task_cfg : TaskConfig
    camera : StereoCamera
    p_world_port : (3,) tuple of float
        The port (the arm's RCM), world, m.
    gap : float
        Least distance from the port to the camera, m (> 0).
    margin : float
        Spare fraction of the image half-size, in [0, 1).
    roll : float
        Image rotation about the optical axis from the level horizon, rad (a carrier that
        cannot level its horizon).

    Returns
    -------
    T_world_cam : (4, 4) ndarray
        The view, world, optical frame, m (a new array).
    look_distance : float
        Distance along the optical axis to the task centre's foot on it, m.

    Raises
    ------
    ValueError
        For a bad ``gap`` or ``margin``.
    FramingError
        When no view from the port frames the task (the message says how much of the image it
        would need).
    """
    instruments = task_cfg.instruments
    T, look = _port_view(
        task_cfg.wire, instruments.psm2_tip, camera, tuple(p_world_port), gap, margin, roll
    )
    return T.copy(), look


@functools.lru_cache(maxsize=16)
def _port_view(
    wire_cfg: WireConfig,
    psm2_tip: Vec3,
    camera: StereoCamera,
    p_world_port: tuple[float, ...],
    gap: float,
    margin: float,
    roll: float,
) -> tuple[FloatArray, float]:
    """:func:`port_view`, cached by what it depends on.

    One optimisation per wire, PSM2 tip, camera and port, whatever the trajectory settings.
    """
    if not (math.isfinite(gap) and gap > 0.0):
        raise ValueError(f"gap: must be a positive number of metres, got {gap}")
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"margin must be in [0, 1), got {margin}")
    port = as_vector3(p_world_port, "p_world_port")
    pts = _layout_points(wire_cfg, psm2_tip)
    hull = pts[ConvexHull(pts).vertices]
    centre = _box_centre(pts)
    to_centre = centre - port
    d_centre = float(np.linalg.norm(to_centre))
    if d_centre <= gap:
        raise FramingError(
            f"port: the task centre is {d_centre:.3f} m from the port, not beyond the "
            f"camera's {gap:.3f} m gap"
        )
    yaw0 = math.atan2(to_centre[1], to_centre[0])
    pitch0 = math.asin(-to_centre[2] / d_centre)

    def best(s: float, start: FloatArray) -> tuple[float, FloatArray]:
        res = minimize(
            lambda a: min(
                image_fraction(camera, _port_pose(port, a[0], a[1], s, roll), hull), _NO_IMAGE
            ),
            start,
            method="Nelder-Mead",
            options={"xatol": _FRAMING_TOL_RAD, "fatol": 1e-6},
        )
        return float(res.fun), np.asarray(res.x)

    need, a_lo = best(gap, np.array([yaw0, pitch0]))
    if need >= _NO_IMAGE:
        raise FramingError(
            f"port: from {gap:.3f} m beyond the port, part of the task is behind the camera "
            "whichever way it looks (the port is among the task)"
        )
    if need > 1.0 - margin:
        raise FramingError(
            f"port: no view from {gap:.3f} m beyond the port frames the task: it needs "
            f"{need:.0%} of the image half-size, {1.0 - margin:.0%} allowed"
        )
    lo, hi = gap, d_centre
    while hi - lo > _FRAMING_TOL_M:
        mid = 0.5 * (lo + hi)
        need_mid, a_mid = best(mid, a_lo)
        if need_mid <= 1.0 - margin:
            lo, a_lo = mid, a_mid
        else:
            hi = mid
    T = _port_pose(port, float(a_lo[0]), float(a_lo[1]), lo, roll)
    look = max(float((centre - T[:3, 3]) @ T[:3, 2]), lo)
    T.setflags(write=False)
    return T, look
