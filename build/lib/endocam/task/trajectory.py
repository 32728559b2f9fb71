"""Ring trajectories along the wire (paper Sec. IV-B).

``N`` control points are spaced evenly by arc length along the wire. Each holds a position
(x, y, z) in world (m) and Tait–Bryan angles (α, β, γ) (rad) with ``R = Rx(α) Ry(β) Rz(γ)``
(``docs/conventions.md``). The ring passes through them at evenly spaced times: a cubic position
spline (zero velocity at both ends) and a C² rotation spline (scipy ``RotationSpline``).

Ideal control points centre the ring on the wire with its face normal (ring z) along the wire's
tangent and its handle (ring +x) pointing as far up as possible. Noisy control points add noise
to all six values. Our reading of the paper's "position threshold 3-3.5 mm, angular threshold
10-30°" treats a threshold as a limit drawn once per trajectory: ``t_p`` uniform in
``position_noise`` bounds how far any control point moves (its offset is uniform in the ball of
radius ``t_p``), ``t_a`` uniform in ``angle_noise`` bounds each angle offset (uniform in
``[−t_a, t_a]``). See docs/world.md for why (touches a person can count).

Clean ends: the first and last control points of a noisy trajectory keep their ideal pose (their
noise is drawn, so the interior points are those of the same seed, then set to zero). The ring
starts and ends centred on the wire, ``R − r − r_w`` (3 mm by default) clear of it, so every
touch is an event with a start and an end inside the video, never one already under way when
the video begins or still under way when it stops.

Legible paths (``TrajectoryConfig.legible_band = (d, g)``, set for the study's paths): the drawn
noise puts the ring within a fraction of a millimetre of the wire many times a minute, touching
or not. :func:`legible_control_points` moves the control points nearest to each such ambiguous
approach, by the least distance along the contact normal, until every local extremum of the
clearance is a touch at least ``d`` deep or a pass at least ``g`` clear.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline

from endocam.geometry import UP, FloatArray, R_from_euler_xyz, euler_xyz_from_R
from endocam.task.config import RingConfig, TaskConfig, TrajectoryConfig
from endocam.task.touches import clearances, contact_normal
from endocam.task.wire import Wire

_EPS_DIR = 1e-9  # unitless, below this the tangent is taken as vertical
LEGIBLE_DT = 4.0e-3  # s, clearance sampling step when looking for ambiguous extrema
LEGIBLE_OVERSHOOT = 20.0e-6  # m, a moved extremum aims this far past the band's edge
LEGIBLE_MAX_ROUNDS = 60  # count, rounds of moves before a path is declared illegible
# count, rounds without fewer ambiguous extrema before a path is declared illegible: the moves
# then undo each other (two extrema pulling one control point to opposite edges). Over 120
# drawn study paths (seeds 0-39 of the three) the longest such plateau before success was 8.
LEGIBLE_STALL_ROUNDS = 12
LEGIBLE_REDRAWS = 8  # count, fresh draws of an illegible noisy path before giving up
LEGIBLE_REDRAW_STREAM = 5  # second entry of a re-draw's seed sequence ([seed, stream, attempt])


class IllegiblePathError(ValueError):
    """A noisy path that :func:`legible_control_points` cannot make legible (one line)."""


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
    position_threshold : float
        Drawn bound on every point's position offset (its distance from the ideal point), m;
        0 for ideal points.
    angle_threshold : float
        Drawn bound on every angle offset ``|dα|, |dβ|, |dγ|``, rad; 0 for ideal points.
    noise_seed : int or None
        Seed the noise was drawn with (None for ideal points); :func:`make_trajectory`'s
        ``seed`` unless that path was illegible and re-drawn (:func:`redraw_seed`).
    """

    positions: FloatArray
    euler_xyz: FloatArray
    arc_length: FloatArray
    position_threshold: float = 0.0
    angle_threshold: float = 0.0
    noise_seed: int | None = None

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
        if not (self.position_threshold >= 0.0 and self.angle_threshold >= 0.0):
            raise ValueError(
                "position_threshold and angle_threshold must be ≥ 0, got "
                f"{self.position_threshold}, {self.angle_threshold}"
            )

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


def _draw_threshold(rng: np.random.Generator, threshold_range: tuple[float, float]) -> float:
    lo, hi = threshold_range
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi):
        raise ValueError(f"threshold_range must satisfy 0 ≤ lo ≤ hi, got {threshold_range}")
    return float(rng.uniform(lo, hi))


