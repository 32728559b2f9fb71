"""dVRK arm kinematics (PSM, ECM) and a CRTK-style arm interface.

Poses are ``T_rcm_tip``: the tool tip in the arm's remote-centre-of-motion frame, metres and
radians, as the dVRK's ``measured_cp`` reports them (see ``docs/robot.md``).
"""

from endocam.robot.arm import (
    ECM_MAX_ACCELERATION,
    ECM_MAX_VELOCITY,
    PSM_MAX_ACCELERATION,
    PSM_MAX_VELOCITY,
    CrtkArm,
    MotionStatus,
    SimulatedArm,
    UnreachablePolicy,
)
from endocam.robot.dh import DHChain, DHLink, JointType
from endocam.robot.ecm import ECM, ECM_CHAIN
from endocam.robot.ik import IKResult, IKStatus, UnreachableError, pose_error
from endocam.robot.kinematics import RcmArm
from endocam.robot.psm import PSM, PSM_CHAIN, PSM_TOOLTIP_OFFSET

__all__ = [
    "ECM",
    "ECM_CHAIN",
    "ECM_MAX_ACCELERATION",
    "ECM_MAX_VELOCITY",
    "PSM",
    "PSM_CHAIN",
    "PSM_MAX_ACCELERATION",
    "PSM_MAX_VELOCITY",
    "PSM_TOOLTIP_OFFSET",
    "CrtkArm",
    "DHChain",
    "DHLink",
    "IKResult",
    "IKStatus",
    "JointType",
    "MotionStatus",
    "RcmArm",
    "SimulatedArm",
    "UnreachableError",
    "UnreachablePolicy",
    "pose_error",
]
