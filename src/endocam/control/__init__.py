"""The camera controller: goal pose, way-point planner, safety rules and policies."""

from endocam.control.goal import goal_pose, look_at_pose
from endocam.control.planner import WaypointPath, intermediate_waypoints
from endocam.control.policies import (
    POLICIES,
    CameraCommand,
    CameraPolicy,
    CenteringPolicy,
    ControllerConfig,
    FixedPolicy,
    Observation,
    OrientationPolicy,
    PolicyContext,
    SideRule,
    TrackingState,
    make_policy,
)
from endocam.control.safety import (
    ConeWorkspace,
    ImageWindows,
    WindowStatus,
    adjust_working_distance,
    window_status,
)

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
    "look_at_pose",
    "make_policy",
    "window_status",
]
