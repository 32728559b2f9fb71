"""Ring trajectories along the wire (paper Sec. IV-B).

``N`` control points are spaced evenly by arc length along the wire. Each holds a position
(x, y, z) in world (m) and Tait–Bryan angles (α, β, γ) (rad) with ``R = Rx(α) Ry(β) Rz(γ)``
(``docs/conventions.md``). The ring passes through them at evenly spaced times: a cubic position
spline (zero velocity at both ends) and a C² rotation spline (scipy ``RotationSpline``).

Ideal control points centre the ring on the wire with its face normal (ring z) along the wire's
tangent and its handle (ring +x) pointing as far up as possible. Noisy control points add, to each
of the six values, an offset of magnitude uniform in the configured ``[lo, hi]`` with a random
sign (our reading of the paper's "position threshold 3-3.5 mm, angular threshold 10-30°").
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline

from endocam.geometry import UP, FloatArray, R_from_euler_xyz, euler_xyz_from_R
from endocam.task.config import TaskConfig, TrajectoryConfig
from endocam.task.wire import Wire

_EPS_DIR = 1e-9  # unitless, below this the tangent is taken as vertical


class TrajectoryKind(StrEnum):
    """Which control points to generate."""

    IDEAL = "ideal"
    NOISY = "noisy"


@dataclass(frozen=True)
class ControlPoints:
    """Ring poses to pass through, in order along the wire.

    Attributes
    ----------
    positions : (n, 3)
        Ring centres in world, m.
    euler_xyz : (n, 3)
        Tait–Bryan angles (α, β, γ), rad, with ``R_world_ring = Rx(α) Ry(β) Rz(γ)``.
    arc_length : (n,)
        Arc length of the wire point each control point was built from, m.
    """

    positions: FloatArray
    euler_xyz: FloatArray
    arc_length: FloatArray

    def __post_init__(self) -> None:
        n = self.positions.shape[0] if self.positions.ndim == 2 else -1
        if n < 2 or self.positions.shape != (n, 3):
            raise ValueError(f"positions must have shape (n, 3), n ≥ 2; got {self.positions.shape}")
        if self.euler_xyz.shape != (n, 3):
            raise ValueError(f"euler_xyz must have shape ({n}, 3), got {self.euler_xyz.shape}")
        if self.arc_length.shape != (n,):
            raise ValueError(f"arc_length must have shape ({n},), got {self.arc_length.shape}")
        if not (np.all(np.isfinite(self.positions)) and np.all(np.isfinite(self.euler_xyz))):
            raise ValueError("control points must be finite")

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    @property
    def rotations(self) -> FloatArray:
        """(n, 3, 3) ring orientations ``R_world_ring``."""
        return R_from_euler_xyz(self.euler_xyz)


def ideal_ring_rotations(wire: Wire, s: ArrayLike) -> FloatArray:
    """Ideal ring orientations at arc lengths ``s``: face normal along the wire, handle up.

    Ring z = wire tangent; ring x = the component of world up orthogonal to the tangent
    (normalised), so the handle along +x points as far up as possible; y = z × x. If the tangent
    is vertical, x falls back to world x projected onto the ring plane.

    Parameters
    ----------
    wire : Wire
    s : (N,)
        Arc lengths, m.

    Returns
    -------
    (N, 3, 3)
        ``R_world_ring``.
    """
    z = np.atleast_2d(wire.tangent(np.atleast_1d(s)))
    x = UP - (z @ UP)[:, None] * z
    norm = np.linalg.norm(x, axis=1)
    vertical = norm < _EPS_DIR
    if np.any(vertical):
        ex = np.array([1.0, 0.0, 0.0])
        x[vertical] = ex - (z[vertical] @ ex)[:, None] * z[vertical]
        norm = np.linalg.norm(x, axis=1)
    x /= norm[:, None]
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def _signed_uniform(
    rng: np.random.Generator, lo: float, hi: float, shape: tuple[int, int]
) -> FloatArray:
    magnitude = rng.uniform(lo, hi, size=shape)
    sign = rng.choice(np.array([-1.0, 1.0]), size=shape)
    return np.asarray(magnitude * sign, dtype=float)


def control_points(
    wire: Wire,
    n: int,
    kind: TrajectoryKind,
    cfg: TrajectoryConfig,
    seed: int | None = None,
) -> ControlPoints:
    """Control points spaced evenly by arc length over ``[end_margin, length − end_margin]``.

    Parameters
    ----------
    wire : Wire
    n : int
        Number of control points, ≥ 2 (paper: 36 or 71).
    kind : TrajectoryKind
        ``IDEAL``: ring centred on the wire, normal along the tangent, handle up. ``NOISY``: the
        ideal values plus, for every one of the six values of every point, an independent offset
        of magnitude uniform in ``cfg.position_noise`` (m, for x, y, z) or ``cfg.angle_noise``
        (rad, for α, β, γ) with a random sign.
    cfg : TrajectoryConfig
        Noise ranges and end margin.
    seed : int, optional
        Seed of ``np.random.default_rng`` for ``NOISY`` (required); ignored for ``IDEAL``.

    Returns
    -------
    ControlPoints
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
        raise ValueError(f"n must be an integer ≥ 2, got {n!r}")
    kind = TrajectoryKind(kind)
    span = wire.length - 2.0 * cfg.end_margin
    if span <= 0.0:
        raise ValueError(f"cfg.end_margin {cfg.end_margin} m leaves no wire to follow")
    s = np.linspace(cfg.end_margin, wire.length - cfg.end_margin, int(n))
    positions = wire.points(s)
    euler = euler_xyz_from_R(ideal_ring_rotations(wire, s))
    if kind is TrajectoryKind.NOISY:
        if seed is None:
            raise ValueError("seed is required for noisy control points")
        rng = np.random.default_rng(seed)
        positions = positions + _signed_uniform(rng, *cfg.position_noise, (int(n), 3))
        euler = euler + _signed_uniform(rng, *cfg.angle_noise, (int(n), 3))
    return ControlPoints(positions=positions, euler_xyz=euler, arc_length=s)


