"""The camera's actuator model: Cartesian motion under speed and acceleration limits (ruckig).

A policy commands a pose; the camera does not teleport there. Each control step,
:class:`CartesianLimiter` asks ruckig (online trajectory generation) for the next state of six
degrees of freedom, the position and the rotation vector relative to the current orientation,
under per-axis velocity, acceleration and jerk limits. The per-axis limits are the configured
norms divided by √3, so the speed and acceleration *norms* never exceed the configured limits.
The rotation-vector map (SO(3) log and exp) runs on plain floats (:mod:`endocam.kernels`):
the limiter steps once per control period (100 Hz by default, ``EpisodeConfig.control_rate``).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from ruckig import InputParameter, OutputParameter, Result, Ruckig, RuckigError, Synchronization

from endocam.geometry import FloatArray, as_pose
from endocam.kernels import Rows, matmul, so3_exp, so3_log, tmatmul
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind
from endocam.robot.arm import MotionStatus


class MotionLimits(BaseModel):
    """Limits on the free camera's Cartesian motion (norms): it never teleports.

    The paper's 6-DoF camera is "a stereo camera attached to the end of the surgical tool tip"
    (Sec. III-D): a camera carried by a dVRK PSM. Its limits are therefore ones that PSM can
    deliver in every direction, from the dVRK's joint-trajectory defaults (sawIntuitiveResearchKit
    ``mtsIntuitiveResearchKitPSM.cpp``, the values of ``robot.arm.PSM_MAX_VELOCITY`` /
    ``PSM_MAX_ACCELERATION``), at a camera ≈ 0.15 m from the RCM: the outer yaw/pitch joints
    (π rad/s, π rad/s²) move the tip ≈ 0.47 m/s and 0.47 m/s², the insertion stage 0.2 m/s, and
    the wrist turns at 6π rad/s with 4π rad/s². The jerk limits are ours, for smooth video (the
    dVRK's defaults limit no jerk).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_linear_speed: float = Field(
        0.15,
        gt=0.0,
        description="Camera speed limit, m/s: under the PSM's slowest translational axis "
        "(insertion, 0.2 m/s).",
    )
    max_linear_acceleration: float = Field(
        0.47,
        gt=0.0,
        description="Acceleration limit, m/s²: the PSM's outer joints (π rad/s²) at 0.15 m.",
    )
    max_angular_speed: float = Field(
        math.radians(120.0),
        gt=0.0,
        description="Angular speed limit, rad/s: a third of a turn per second, far under the "
        "PSM wrist's 6π rad/s, so the view never whips.",
    )
    max_angular_acceleration: float = Field(
        4.0 * math.pi,
        gt=0.0,
        description="Angular acceleration limit, rad/s²: the PSM wrist's 4π rad/s².",
    )
    max_linear_jerk: float = Field(20.0, gt=0.0, description="Jerk limit, m/s³ (smooth video).")
    max_angular_jerk: float = Field(
        math.radians(24000.0), gt=0.0, description="Angular jerk limit, rad/s³ (smooth video)."
    )


_SQRT3 = math.sqrt(3.0)
_SNAP_POS = 1e-12  # m or rad: smaller target offsets are round-off
_SNAP_VEL = 1e-12  # m/s or rad/s: smaller velocities are round-off
_SNAP_ACC = 1e-10  # m/s² or rad/s²: smaller accelerations are round-off


def _snap(values: list[float], tol: float) -> list[float]:
    """Values with magnitude below ``tol`` set to exactly 0."""
    return [0.0 if abs(v) < tol else v for v in values]