def position_offsets(
    rng: np.random.Generator, threshold_range: tuple[float, float], n: int
) -> tuple[float, FloatArray]:
    """Position noise of ``n`` control points: offsets within a distance drawn per trajectory.

    The position threshold ``t_p`` is drawn once, uniform in ``threshold_range``; each point's
    offset (dx, dy, dz) is then uniform in the ball ``|d| ≤ t_p`` (paper Sec. IV-B: the
    threshold bounds how far noise moves a control point).

    Parameters
    ----------
    rng : numpy.random.Generator
    threshold_range : (2,)
        ``[lo, hi]`` of the threshold, m.
    n : int
        Control points.

    Returns
    -------
    threshold : float
        The drawn ``t_p``, m.
    offsets : (n, 3)
        Offsets in world, m, each of norm ≤ ``t_p``.
    """
    threshold = _draw_threshold(rng, threshold_range)
    direction = rng.normal(size=(n, 3))
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), _EPS_DIR)
    radius = threshold * rng.uniform(size=(n, 1)) ** (1.0 / 3.0)  # uniform in the ball's volume
    return threshold, np.asarray(direction * radius, dtype=float)


def angle_offsets(
    rng: np.random.Generator, threshold_range: tuple[float, float], n: int
) -> tuple[float, FloatArray]:
    """Angle noise of ``n`` control points: offsets within an angle drawn per trajectory.

    The angular threshold ``t_a`` is drawn once, uniform in ``threshold_range``; each of the
    three offsets (dα, dβ, dγ) of each point is then uniform in ``[−t_a, t_a]``.

    Parameters
    ----------
    rng : numpy.random.Generator
    threshold_range : (2,)
        ``[lo, hi]`` of the threshold, rad.
    n : int
        Control points.

    Returns
    -------
    threshold : float
        The drawn ``t_a``, rad.
    offsets : (n, 3)
        Offsets of (α, β, γ), rad, each in ``[−t_a, t_a]``.
    """
    threshold = _draw_threshold(rng, threshold_range)
    return threshold, np.asarray(rng.uniform(-threshold, threshold, size=(n, 3)), dtype=float)


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
        ideal values plus noise bounded by two thresholds drawn once per trajectory: a position
        threshold ``t_p`` uniform in ``cfg.position_noise`` (m) and an angular threshold ``t_a``
        uniform in ``cfg.angle_noise`` (rad). Each point's position moves by an offset uniform in
        the ball of radius ``t_p``; each of its angles (α, β, γ) by an offset uniform in
        ``[−t_a, t_a]`` (:func:`position_offsets`, :func:`angle_offsets`). The first and last
        points keep their ideal pose (clean ends, see the module docstring).
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
        t_p, dp = position_offsets(rng, cfg.position_noise, int(n))
        t_a, da = angle_offsets(rng, cfg.angle_noise, int(n))
        for ends in (dp, da):  # clean ends: start and finish centred on the wire, clear of it
            ends[[0, -1]] = 0.0
        return ControlPoints(positions + dp, euler + da, s, t_p, t_a, int(seed))
    return ControlPoints(positions=positions, euler_xyz=euler, arc_length=s)


def ambiguous_extrema(clearance: ArrayLike, band: tuple[float, float]) -> NDArray[np.intp]:
    """Indices of the interior local extrema of ``clearance`` (N,), m, inside the band.

    A minimum or maximum with ``−d < clearance < g`` (``band = (d, g)``, m) is ambiguous: a touch
    shallower than ``d`` or a pass closer than ``g`` (or a touch that almost ends, two that
    almost merge), which no video can tell from its opposite.
    """
    c = np.asarray(clearance, dtype=float)
    i = np.arange(1, c.size - 1)
    lower = (c[i] <= c[i - 1]) & (c[i] < c[i + 1])
    upper = (c[i] >= c[i - 1]) & (c[i] > c[i + 1])
    extrema = i[lower | upper]
    depth, gap = band
    return extrema[(c[extrema] > -depth) & (c[extrema] < gap)]


