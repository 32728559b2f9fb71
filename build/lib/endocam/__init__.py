"""endocam: autonomous 6-DoF endoscopic camera control for minimally invasive surgery.

Implements Abdelaal et al., "Orientation Matters: 6-DoF Autonomous Camera Movement for MIS":
the orientation-aware goal pose, way-point planner and safety rules (``endocam.control``), the
wire-chaser world (``endocam.task``, ``endocam.sim``), dVRK kinematics (``endocam.robot``) and the
video-based skill-assessment study (``endocam.study``). Conventions: ``docs/conventions.md``.
"""

from importlib.metadata import PackageNotFoundError, version

# first, before any module imports numba: a kernel cache folder per version of the source
import endocam._numba_cache  # noqa: F401

try:
    __version__ = version("endocam")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

from endocam.camera import Intrinsics, StereoCamera
from endocam.control import (
    CameraCommand,
    ControllerConfig,
    Observation,
    PolicyContext,
    TrackingState,
    goal_pose,
)
from endocam.metrics import center_error_3d, image_centering_error, orientation_error
from endocam.registry import POLICIES, make_policy
from endocam.robot import ECM, PSM
from endocam.view import look_at_pose
from endocam.workspace import ConeWorkspace

__all__ = [
    "ECM",
    "POLICIES",
    "PSM",
    "CameraCommand",
    "ConeWorkspace",
    "ControllerConfig",
    "Intrinsics",
    "Observation",
    "PolicyContext",
    "StereoCamera",
    "TrackingState",
    "__version__",
    "center_error_3d",
    "goal_pose",
    "image_centering_error",
    "look_at_pose",
    "make_policy",
    "orientation_error",
]
