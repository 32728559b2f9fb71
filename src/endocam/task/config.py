"""Validated configuration of the wire-chaser task (paper Sec. IV-A/B), all SI.

Every model is a frozen pydantic v2 model that forbids unknown keys. Lengths are in metres,
angles in radians, times in seconds, colours are RGBA in [0, 1]. File loading (TOML/YAML) is not
done here: a top-level experiment config nests :class:`TaskConfig`.
"""

from __future__ import annotations

import enum
import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from endocam.geometry import FloatArray, R_from_euler_xyz, make_pose
from endocam.task.centreline import centre_line_length

Vec3 = tuple[float, float, float]
Range = tuple[float, float]
RGBA = tuple[float, float, float, float]

# The default wire: a smooth 3D curve through these knots (m), from the left post to the right
# post. It rises, falls and turns in plan view; heights 25-65 mm; length ≈ 0.273 m; tightest
# bend radius ≈ 16 mm (three times the ring's major radius).
DEFAULT_KNOTS: tuple[Vec3, ...] = (
    (-0.105, 0.000, 0.030),
    (-0.075, 0.020, 0.050),
    (-0.045, 0.012, 0.065),
    (-0.015, -0.018, 0.047),
    (0.015, -0.026, 0.026),
    (0.045, -0.008, 0.032),
    (0.072, 0.015, 0.052),
    (0.100, 0.022, 0.040),
)
_FROZEN = ConfigDict(frozen=True, extra="forbid")
# Size bounds: every size a config or the command line can set is bounded, so a typo fails with
# a message instead of an allocation of gigabytes.
MAX_CONTROL_POINTS = 10_000  # count: control points of a trajectory (the paper uses 36 and 71)
MAX_DURATION_S = 3600.0  # s: one episode
MAX_TOUCH_SAMPLES = 5_000_000  # count: duration / touch_sample_dt, the clearance's base samples
MAX_MESH_SEGMENTS = 10_000  # count: segments of a rendered mesh


def _check_finite(values: tuple[float, ...], name: str) -> None:
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} must be finite, got {values}")


def _check_rgba(rgba: RGBA, name: str) -> RGBA:
    if not all(0.0 <= c <= 1.0 for c in rgba):
        raise ValueError(f"{name} components must be in [0, 1], got {rgba}")
    return rgba


def _check_range(value: Range, name: str, upper: float = math.inf) -> Range:
    lo, hi = value
    _check_finite(value, name)
    if not (0.0 <= lo <= hi <= upper):
        raise ValueError(f"{name} must satisfy 0 ≤ lo ≤ hi ≤ {upper}, got {value}")
    return value


