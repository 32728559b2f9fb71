"""The moving policies' parameters: every controller default is defined here, once."""

from __future__ import annotations

import enum
import math
from typing import Annotated

from numpy.typing import ArrayLike
from pydantic import BaseModel, ConfigDict, Field, model_validator

from endocam.control.clearance import WIRE_CLEARANCE, ClearanceGuard
from endocam.control.gate import FLOOR_M, FLOOR_RAD, RingGate, RingLimits
from endocam.control.goal import SIDE_HYSTERESIS
from endocam.control.windows import D_F_STEP, ImageWindows
from endocam.task.wire import Wire
from endocam.workspace.cone import CONE_BASE_RADIUS, CONE_HEIGHT, ConeWorkspace
from endocam.workspace.region import Workspace

__all__ = ["ControllerConfig", "SideRule", "TrackerConfig", "Transfer"]


class Transfer(enum.Enum):
    """How the camera moves to a far goal (a side change, the first approach, after a freeze)."""

    ORBIT = "orbit"
    """About the ring centre at the look distance, looking at it with a level horizon."""
    WAYPOINTS = "waypoints"
    """The paper's way-points: up, across above the goal, down (Sec. III-B, Fig. 4)."""
    DIRECT = "direct"
    """Straight to the goal pose under the carrier's limits (no path planning)."""


class TrackerConfig(BaseModel):
    """Switches and parameters of the ``endocam`` tracker. Validated at construction."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    keep_side: bool = Field(
        True,
        description="keep the side the camera looks from while its view stays feasible (above "
        "min_camera_height, inside the cone) and within side_change_angle of the ring normal; "
        "off: the orientation policy's side rule (ControllerConfig.side_rule, side_hysteresis)",
    )
    side_change_angle: float = Field(
        math.pi / 2,
        gt=0.0,
        le=math.pi / 2,
        description="how far the feasible view on the kept side may turn from the ring normal "
        "before the camera changes side (when the other side is feasible and better), rad",
    )
    shorten_when_low: bool = Field(
        True,
        description="while the kept side's view is height-limited (the camera held at "
        "min_camera_height, turned off the normal) and every instrument tip is between the "
        "windows, shorten the look distance by d_f_step per step (down to d_min) so the camera "
        "can reach the normal, as long as every tip stays inside the outer window of the "
        "shortened goal; a tip outside the outer window always lengthens it (safety first)",
    )
    side_transfer: Transfer = Field(
        Transfer.ORBIT, description="how the camera changes side: orbit, waypoints or direct"
    )
    first_approach: Transfer = Field(
        Transfer.DIRECT,
        description="how the camera reaches its first goal (from the overview pose) and a goal "
        "after a freeze or lost tracking: orbit, waypoints or direct",
    )
    predict: bool = Field(
        True,
        description="estimate the ring's velocity from the delayed observations and predict "
        "its pose across the sensing delay and the carrier's lead",
    )
    feedforward: bool = Field(
        True,
        description="give the carrier the goal's velocity (twist) as its target velocity",
    )
    feedforward_gain: tuple[
        Annotated[float, Field(ge=0.0, le=1.0)], Annotated[float, Field(ge=0.0, le=1.0)]
    ] = Field(
        (0.5, 0.5),
        description="gains on the linear and the angular part of the goal twist given to the "
        "carrier (1: the full estimated velocity; 0.5 measured best on noisy paths, where the full "
        "velocity makes the jerk-limited carrier overshoot)",
    )
    floor_clearance: float = Field(
        1e-3,
        ge=0.0,
        description="endocam's goals keep the camera this far above min_camera_height, m, so a "
        "carrier's overshoot stays above the floor itself: the PSM's joint-space motion dipped "
        "0.8 mm below a goal on the floor (study path t3-71-high); 2 mm costs the free camera "
        "0.14 deg of noisy orientation error",
    )
    carrier_lead: float = Field(
        0.04,
        ge=0.0,
        le=0.5,
        description="extra prediction beyond the sensing latency for the carrier's response, "
        "s: a command moves the camera during the next step, and the jerk-limited carrier "
        "fed half the goal's velocity lags a few steps more (0.04 s measured best on noisy "
        "36/71-point seeds 4-6, flat over 0.03-0.05 s; 0.01 s: +0.5° orientation error)",
    )
    velocity_window: float = Field(
        0.03,
        gt=0.0,
        le=0.5,
        description="spacing of the delayed samples the ring velocity and acceleration are "
        "differenced over, s",
    )
    orbit_max_speed: float = Field(
        0.08,
        gt=0.0,
        description="largest speed of the camera along any world axis during an orbit, m/s "
        "(under the carrier's per-axis limit, 0.15/√3 m/s by default)",
    )
    orbit_max_rate: float = Field(
        1.2,
        gt=0.0,
        description="largest turn rate of the camera about any of its own axes during an "
        "orbit, rad/s (under the carrier's per-axis limit, 120°/√3 per s by default)",
    )
    orbit_lookahead: float = Field(
        math.radians(15.0),
        gt=0.0,
        le=math.pi,
        description="largest lead of the orbit's commanded direction over the camera's, rad",
    )


class SideRule(enum.Enum):
    """Which side of the feature the orientation camera looks from (see ``control.goal``)."""

    UP = "up"
    """The paper's rule: the side above the feature, ``s n·up ≥ 0``."""
    PORT = "port"
    """The side facing the camera arm's RCM, ``s n·(p_rcm − p_c) ≥ 0``."""