class RingTrajectory:
    """Smooth ring motion through control points at evenly spaced times.

    Parameters
    ----------
    control_points : ControlPoints
        Poses to pass through; the i-th is reached at ``t_i = i · duration / (n − 1)``.
    duration : float
        Total time, s (> 0).
    """

    def __init__(self, control_points: ControlPoints, duration: float) -> None:
        if not np.isfinite(duration) or duration <= 0.0:
            raise ValueError(f"duration must be a positive number of seconds, got {duration}")
        self.control_points = control_points
        self._duration = float(duration)
        self.times = np.linspace(0.0, self._duration, len(control_points))
        self._pos = CubicSpline(self.times, control_points.positions, bc_type="clamped")
        self._vel = self._pos.derivative()
        self._rot = RotationSpline(self.times, Rotation.from_matrix(control_points.rotations))

    @property
    def duration(self) -> float:
        """Total time, s."""
        return self._duration

    def _clamp(self, ts: ArrayLike) -> FloatArray:
        arr = np.atleast_1d(np.asarray(ts, dtype=float))
        if arr.ndim != 1 or not np.all(np.isfinite(arr)):
            raise ValueError("ts must be a finite 1-D array of times in s")
        return np.clip(arr, 0.0, self._duration)

    def poses(self, ts: ArrayLike) -> FloatArray:
        """Ring poses ``T_world_ring`` (N, 4, 4), m, at times ``ts`` (N,), s (clamped)."""
        t = self._clamp(ts)
        T = np.zeros((t.size, 4, 4))
        T[:, :3, :3] = self._rot(t).as_matrix()
        T[:, :3, 3] = self._pos(t)
        T[:, 3, 3] = 1.0
        return T

    def pose(self, t: float) -> FloatArray:
        """Ring pose ``T_world_ring`` (4, 4), m, at time ``t`` (s, clamped to [0, duration])."""
        return self.poses(np.array([t]))[0]

    def linear_velocity(self, ts: ArrayLike) -> FloatArray:
        """Ring-centre velocity (N, 3) in world, m/s, at times ``ts`` (N,), s (clamped)."""
        return np.asarray(self._vel(self._clamp(ts)), dtype=float)

    def angular_rate(self, ts: ArrayLike) -> FloatArray:
        """Rotation-vector rate (N, 3), rad/s, of the orientation spline at ``ts`` (N,), s.

        Its norm equals the angular speed (scipy ``RotationSpline`` first derivative).
        """
        return np.asarray(self._rot(self._clamp(ts), 1), dtype=float)

    def max_point_speed(self, ts: ArrayLike, radius: float) -> float:
        """Largest speed, m/s, over ``ts`` of any point within ``radius`` (m) of the ring centre.

        ``|v| + |ω| · radius``: a Lipschitz constant of every distance to the ring's surface.
        """
        v = np.linalg.norm(self.linear_velocity(ts), axis=1)
        w = np.linalg.norm(self.angular_rate(ts), axis=1)
        return float(np.max(v + w * radius))


def make_trajectory(
    task_cfg: TaskConfig,
    kind: TrajectoryKind,
    n: int | None = None,
    seed: int | None = None,
    wire: Wire | None = None,
) -> RingTrajectory:
    """Build a ring trajectory from the task config.

    Parameters
    ----------
    task_cfg : TaskConfig
    kind : TrajectoryKind
    n : int, optional
        Control points; defaults to ``task_cfg.trajectory.control_points``.
    seed : int, optional
        Noise seed (required for ``NOISY``).
    wire : Wire, optional
        A wire already built from ``task_cfg.wire`` (saves rebuilding it).

    Returns
    -------
    RingTrajectory
        Lasting ``task_cfg.trajectory.duration`` s.
    """
    w = Wire(task_cfg.wire) if wire is None else wire
    count = task_cfg.trajectory.control_points if n is None else n
    cps = control_points(w, count, kind, task_cfg.trajectory, seed)
    return RingTrajectory(cps, task_cfg.trajectory.duration)