class WireConfig(BaseModel):
    """The wire (rail): a cubic spline through ``knots``, a tube of radius ``radius``."""

    model_config = _FROZEN

    knots: tuple[Vec3, ...] = Field(
        DEFAULT_KNOTS,
        description="Spline knots [x, y, z] in world, m, in order along the wire "
        "(≥ 4, z > radius).",
    )
    radius: float = Field(1.0e-3, gt=0.0, description="Wire tube radius, m.")
    post_radius: float = Field(
        2.0e-3, gt=0.0, description="Radius of the two vertical posts holding the wire's ends, m."
    )
    samples: int = Field(
        2001,
        ge=100,
        le=1_000_000,
        description="Points of the dense centre-line polyline (scene.json, plots, nearest-point "
        "search), count.",
    )

    @field_validator("knots")
    @classmethod
    def _knots_valid(cls, knots: tuple[Vec3, ...]) -> tuple[Vec3, ...]:
        if len(knots) < 4:
            raise ValueError(f"knots needs at least 4 points for a cubic spline, got {len(knots)}")
        arr = np.asarray(knots, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ValueError("knots must be finite")
        if np.any(np.linalg.norm(np.diff(arr, axis=0), axis=1) < 1e-6):
            raise ValueError("knots must not repeat consecutive points (closer than 1 µm)")
        return knots

    @model_validator(mode="after")
    def _above_board(self) -> WireConfig:
        lowest = min(k[2] for k in self.knots)
        if lowest <= self.radius:
            raise ValueError(f"knots must lie above the board (z > radius), lowest z = {lowest} m")
        return self


class RingConfig(BaseModel):
    """The ring: a torus in the ring frame's x-y plane, with a straight handle along +x."""

    model_config = _FROZEN

    major_radius: float = Field(5.0e-3, gt=0.0, description="Torus core-circle radius R, m.")
    minor_radius: float = Field(1.0e-3, gt=0.0, description="Torus tube radius r, m.")
    handle_length: float = Field(
        15.0e-3, gt=0.0, description="Handle length from the ring's core circle along +x, m."
    )
    handle_radius: float = Field(0.6e-3, gt=0.0, description="Handle (rod) radius, m.")

    @model_validator(mode="after")
    def _proper_torus(self) -> RingConfig:
        if self.minor_radius >= self.major_radius:
            raise ValueError(
                f"minor_radius ({self.minor_radius} m) must be below major_radius "
                f"({self.major_radius} m)"
            )
        if self.handle_radius > self.minor_radius * 2.0:
            raise ValueError("handle_radius must not exceed twice minor_radius")
        return self


class TrajectoryConfig(BaseModel):
    """Ring trajectories along the wire (paper Sec. IV-B).

    Noise reading of the paper's "threshold" (3-3.5 mm, 10-30°) as a limit drawn once per noisy
    trajectory: a position threshold ``t_p`` uniform in ``position_noise`` and an angular
    threshold ``t_a`` uniform in ``angle_noise``. Every control point then moves by an offset
    (dx, dy, dz) uniform in the ball ``|d| ≤ t_p`` and turns by offsets (dα, dβ, dγ) each uniform
    in ``[−t_a, t_a]``. Noisy 71-point paths then touch the wire in discrete events (≈ 12 per
    60 s, in contact ≈ 8 % of the time; docs/world.md).
    """

    model_config = _FROZEN

    control_points: int = Field(
        36,
        ge=2,
        le=MAX_CONTROL_POINTS,
        description="Control points spaced evenly by arc length (paper: 36 or 71), count.",
    )
    position_noise: Range = Field(
        (3.0e-3, 3.5e-3),
        description="Range [lo, hi] of the position threshold t_p, m, drawn uniformly once per "
        "noisy trajectory; every control point's position offset is uniform in the ball of "
        "radius t_p (paper Sec. IV-B: 3-3.5 mm). hi ≤ ring.major_radius + ring.minor_radius + "
        "wire.radius (the ring's reach of the wire, 7 mm by default).",
    )
    angle_noise: Range = Field(
        (math.radians(10.0), math.radians(30.0)),
        description="Range [lo, hi] of the angular threshold t_a, rad, drawn uniformly once per "
        "noisy trajectory; every offset of α, β and γ is uniform in [−t_a, t_a] (paper "
        "Sec. IV-B: 10-30°).",
    )
    duration: float = Field(
        60.0,
        gt=0.0,
        le=MAX_DURATION_S,
        description="Time for the ring to travel from the first to the last control point, s "
        "(default: 60 s over ≈ 0.25 m ≈ 4.2 mm/s).",
    )
    end_margin: float = Field(
        10.0e-3,
        ge=0.0,
        description="Arc length kept free at each wire end (posts), m: control points span "
        "[end_margin, length − end_margin]; below half the wire's length.",
    )
    legible_band: Range | None = Field(
        None,
        description="(d, g), m: when set, every noisy trajectory is made legible: each local "
        "extremum of the ring–wire clearance is a touch at least d deep (≤ −d) or a pass at "
        "least g clear (≥ g), never in between, by the smallest move of the nearest control "
        "point along the contact normal (offsets stay within t_p). None: the noise as drawn "
        "(docs/world.md, 'Legible trajectories').",
    )
    touch_sample_dt: float = Field(
        2.0e-3,
        gt=0.0,
        description="Base sampling step of the clearance for touch detection, s. The clearance "
        "changes at most at the ring's fastest surface-point speed v (≤ ~0.05 m/s on noisy "
        "paths), so a touch deeper than v·dt/2 (≤ 50 µm) cannot fall between samples; "
        "intervals where a shallower touch could hide are re-sampled until v·dt/2 < 1 µm.",
    )

    @field_validator("position_noise")
    @classmethod
    def _pos_noise(cls, value: Range) -> Range:
        return _check_range(value, "position_noise")

    @field_validator("angle_noise")
    @classmethod
    def _ang_noise(cls, value: Range) -> Range:
        return _check_range(value, "angle_noise", upper=math.pi)

    @field_validator("legible_band")
    @classmethod
    def _legible_band(cls, value: Range | None) -> Range | None:
        if value is None:
            return None
        _check_finite(value, "legible_band")
        depth, gap = value
        if not (depth >= 0.0 and gap > 0.0):
            raise ValueError(f"legible_band (d, g) needs d ≥ 0 and g > 0 m, got {value}")
        return value

    @model_validator(mode="after")
    def _bounded(self) -> TrajectoryConfig:
        samples = self.duration / self.touch_sample_dt
        if samples > MAX_TOUCH_SAMPLES:
            raise ValueError(
                f"duration / touch_sample_dt = {samples:.3g} clearance samples, more than "
                f"{MAX_TOUCH_SAMPLES}: raise touch_sample_dt or shorten the duration"
            )
        return self


class Psm2Idle(enum.Enum):
    """What the idle second instrument (PSM2) does while PSM1 moves the ring."""

    FOLLOW = "follow"
    """Stays near the work site: its tip follows the ring centre, smoothed by a first-order lag
    of ``psm2_follow_time``, at the fixed world offset ``psm2_offset`` (retracted, clear of the
    wire), as an assistant keeps a second instrument beside the work (see
    :mod:`endocam.task.instruments`)."""
    FIXED = "fixed"
    """Waits at ``psm2_tip`` for the whole episode (the world before issue 11)."""


class InstrumentConfig(BaseModel):
    """The two patient-side instruments: PSM1 holds the ring's handle, PSM2 waits near it."""

    model_config = _FROZEN

    shaft_radius: float = Field(4.0e-3, gt=0.0, description="Instrument shaft radius, m.")
    shaft_length: float = Field(0.06, gt=0.0, description="Visible shaft length, m.")
    wrist_length: float = Field(8.0e-3, gt=0.0, description="Wrist length (shaft end to jaws), m.")
    jaw_length: float = Field(8.0e-3, gt=0.0, description="Jaw length (wrist to tip), m.")
    jaw_opening: float = Field(
        math.radians(20.0), ge=0.0, lt=math.pi / 2, description="PSM2 jaw half-opening, rad."
    )
    psm2_tip: Vec3 = Field(
        (0.030, -0.050, 0.030),
        description="PSM2 tip position in world with psm2_idle 'fixed', m; the overview "
        "camera frames it either way.",
    )
    psm2_idle: Psm2Idle = Field(
        Psm2Idle.FOLLOW,
        description="PSM2's idle behaviour: 'follow' (beside the ring, lagged) or 'fixed' "
        "(at psm2_tip).",
    )
    psm2_offset: Vec3 = Field(
        (0.0, -0.020, 0.010),
        description="With psm2_idle 'follow': PSM2 tip offset from the lagged ring centre, "
        "world, m (default: 20 mm in front of the wire, 10 mm above the ring).",
    )
    psm2_follow_time: float = Field(
        1.0,
        gt=0.0,
        description="With psm2_idle 'follow': time constant of the first-order lag with which "
        "PSM2's tip follows the ring centre, s.",
    )
    psm2_direction: Vec3 = Field(
        (0.3, -0.6, 0.75),
        description="Direction from the PSM2 tip up its shaft, world, unitless (normalised).",
    )
    rgba: RGBA = Field((0.55, 0.57, 0.6, 1.0), description="Instrument metal colour, RGBA.")
    jaw_rgba: RGBA = Field((0.25, 0.25, 0.28, 1.0), description="Wrist and jaw colour, RGBA.")

    @field_validator("psm2_tip", "psm2_direction", "psm2_offset")
    @classmethod
    def _finite(cls, value: Vec3) -> Vec3:
        _check_finite(value, "instrument vector")
        return value

    @field_validator("psm2_direction")
    @classmethod
    def _nonzero(cls, value: Vec3) -> Vec3:
        if math.hypot(*value) < 1e-9:
            raise ValueError("psm2_direction must be non-zero")
        return value

    @field_validator("rgba", "jaw_rgba")
    @classmethod
    def _colour(cls, value: RGBA) -> RGBA:
        return _check_rgba(value, "instrument colour")


class SceneConfig(BaseModel):
    """Board, look and camera arm of the rendered scene."""

    model_config = _FROZEN

    board_size: tuple[float, float] = Field(
        (0.32, 0.22), description="Board extent along world x and y (centred at the origin), m."
    )
    board_rgba: RGBA = Field((0.72, 0.78, 0.74, 1.0), description="Matte board colour, RGBA.")
    board_checker_rgba: RGBA = Field(
        (0.64, 0.71, 0.67, 1.0), description="Second colour of the board's 1 cm checker, RGBA."
    )
    wire_rgba: RGBA = Field(
        (0.08, 0.30, 0.85, 1.0),
        description="Wire colour, RGBA: saturated blue, against the pale board, the beige "
        "backdrop and the orange ring (hues apart, so assessors and the observer tell them apart).",
    )
    backdrop_rgba: RGBA = Field(
        (0.80, 0.76, 0.70, 1.0),
        description="Training-box walls around the board, RGBA: a lit, matte beige backdrop "
        "instead of the black void above the board.",
    )
    backdrop_height: float = Field(
        0.20, gt=0.0, description="Height of the box's back and side walls above the board, m."
    )
    backdrop_port_height: float = Field(
        0.06,
        gt=0.0,
        description="Height of the wall on the camera port's side (+x), m: low, so the camera "
        "arm's shaft passes above it.",
    )
    post_rgba: RGBA = Field((0.3, 0.3, 0.32, 1.0), description="Post colour, RGBA.")
    ring_rgba: RGBA = Field((1.0, 0.62, 0.05, 1.0), description="Bright ring colour, RGBA.")
    handle_rgba: RGBA = Field((0.85, 0.85, 0.85, 1.0), description="Ring handle colour, RGBA.")
    key_light_direction: Vec3 = Field(
        (0.3, 0.4, -1.0), description="Direction of the main directional light, world (normalised)."
    )
    fill_light_direction: Vec3 = Field(
        (-0.5, -0.6, -0.5), description="Direction of the fill light, world (normalised)."
    )
    key_light_diffuse: float = Field(0.6, ge=0.0, le=1.0, description="Key light diffuse, 0-1.")
    fill_light_diffuse: float = Field(0.25, ge=0.0, le=1.0, description="Fill light diffuse, 0-1.")
    headlight_diffuse: float = Field(
        0.35, ge=0.0, le=1.0, description="Camera headlight diffuse (endoscope light), 0-1."
    )
    ambient: float = Field(0.25, ge=0.0, le=1.0, description="Headlight ambient term, 0-1.")
    wire_segments: int = Field(
        240,
        ge=8,
        le=MAX_MESH_SEGMENTS,
        description="Segments of the rendered wire tube mesh along its length, count.",
    )
    ring_mesh_segments: tuple[int, int] = Field(
        (128, 48),
        description="Torus mesh resolution (around the core, around the tube), count. A "
        "polygon's silhouette is up to R (1 − cos(π/n)) inside the smooth ring's: at (128, 48) "
        "1.5 µm and 2.1 µm, 0.02 px at 50 mm. (64, 16), before round 15, put the tube's "
        "silhouette 19 µm (0.16 px) in at some views and not at others: the two eyes saw "
        "different tube widths and the stereo estimator read a 0.5° tilt that no smooth ring "
        "has (docs/perception.md, 'Round 15'); rendering cost unchanged (~6 ms per eye).",
    )
    rcm_position: Vec3 = Field(
        (0.20, 0.0, 0.12),
        description="Camera arm's remote centre of motion (cone workspace tip) in world, m: "
        "a port 0.12 m above the board, right of the task (+x), within the PSM-held camera's "
        "0.30 m reach of the whole wire, so the cone from it towards the ring's start (the "
        "wire's left end) runs along the wire (see docs/world.md).",
    )
    rcm_euler_xyz: Vec3 = Field(
        (0.0, 1.2121, 3.1416),
        description="Orientation of the RCM frame in world, Tait-Bryan (α, β, γ), rad. The "
        "default aims the frame's −z axis (the shaft of a dVRK arm at mid-range yaw/pitch) from "
        "the default RCM at the task centre (0, 0, 45) mm, with y horizontal: at zero yaw, pitch "
        "and roll the ECM's image (its optical frame is its tip frame) and the PSM's (with the "
        "default episode.tip_cam_euler_xyz) are upright with a level horizon. The dVRK's RCM "
        "frame for the same image is this one turned by +90° about z (docs/robot.md).",
    )

    @field_validator(
        "board_rgba",
        "board_checker_rgba",
        "wire_rgba",
        "backdrop_rgba",
        "post_rgba",
        "ring_rgba",
        "handle_rgba",
    )
    @classmethod
    def _colour(cls, value: RGBA) -> RGBA:
        return _check_rgba(value, "scene colour")

    @field_validator("board_size")
    @classmethod
    def _board(cls, value: tuple[float, float]) -> tuple[float, float]:
        _check_finite(value, "board_size")
        if min(value) <= 0.0:
            raise ValueError(f"board_size must be positive, got {value}")
        return value

    @field_validator("ring_mesh_segments")
    @classmethod
    def _mesh(cls, value: tuple[int, int]) -> tuple[int, int]:
        if min(value) < 3 or max(value) > MAX_MESH_SEGMENTS:
            raise ValueError(
                f"ring_mesh_segments must be in 3..{MAX_MESH_SEGMENTS} each, got {value}"
            )
        return value

    @field_validator("key_light_direction", "fill_light_direction", "rcm_position", "rcm_euler_xyz")
    @classmethod
    def _vec(cls, value: Vec3) -> Vec3:
        _check_finite(value, "scene vector")
        return value

    @property
    def T_world_rcm(self) -> FloatArray:
        """(4, 4) pose of the camera arm's RCM frame in world, m."""
        return make_pose(R_from_euler_xyz(self.rcm_euler_xyz), self.rcm_position)


class TaskConfig(BaseModel):
    """Everything that defines the wire-chaser world, with the paper-like defaults."""

    model_config = _FROZEN

    wire: WireConfig = Field(default_factory=WireConfig, description="The wire.")
    ring: RingConfig = Field(default_factory=RingConfig, description="The ring and its handle.")
    trajectory: TrajectoryConfig = Field(
        default_factory=TrajectoryConfig, description="Ring trajectories."
    )
    instruments: InstrumentConfig = Field(
        default_factory=InstrumentConfig, description="PSM1 and PSM2."
    )
    scene: SceneConfig = Field(default_factory=SceneConfig, description="Board, look, camera arm.")

    @model_validator(mode="after")
    def _ring_fits_wire(self) -> TaskConfig:
        gap = self.ring.major_radius - self.ring.minor_radius - self.wire.radius
        if gap <= 0.0:
            raise ValueError(
                "the ring's hole is too small for the wire: major_radius − minor_radius − "
                f"wire.radius = {gap} m ≤ 0"
            )
        band = self.trajectory.legible_band
        if band is not None and band[1] >= gap:
            raise ValueError(
                f"trajectory.legible_band's clear gap {band[1]} m must be below the centred "
                f"ring's clearance major_radius − minor_radius − wire.radius = {gap} m"
            )
        if self.instruments.psm2_tip[2] <= 0.0:
            raise ValueError("instruments.psm2_tip must be above the board (z > 0)")
        reach = self.max_position_noise
        if self.trajectory.position_noise[1] > reach:
            raise ValueError(
                f"trajectory.position_noise {list(self.trajectory.position_noise)} m goes beyond "
                f"{reach:.4g} m = ring.major_radius + ring.minor_radius + wire.radius: farther "
                "than that from the wire a control point takes the ring off it"
            )
        length = centre_line_length(self.wire.knots)
        if not 2.0 * self.trajectory.end_margin < length:
            raise ValueError(
                f"trajectory.end_margin {self.trajectory.end_margin} m leaves no wire to follow: "
                f"the wire is {length:.4g} m long, so end_margin must be below {length / 2:.4g} m"
            )
        return self

    @property
    def max_position_noise(self) -> float:
        """Largest position threshold t_p a trajectory may draw, m.

        A ring centre farther than ``major_radius + minor_radius + wire.radius`` from the
        wire's centre line no longer has the wire through its hole.
        """
        return self.ring.major_radius + self.ring.minor_radius + self.wire.radius