class CartesianLimiter:
    """Moves a pose towards a (moving) target under speed, acceleration and jerk limits.

    Parameters
    ----------
    limits : MotionLimits
        Speed and acceleration norms (m/s, m/s², rad/s, rad/s²).
    dt : float
        Control period, s.
    """

    def __init__(self, limits: MotionLimits, dt: float) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be > 0 s, got {dt}")
        self.limits = limits
        self.dt = dt
        self._otg = Ruckig(6, dt)
        self._inp = InputParameter(6)
        self._out = OutputParameter(6)
        v, a = limits.max_linear_speed / _SQRT3, limits.max_linear_acceleration / _SQRT3
        w, al = limits.max_angular_speed / _SQRT3, limits.max_angular_acceleration / _SQRT3
        self._inp.max_velocity = [v, v, v, w, w, w]
        self._inp.max_acceleration = [a, a, a, al, al, al]
        j, jr = limits.max_linear_jerk / _SQRT3, limits.max_angular_jerk / _SQRT3
        self._inp.max_jerk = [j, j, j, jr, jr, jr]  # jerk-limited: smooth for the viewer
        # Each DoF is limited on its own (no time synchronisation): the target moves every step,
        # so synchronised arrival buys nothing, and it halves ruckig's cost.
        self._inp.synchronization = Synchronization.No
        self._p = [0.0, 0.0, 0.0]
        self._R: Rows = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        self._v = [0.0] * 6  # linear velocity (world) and angular velocity (body), SI
        self._acc = [0.0] * 6
        self._target = np.eye(4)
        self._arrived_at: list[float] = []  # flattened target the camera rests on
        self._moving_target = False  # the last step had a target velocity
        self._pose_array = np.eye(4)
        self.status = MotionStatus.FINISHED

    def reset(self, T_world_cam: FloatArray) -> None:
        """Start at rest at ``T_world_cam`` (4, 4)."""
        T = np.asarray(T_world_cam, dtype=float)
        self._p = T[:3, 3].tolist()
        self._R = T[:3, :3].tolist()
        self._v = [0.0] * 6
        self._acc = [0.0] * 6
        self._target = np.array(T_world_cam, dtype=float)
        self._arrived_at = self._target.ravel().tolist()
        self._pose_array = self.pose
        self.status = MotionStatus.FINISHED
        if self._moving_target:
            self._inp.target_velocity = [0.0] * 6
            self._moving_target = False

    @property
    def pose(self) -> FloatArray:
        """Current ``T_world_cam`` (4, 4)."""
        R, p = self._R, self._p
        return np.array(
            [
                [R[0][0], R[0][1], R[0][2], p[0]],
                [R[1][0], R[1][1], R[1][2], p[1]],
                [R[2][0], R[2][1], R[2][2], p[2]],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )

    @property
    def velocity(self) -> FloatArray:
        """(6,) linear velocity in world (m/s), then angular velocity in the camera (rad/s)."""
        return np.array(self._v)

    def _retry(self, inp: InputParameter) -> Result:
        """Ruckig fails on rare round-off residue near rest (~1e-16): snap it to 0 and retry."""
        inp.current_velocity = _snap(self._v, _SNAP_VEL)
        inp.current_acceleration = _snap(self._acc, _SNAP_ACC)
        inp.target_position = [
            c if abs(t - c) < _SNAP_POS else t
            for t, c in zip(inp.target_position, inp.current_position, strict=True)
        ]
        return self._otg.update(inp, self._out)

    def _target_velocity(self, twist: FloatArray | None) -> list[float] | None:
        """Target velocity in ruckig's coordinates, clipped to the per-axis limits, or ``None``.

        ``twist`` (6,): linear velocity in world (m/s), angular velocity in world (rad/s); the
        angular part is expressed in the current camera frame (the orientation DoFs' frame).
        ``None`` for no twist, a non-finite one or an all-zero one (arrive at rest).
        """
        if twist is None:
            return None
        w = np.ravel(twist).tolist()
        if len(w) != 6 or not math.isfinite(math.fsum(w)) or not any(w):
            return None
        R = self._R
        body = [
            R[0][0] * w[3] + R[1][0] * w[4] + R[2][0] * w[5],
            R[0][1] * w[3] + R[1][1] * w[4] + R[2][1] * w[5],
            R[0][2] * w[3] + R[1][2] * w[4] + R[2][2] * w[5],
        ]
        vmax = self._inp.max_velocity
        return [min(max(v, -m), m) for v, m in zip([w[0], w[1], w[2], *body], vmax, strict=True)]

    def step(self, T_world_target: FloatArray, twist: FloatArray | None = None) -> FloatArray:
        """Advance one control period towards ``T_world_target`` (4, 4); returns the new pose.

        A non-finite target is rejected: the camera keeps going to the last valid target,
        within its limits, and ``status`` says ``REJECTED``.

        ``twist`` (6,), optional: the target's velocity, linear in world (m/s) then angular in
        world (rad/s). The camera then reaches the target moving with it (clipped to the
        per-axis speed limits), so a steadily moving target is followed without lag. ``None``
        (the default) arrives at rest, exactly as without the argument.
        """
        flat = np.ravel(T_world_target).tolist()
        rejected = len(flat) != 16 or not math.isfinite(math.fsum(flat))
        if rejected:
            T_world_target = self._target
            flat = T_world_target.ravel().tolist()
            twist = None
        else:
            self._target = T_world_target
        v_target = self._target_velocity(twist)
        if v_target is not None or self._moving_target:
            self._inp.target_velocity = v_target if v_target is not None else [0.0] * 6
            self._moving_target = v_target is not None
            if v_target is not None:
                self.status = MotionStatus.MOVING
        if self.status is MotionStatus.FINISHED and flat == self._arrived_at:
            return self._pose_array.copy()  # at rest on an unchanged target: nothing to do
        # Re-anchor the orientation DoFs at the current orientation: current rotation vector 0,
        # target = log(R_cur^T R_target) (body frame, |θ| ≤ π).
        R_tgt = [flat[0:3], flat[4:7], flat[8:11]]
        theta = so3_log(tmatmul(self._R, R_tgt))
        p = self._p
        inp = self._inp
        inp.current_position = [p[0], p[1], p[2], 0.0, 0.0, 0.0]
        inp.target_position = [flat[3], flat[7], flat[11], *theta]
        inp.current_velocity = self._v
        inp.current_acceleration = self._acc
        try:
            result = self._otg.update(inp, self._out)
        except RuckigError:
            result = self._retry(inp)
        if result not in (Result.Working, Result.Finished):
            raise RuntimeError(f"ruckig failed with {result} for a finite target")
        if result == Result.Finished and v_target is None:
            # at rest on the target: take it exactly (no round-off)
            self._p = [flat[3], flat[7], flat[11]]
            self._R = R_tgt
            self._v = [0.0] * 6
            self._acc = [0.0] * 6
            self.status = MotionStatus.REJECTED if rejected else MotionStatus.FINISHED
            self._arrived_at = flat
            self._pose_array = self.pose
            return self._pose_array
        new = self._out.new_position
        self._p = new[:3]
        self._R = matmul(self._R, so3_exp(new[3:]))
        self._v = self._out.new_velocity
        self._acc = self._out.new_acceleration
        self.status = MotionStatus.REJECTED if rejected else MotionStatus.MOVING
        return self.pose


_NO_JOINTS = np.zeros(0)
_NO_JOINTS.setflags(write=False)


class FreeCamera:
    """The free 6-DoF camera (the paper's simulated endoscope) behind the ``Actuator`` interface.

    It has no joints and reaches every command, within the Cartesian limits of its
    :class:`CartesianLimiter`; it starts at the whole-task overview pose.

    Parameters
    ----------
    limits : MotionLimits
        Speed, acceleration and jerk norms.
    dt : float
        Control period, s.
    """

    kind = ArmKind.FREE
    follows_twist = True  # the limiter tracks the command's velocity

    def __init__(self, limits: MotionLimits, dt: float) -> None:
        self.limiter = CartesianLimiter(limits, dt)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """No joints."""
        return ()

    @property
    def q(self) -> FloatArray:
        """No joints: ``(0,)``."""
        return _NO_JOINTS

    def start_view(
        self, T_world_overview: FloatArray, p_world_centre: FloatArray
    ) -> tuple[FloatArray, float]:
        """The free camera starts at the overview pose itself, looking at the task centre."""
        look = float(np.linalg.norm(np.asarray(p_world_centre) - T_world_overview[:3, 3]))
        return T_world_overview, look

    def reset(self, T_world_cam: object, look_distance: float | None = None) -> FloatArray:
        """Start at rest at ``T_world_cam`` (4, 4); returns it."""
        T = as_pose(T_world_cam, "T_world_cam")
        self.limiter.reset(T)
        return T

    def step(
        self, T_world_cmd: FloatArray, look_distance: float, twist: FloatArray | None = None
    ) -> ActuatorStep:
        """One limiter step towards the command (a non-finite one keeps the last valid target).

        ``twist`` (6,): the command's velocity, linear then angular, world, m/s and rad/s.
        """
        T = self.limiter.step(T_world_cmd, twist)
        return ActuatorStep(T, _NO_JOINTS, T_world_cmd, ActuatorStatus.EXACT, 0.0, 0.0, True)
