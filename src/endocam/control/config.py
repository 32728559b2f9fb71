"""The moving policies' parameters: every controller default is defined here, once."""

from __future__ import annotations

import enum
import math

from pydantic import BaseModel, ConfigDict, Field, model_validator

from endocam.control.goal import SIDE_HYSTERESIS
from endocam.control.safety import (
    CONE_BASE_RADIUS,
    CONE_HEIGHT,
    D_F_STEP,
    ImageWindows,
)

__all__ = ["ControllerConfig", "SideRule"]


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
    d_f_step: float = Field(D_F_STEP, gt=0, description="working-distance change per step, m")
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
        description="lowest camera height above the board (world z) the side hysteresis may "
        "keep, m",
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
    window_inner_frac: float = Field(0.5, gt=0, le=1, description="inner window, image fraction")
    window_outer_frac: float = Field(0.9, gt=0, le=1, description="outer window, image fraction")

    @model_validator(mode="after")
    def _check_ranges(self) -> ControllerConfig:
        if not self.d_min <= self.d_f <= self.d_max:
            raise ValueError(
                f"need d_min ≤ d_f ≤ d_max, got {self.d_min}, {self.d_f}, {self.d_max}"
            )
        if not self.window_inner_frac < self.window_outer_frac:
            raise ValueError("window_inner_frac must be smaller than window_outer_frac")
        return self

    @property
    def windows(self) -> ImageWindows:
        """The tool-in-view windows."""
        return ImageWindows(self.window_inner_frac, self.window_outer_frac)
