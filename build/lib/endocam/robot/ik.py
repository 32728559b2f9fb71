"""Inverse-kinematics results, statuses and pose-error helpers shared by the arms."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from numba.extending import register_jitable

from endocam.geometry import FloatArray
from endocam.kernels import rotation_angle

__all__ = [
    "IK_ORIENTATION_TOL_RAD",
    "IK_POSITION_TOL_M",
    "IKResult",
    "IKStatus",
    "UnreachableError",
    "pose12_error",
    "pose_error",
    "within_tolerance",
]


IK_POSITION_TOL_M = 1e-7  # m: a pose closer than this is "reached"
IK_ORIENTATION_TOL_RAD = 1e-7  # rad: an orientation closer than this is "reached"


def within_tolerance(position_error: float, orientation_error: float) -> bool:
    """True if both residuals are within the IK tolerances (m, rad)."""
    return position_error <= IK_POSITION_TOL_M and orientation_error <= IK_ORIENTATION_TOL_RAD


class IKStatus(enum.Enum):
    """Outcome of an inverse-kinematics request.

    Precedence: ``UNREACHABLE`` (no exact solution even with unlimited joints) over
    ``CLAMPED_TO_LIMITS`` (an exact solution exists but violates joint limits) over ``OK``.
    """

    OK = "ok"
    """Pose reached within tolerance, joints within limits."""
    CLAMPED_TO_LIMITS = "clamped_to_limits"
    """Joint limits prevent the pose; ``q`` is the nearest feasible configuration."""
    UNREACHABLE = "unreachable"
    """The arm's geometry cannot reach the pose; ``q`` is the nearest feasible configuration."""


@dataclass(frozen=True)
class IKResult:
    """Immutable result of an IK solve.

    Attributes
    ----------
    q : (n,) ndarray
        Joint values within the joint limits, rad / m. The exact solution when ``status`` is
        ``OK``, otherwise the nearest feasible configuration found.
    status : IKStatus
        Outcome.
    position_error : float
        ``|p_goal - p(q)|``, m.
    orientation_error : float
        Angle of ``R_goal^T R(q)``, rad.
    T_rcm_tip : (4, 4) ndarray
        ``forward(q)``: the pose actually reached, in the RCM frame, m.
    """

    q: FloatArray
    status: IKStatus
    position_error: float
    orientation_error: float
    T_rcm_tip: FloatArray

    @property
    def ok(self) -> bool:
        """True when ``status`` is ``IKStatus.OK``."""
        return self.status is IKStatus.OK


class UnreachableError(ValueError):
    """Raised by ``inverse`` when the requested pose cannot be reached exactly.

    Attributes
    ----------
    result : IKResult
        The nearest feasible configuration, its pose and its residual errors.
    """

    def __init__(self, result: IKResult) -> None:
        self.result = result
        super().__init__(
            f"pose not reachable ({result.status.value}): nearest feasible pose leaves "
            f"{result.position_error * 1e3:.3f} mm / "
            f"{math.degrees(result.orientation_error):.3f} deg"
        )

    @property
    def q(self) -> FloatArray:
        """Nearest feasible joint values, (n,), rad / m."""
        return self.result.q

    @property
    def T_rcm_tip(self) -> FloatArray:
        """Pose at ``q``, (4, 4), RCM frame, m."""
        return self.result.T_rcm_tip

    @property
    def position_error(self) -> float:
        """Residual position error, m."""
        return self.result.position_error

    @property
    def orientation_error(self) -> float:
        """Residual orientation error, rad."""
        return self.result.orientation_error


def pose_error(T_goal: FloatArray, T: FloatArray) -> tuple[float, float]:
    """Position and orientation distance between two poses in the same frame.

    Parameters
    ----------
    T_goal, T : (4, 4) ndarray
        Poses, m.

    Returns
    -------
    position_error : float
        Distance between the origins, m.
    orientation_error : float
        Angle between the rotations, rad.
    """
    A = T_goal.tolist()
    B = T.tolist()
    d0, d1, d2 = A[0][3] - B[0][3], A[1][3] - B[1][3], A[2][3] - B[2][3]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), rotation_angle(A, B)


@register_jitable  # also callable from compiled kernels (the same source)
def pose12_error(goal: tuple[float, ...], pose: tuple[float, ...]) -> tuple[float, float]:
    """:func:`pose_error` of two 12-float poses (rotation row-major, then translation).

    The float form used in control loops (``endocam.robot.dh.Pose12``).

    Parameters
    ----------
    goal, pose : tuple of 12 floats
        Poses in the same frame, m.

    Returns
    -------
    position_error : float
        Distance between the origins, m.
    orientation_error : float
        Angle between the rotations, rad.
    """
    angle = rotation_angle(
        (goal[0:3], goal[3:6], goal[6:9]), (pose[0:3], pose[3:6], pose[6:9])
    )  # the rotations' rows as slices: cheaper than unpacking and re-packing twelve floats
    dx, dy, dz = goal[9] - pose[9], goal[10] - pose[10], goal[11] - pose[11]
    return math.sqrt(dx * dx + dy * dy + dz * dz), angle