def legible_control_points(
    cps: ControlPoints,
    wire: Wire,
    ring_cfg: RingConfig,
    duration: float,
    band: tuple[float, float],
) -> ControlPoints:
    """Noisy control points moved so that every approach of the ring to the wire is legible.

    Each round samples the clearance every ``LEGIBLE_DT`` and finds its ambiguous extrema
    (:func:`ambiguous_extrema`). For each, the interior control point nearest in time moves
    along the contact normal (:func:`endocam.task.touches.contact_normal`) by the clearance it
    lacks: to ``−d`` (a touch ``d`` deep) if the extremum is below the band's middle, else to
    ``g`` (a clear pass), ``LEGIBLE_OVERSHOOT`` past the edge; if that would take the point
    farther than ``t_p`` from its ideal point, to the other edge. Rounds repeat until no
    extremum is ambiguous. The angles, the first and last points and every point no extremum
    needs keep their drawn values.

    Parameters
    ----------
    cps : ControlPoints
        Noisy control points (:func:`control_points`).
    wire : Wire
    ring_cfg : RingConfig
    duration : float
        Trajectory duration, s.
    band : (2,)
        ``(d, g)``, m.

    Returns
    -------
    ControlPoints
        The same points, some positions moved (each still within ``t_p`` of its ideal point).

    Raises
    ------
    IllegiblePathError
        If ambiguous extrema remain after ``LEGIBLE_MAX_ROUNDS`` rounds, or after
        ``LEGIBLE_STALL_ROUNDS`` rounds in a row without fewer of them than before, or no edge
        of the band can be reached within ``t_p``.
    """
    depth, gap = band
    middle = 0.5 * (gap - depth)
    n = len(cps)
    ideal = wire.points(cps.arc_length)
    positions = cps.positions.copy()
    t = np.arange(0.0, duration, LEGIBLE_DT)
    t_points = np.linspace(0.0, duration, n)
    fewest, stalled = math.inf, 0
    for _ in range(LEGIBLE_MAX_ROUNDS):
        moved = dataclasses.replace(cps, positions=positions.copy())
        T = RingTrajectory(moved, duration).poses(t)
        c, p = clearances(T, wire, ring_cfg)
        ambiguous = ambiguous_extrema(c, band)
        if ambiguous.size == 0:
            return moved
        fewest, stalled = (ambiguous.size, 0) if ambiguous.size < fewest else (fewest, stalled + 1)
        if stalled >= LEGIBLE_STALL_ROUNDS:
            raise IllegiblePathError(
                f"cannot make the path legible: {ambiguous.size} ambiguous approaches left after "
                f"{LEGIBLE_STALL_ROUNDS} rounds without progress (band {band} m)"
            )
        for j in ambiguous.tolist():
            k = int(np.clip(np.argmin(np.abs(t_points - t[j])), 1, n - 2))
            normal = contact_normal(p[j], T[j], ring_cfg.major_radius)
            near, far = -depth - LEGIBLE_OVERSHOOT, gap + LEGIBLE_OVERSHOOT
            targets = (near, far) if c[j] < middle else (far, near)
            for target in targets:
                candidate = positions[k] + (target - c[j]) * normal
                if np.linalg.norm(candidate - ideal[k]) <= cps.position_threshold:
                    positions[k] = candidate
                    break
            else:
                raise IllegiblePathError(
                    f"cannot make the path legible: control point {k} would leave the position "
                    f"threshold {cps.position_threshold} m"
                )
    raise IllegiblePathError(
        f"cannot make the path legible in {LEGIBLE_MAX_ROUNDS} rounds of moves (band {band} m)"
    )


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


def capture_times(t: ArrayLike, delay: float) -> FloatArray:
    """When the ring poses sensed at times ``t`` (N,), s, were captured, ``delay`` (s) earlier.

    Clipped at 0: before the trajectory starts the sensor sees its first pose. The sensed poses
    are ``trajectory.poses(capture_times(t, delay))``; these are their stamps
    (:attr:`endocam.control.types.Observation.t_ring`).
    """
    return np.clip(np.asarray(t, dtype=float) - delay, 0.0, None)


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
        Lasting ``task_cfg.trajectory.duration`` s; a noisy one made legible
        (:func:`legible_control_points`) when ``task_cfg.trajectory.legible_band`` is set. A
        drawn path that cannot be made legible is drawn again, deterministically, from
        :func:`redraw_seed` ``(seed, 1)``, ``(seed, 2)``, ... (at most ``LEGIBLE_REDRAWS``
        times); ``control_points.noise_seed`` says which seed the path was drawn with.

    Raises
    ------
    IllegiblePathError
        If no draw can be made legible.
    """
    w = Wire(task_cfg.wire) if wire is None else wire
    cfg = task_cfg.trajectory
    count = cfg.control_points if n is None else n
    cps = control_points(w, count, kind, cfg, seed)
    if TrajectoryKind(kind) is TrajectoryKind.NOISY and cfg.legible_band is not None:
        assert seed is not None  # control_points refused a noisy path without one
        for attempt in range(1, LEGIBLE_REDRAWS + 2):
            try:
                cps = legible_control_points(cps, w, task_cfg.ring, cfg.duration, cfg.legible_band)
                break
            except IllegiblePathError as exc:
                if attempt > LEGIBLE_REDRAWS:
                    raise IllegiblePathError(
                        f"noise seed {seed}: {exc}, and in {LEGIBLE_REDRAWS} re-draws"
                    ) from None
                cps = control_points(w, count, kind, cfg, redraw_seed(seed, attempt))
    return RingTrajectory(cps, cfg.duration)


def redraw_seed(seed: int, attempt: int) -> int:
    """Noise seed of the ``attempt``-th re-draw (≥ 1) of an illegible path drawn with ``seed``.

    A draw of ``numpy.random.default_rng([seed, LEGIBLE_REDRAW_STREAM, attempt])`` in
    ``[0, 2**31)``: the same seed always gives the same path, and no other seed's first draw is
    reused on purpose.
    """
    if seed < 0 or attempt < 1:
        raise ValueError(f"seed must be ≥ 0 and attempt ≥ 1, got {seed}, {attempt}")
    return int(np.random.default_rng([seed, LEGIBLE_REDRAW_STREAM, attempt]).integers(0, 2**31))
