"""The camera controller: goal pose, way-point planner, safety rules and policies."""

from endocam.control.config import ControllerConfig, SideRule
from endocam.control.goal import goal_pose
from endocam.control.planner import WaypointPath, intermediate_waypoints
from endocam.control.policies import (
    CenteringPolicy,
    FixedPolicy,
    OrientationPolicy,
)
from endocam.control.types import (
    CameraCommand,
    CameraPolicy,
    Observation,
    PolicyContext,
    TrackingState,
)
from endocam.control.windows import (
    ImageWindows,
    WindowStatus,
    adjust_working_distance,
    window_status,
)

__all__ = [
    "CameraCommand",
    "CameraPolicy",
    "CenteringPolicy",
    "ControllerConfig",
    "FixedPolicy",
    "ImageWindows",
    "Observation",
    "OrientationPolicy",
    "PolicyContext",
    "SideRule",
    "TrackingState",
    "WaypointPath",
    "WindowStatus",
    "adjust_working_distance",
    "goal_pose",
    "intermediate_waypoints",
    "window_status",
]