class ControllerConfig(BaseModel):
    """Parameters of the moving policies, SI units. Validated at construction."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    d_f: float = Field(0.05, gt=0, description="initial working distance, m")
    d_min: float = Field(0.03, gt=0, description="smallest working distance, m")
    d_max: float = Field(0.08, gt=0, description="largest working distance, m")
    d_f_step: float = Field(
        D_F_STEP,
        gt=0,
        description="working-distance change per control step, m: the paper's ±1 mm (Sec. "
        "III-C), once per step, i.e. 0.1 m/s at 100 Hz, under the camera's speed limit",
    )
    jump_threshold: float = Field(
        0.02, gt=0, description="goal jump between control steps that triggers way-points, m"
    )
    d_wp: float = Field(0.04, gt=0, description="height of intermediate way-points, m")
    side_hysteresis: float = Field(
        SIDE_HYSTERESIS,
        ge=0,
        lt=math.pi / 2,
        description="how far below horizontal the ring normal may tip before the orientation "
        "camera changes side, rad",
    )
    side_rule: SideRule = Field(
        SideRule.PORT,
        description="which side of the ring the orientation camera takes: 'up' (the paper: "
        "above the ring) or 'port' (facing the camera arm's RCM, so the camera looks away "
        "from its port, as an RCM arm's wrist must)",
    )
    min_camera_height: float = Field(
        0.015,
        ge=0.0,
        allow_inf_nan=False,
        description="the floor: lowest camera height above the board (world z), m; the paper "
        "policies' side hysteresis never keeps a side below it, and endocam never commands a "
        "pose below it (its goals aim floor_clearance higher)",
    )
    wire_clearance: float = Field(
        WIRE_CLEARANCE,
        ge=0.0,
        allow_inf_nan=False,
        description="smallest distance from the camera's optical centre to the wire's surface "
        "in every pose a moving policy commands, m: the 12 mm da Vinci endoscope's radius "
        "(6 mm) + a 2 mm margin for the carriers' tracking; a goal closer is rotated about "
        "the ring centre by the smallest angle that clears (control.clearance)",
    )
    planner_speed: float = Field(0.15, gt=0, description="progress speed along way-points, m/s")
    planner_lookahead: float = Field(
        0.01, gt=0, description="how far progress may lead the camera's projection, m"
    )
    cone_height: float = Field(
        CONE_HEIGHT,
        gt=0,
        description="cone workspace height, m: the PSM-held camera's reach (0.24 m insertion "
        "+ 0.046 m to the tip + 0.015 m mount), as the paper sets it slightly under the "
        "instrument length",
    )
    cone_base_radius: float = Field(
        CONE_BASE_RADIUS,
        gt=0,
        description="cone base radius, m (the paper chose 0.10 m empirically for its port; "
        "this port is within the PSM's reach of the wire, hence closer and wider-angled: "
        "see docs/world.md)",
    )
    ring_max_speed: float = Field(
        0.5,
        gt=0,
        le=10.0,
        description="observation gate: fastest plausible ring centre, m/s: how far a ring pose "
        "that returns after a refused outlier burst may lie from the last accepted one (over at "
        "most ring_gate_horizon). The default task's ring moves ≤ 0.013 m/s, a 3 s episode's "
        "≤ 0.26 m/s",
    )
    ring_max_rate: float = Field(
        25.0,
        gt=0,
        le=1000.0,
        description="observation gate: fastest plausible turn of the ring normal, rad/s (same "
        "use; a 3 s episode's ≤ 25 rad/s)",
    )
    ring_max_acceleration: float = Field(
        30.0,
        gt=0,
        le=1e6,
        description="observation gate: largest ring-centre acceleration, m/s²: a ring pose may "
        "be ring_gate_floor_position + ½·a·Δt² from the accepted track's constant-velocity "
        "prediction, Δt after its last pose (up to ring_gate_position). The default task's "
        "ring ≤ 0.05 m/s², a 10 s episode's ≤ 1.5, a 3 s episode's ≤ 15",
    )
    ring_max_angular_acceleration: float = Field(
        500.0,
        gt=0,
        le=1e8,
        description="observation gate: largest second derivative of the ring's unit normal, "
        "1/s²: the normal may be ring_gate_floor_angle + ½·α·Δt² from its prediction (up to "
        "ring_gate_angle). The default task's ≤ 5, a 10 s episode's ≤ 200, a 3 s episode's "
        "≤ 1700: faster tasks than ~5 s need a larger value (and cannot tell a 5° outlier "
        "from the ring)",
    )
    ring_gate_position: float = Field(
        0.005,
        gt=0,
        le=10.0,
        description="observation gate: the position innovation's cap, m: a ring pose farther "
        "from the accepted track's prediction is never taken as it comes, however long the "
        "gate has refused (outliers > 5 mm are refused; endocam check requires the hold)",
    )
    ring_gate_angle: float = Field(
        math.radians(3.0),
        gt=0,
        le=math.pi,
        description="observation gate: the normal's innovation cap, rad (3°: outliers turned "
        "more are refused)",
    )
    ring_gate_horizon: float = Field(
        0.1,
        gt=0,
        le=1.0,
        description="observation gate: longest gap between two ring poses compared step to "
        "step, s, and longest time a returning pose's reach grows over",
    )
    ring_gate_floor_position: float = Field(
        FLOOR_M,
        gt=0,
        le=0.01,
        description="observation gate: the ring centre's innovation always allowed, m: the "
        "observation source's position noise (0.5 mm: the truth source; a stereo run takes "
        "perception.gate_floor_position). A larger floor raises ring_gate_position and "
        "ring_gap_position by its rise over 0.5 mm (RingLimits.with_floor)",
    )
    ring_gate_floor_angle: float = Field(
        FLOOR_RAD,
        gt=0,
        le=math.radians(20.0),
        description="observation gate: the normal's innovation always allowed, rad (0.5°: "
        "the truth source; a stereo run takes perception.gate_floor_angle). A larger floor "
        "raises ring_gate_angle and ring_gap_angle by its rise over 0.5°",
    )
    ring_max_age: float = Field(
        0.25,
        gt=0,
        le=10.0,
        description="oldest ring pose the camera acts on, s (capture stamp to control time; 5x the "
        "default sensing latency, ~7 frames of a 30 fps endoscope): an older one, e.g. a frozen "
        "tracker re-sending its last pose, is answered by holding",
    )
    ring_reacquire: float = Field(
        0.5,
        gt=0,
        le=60.0,
        description="observation gate: a run of refused ring poses that agree with each other "
        "step to step for this long, s, is taken as the ring (inside the cone only): it moved "
        "while lost, or the tracker now sees it there. Longer than any outlier burst to refuse",
    )
    ring_gap_position: float = Field(
        0.009,
        gt=0,
        le=10.0,
        description="observation gate, after a gap (no fresh ring pose for longer than "
        "ring_gate_horizon): a run of poses that began after it is taken once its centre is "
        "within this, m, of the bridge from the last accepted pose (a trapezoid between the "
        "two tracks' velocities). Twice it is the smallest centre offset refused in an outlier "
        "burst that begins as a gap ends (2 cm: yes; 1 cm: not promised)",
    )
    ring_gap_angle: float = Field(
        math.radians(7.0),
        gt=0,
        le=math.pi,
        description="observation gate, after a gap: the normal's bridge cap, rad (7°: a 15° "
        "outlier burst that begins as a gap ends is refused; a 5° one is not promised)",
    )
    ring_confirm: float = Field(
        0.03,
        gt=0,
        le=1.0,
        description="observation gate, after a gap: how long, s, a run of poses must agree step "
        "to step before it is bridged to the last accepted pose (its velocity is the run's "
        "mean; a noisy tracker needs longer)",
    )
    window_inner_frac: float = Field(0.5, gt=0, le=1, description="inner window, image fraction")
    window_outer_frac: float = Field(0.9, gt=0, le=1, description="outer window, image fraction")
    centre_left_eye: bool = Field(
        True,
        description="the centring (condition II) and endocam cameras put the left eye's optical "
        "axis, where the image and 3D errors are measured (paper Sec. V), on the ring centre; "
        "off: the midpoint between the eyes. The paper-faithful orientation policy always "
        "centres the midpoint",
    )
    tracker: TrackerConfig = Field(
        default_factory=TrackerConfig, description="the endocam tracker's switches (policy endocam)"
    )

    @model_validator(mode="after")
    def _check_ranges(self) -> ControllerConfig:
        if not self.d_min <= self.d_f <= self.d_max:
            raise ValueError(
                f"need d_min ≤ d_f ≤ d_max, got {self.d_min}, {self.d_f}, {self.d_max}"
            )
        if not self.window_inner_frac < self.window_outer_frac:
            raise ValueError("window_inner_frac must be smaller than window_outer_frac")
        return self

    def workspace(
        self, p_world_rcm: ArrayLike, p_world_feature: ArrayLike, wire: Wire | None = None
    ) -> Workspace:
        """Where the camera may be (the carriers keep it there): cone, floor, off the wire.

        The cone runs from the RCM ``p_world_rcm`` (3,) towards the feature's initial position
        ``p_world_feature`` (3,), world, m; the floor is ``min_camera_height``; with a ``wire``
        model the camera keeps ``wire_clearance`` from its surface. Each call builds its own
        clearance cache: give each user (a carrier, a policy) its own workspace.
        """
        cone = ConeWorkspace.from_rcm(
            p_world_rcm, p_world_feature, self.cone_height, self.cone_base_radius
        )
        keep_out = None if wire is None else ClearanceGuard(wire, self.wire_clearance)
        return Workspace(cone, self.min_camera_height, keep_out)

    def ring_gate(self) -> RingGate:
        """A fresh observation gate with these bounds."""
        return RingGate(self.ring_limits)

    @property
    def ring_limits(self) -> RingLimits:
        """The observation gate's bounds (``control.gate.RingLimits``).

        The caps above are stated over the truth source's floor (0.5 mm, 0.5°); a larger
        ``ring_gate_floor_*`` raises them by its rise (``RingLimits.with_floor``).
        """
        return RingLimits(
            max_speed=self.ring_max_speed,
            max_rate=self.ring_max_rate,
            max_acceleration=self.ring_max_acceleration,
            max_angular_acceleration=self.ring_max_angular_acceleration,
            position_gate=self.ring_gate_position,
            angle_gate=self.ring_gate_angle,
            horizon=self.ring_gate_horizon,
            reacquire=self.ring_reacquire,
            gap_position=self.ring_gap_position,
            gap_angle=self.ring_gap_angle,
            confirm=self.ring_confirm,
        ).with_floor(self.ring_gate_floor_position, self.ring_gate_floor_angle)

    @property
    def windows(self) -> ImageWindows:
        """The tool-in-view windows."""
        return ImageWindows(self.window_inner_frac, self.window_outer_frac)
