"""Parameters of the ``endocam`` tracker (:mod:`endocam.control.tracker`), SI units.

Kept apart from the tracker so :class:`~endocam.control.policies.ControllerConfig` can hold it
without importing the tracker (which builds on the policies module). Every ingredient of the
tracker has a switch, so its effect can be measured by turning it off alone.
"""

from __future__ import annotations

import enum
import math

from pydantic import BaseModel, ConfigDict, Field


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
    feedforward_gain: tuple[float, float] = Field(
        (0.5, 0.5),
        description="gains on the linear and the angular part of the goal twist given to the "
        "carrier (1: the full estimated velocity; 0.5 measured best on noisy paths, where the full "
        "velocity makes the jerk-limited carrier overshoot)",
    )
    carrier_lead: float = Field(
        0.01,
        ge=0.0,
        le=0.5,
        description="extra prediction beyond the sensing latency for the carrier's response "
        "(one control period: a command moves the camera during the next step), s",
    )
    velocity_window: float = Field(
        0.03,
        gt=0.0,
        le=0.5,
        description="spacing of the delayed samples the ring velocity and acceleration are "
        "differenced over, s",
    )
    centre_left_eye: bool = Field(
        True,
        description="put the left eye's optical axis (where the image error is measured) on "
        "the ring centre; off: the midpoint between the eyes, as the paper's method",
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
