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
from endocam.registry import POLICIES, make_policy
from endocam.workspace.cone import ConeWorkspace

__all__ = [
    "POLICIES",
    "CameraCommand",
    "CameraPolicy",
    "CenteringPolicy",
    "ConeWorkspace",
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
    "make_policy",
    "window_status",
]
