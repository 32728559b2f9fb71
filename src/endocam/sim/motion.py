"""The camera's actuator model: Cartesian motion under speed and acceleration limits (ruckig).

A policy commands a pose; the camera does not teleport there. Each control step,
:class:`CartesianLimiter` asks ruckig (online trajectory generation) for the next state of six
degrees of freedom, the position and the rotation vector relative to the current orientation,
under per-axis velocity, acceleration and jerk limits. The per-axis limits are the configured
norms divided by √3, so the speed and acceleration *norms* never exceed the configured limits.
Quaternion algebra uses MuJoCo's ``mju_*`` functions (scalar-first, like endocam); scipy's
``Rotation.from_matrix`` costs ~0.1 ms per call here, too slow for a 1 kHz loop.
"""

from __future__ import annotations

import enum
import math

import mujoco
import numpy as np
from ruckig import InputParameter, OutputParameter, Result, Ruckig, RuckigError, Synchronization

from endocam.config import MotionLimits
from endocam.geometry import FloatArray

_SQRT3 = math.sqrt(3.0)
_SNAP_POS = 1e-12  # m or rad: smaller target offsets are round-off
_SNAP_VEL = 1e-12  # m/s or rad/s: smaller velocities are round-off
_SNAP_ACC = 1e-10  # m/s² or rad/s²: smaller accelerations are round-off


def _snap(values: list[float], tol: float) -> list[float]:
    """Values with magnitude below ``tol`` set to exactly 0."""
    return [0.0 if abs(v) < tol else v for v in values]


class MotionStatus(enum.Enum):
    """Outcome of one limiter step."""

    MOVING = "moving"  # still on the way to the target
    ARRIVED = "arrived"  # at the target, at rest
    REJECTED = "rejected"  # the target was not finite; still heading for the last valid one


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
        self._p = np.zeros(3)
        self._R = np.eye(3)
        self._v = [0.0] * 6  # linear velocity (world) and angular velocity (body), SI
        self._acc = [0.0] * 6
        self._target = np.eye(4)
        self._q_cur, self._q_tgt, self._q_rel = np.zeros(4), np.zeros(4), np.zeros(4)
        self._theta = np.zeros(3)
        self.status = MotionStatus.ARRIVED

    def reset(self, T_world_cam: FloatArray) -> None:
        """Start at rest at ``T_world_cam`` (4, 4)."""
        self._p = np.array(T_world_cam[:3, 3], dtype=float)
        self._R = np.array(T_world_cam[:3, :3], dtype=float)
        self._v = [0.0] * 6
        self._acc = [0.0] * 6
        self._target = np.array(T_world_cam, dtype=float)
        self.status = MotionStatus.ARRIVED

    @property
    def pose(self) -> FloatArray:
        """Current ``T_world_cam`` (4, 4)."""
        T = np.eye(4)
        T[:3, :3] = self._R
        T[:3, 3] = self._p
        return T

    @property
    def velocity(self) -> FloatArray:
        """(6,) linear velocity in world (m/s), then angular velocity in the camera (rad/s)."""
        return np.array(self._v)

    def step(self, T_world_target: FloatArray) -> FloatArray:
        """Advance one control period towards ``T_world_target`` (4, 4); returns the new pose.

        A non-finite target is rejected: the camera keeps going to the last valid target,
        within its limits, and ``status`` says ``REJECTED``.
        """
        rejected = not math.isfinite(float(np.sum(T_world_target)))
        if rejected:
            T_world_target = self._target
        self._target = np.array(T_world_target, dtype=float)
        # Re-anchor the orientation DoFs at the current orientation: current rotation vector 0,
        # target = log(q_cur⁻¹ q_target) (body frame, |θ| ≤ π).
        q_cur, q_tgt, q_rel, theta = self._q_cur, self._q_tgt, self._q_rel, self._theta
        mujoco.mju_mat2Quat(q_cur, self._R.ravel())
        mujoco.mju_mat2Quat(q_tgt, np.ascontiguousarray(T_world_target[:3, :3]).ravel())
        mujoco.mju_negQuat(q_rel, q_cur)
        mujoco.mju_mulQuat(q_rel, q_rel.copy(), q_tgt)
        if q_rel[0] < 0.0:
            q_rel *= -1.0  # shortest rotation
        mujoco.mju_quat2Vel(theta, q_rel, 1.0)
        inp = self._inp
        inp.current_position = [*self._p.tolist(), 0.0, 0.0, 0.0]
        inp.current_velocity = self._v
        inp.current_acceleration = self._acc
        inp.target_position = [*T_world_target[:3, 3].tolist(), *theta.tolist()]
        inp.target_velocity = [0.0] * 6
        inp.target_acceleration = [0.0] * 6
        # Round-off residue (~1e-16) near rest makes ruckig's synchronisation fail: snap it to 0.
        inp.current_velocity = _snap(self._v, _SNAP_VEL)
        inp.current_acceleration = _snap(self._acc, _SNAP_ACC)
        delta = [t - c for t, c in zip(inp.target_position, inp.current_position, strict=True)]
        inp.target_position = [
            c if abs(d) < _SNAP_POS else t
            for t, c, d in zip(inp.target_position, inp.current_position, delta, strict=True)
        ]
        try:
            result = self._otg.update(inp, self._out)
        except RuckigError:
            # Rare numerical corner cases: retry without time synchronisation of the DoFs.
            inp.synchronization = Synchronization.No
            try:
                result = self._otg.update(inp, self._out)
            finally:
                inp.synchronization = Synchronization.Time
        if result not in (Result.Working, Result.Finished):
            raise RuntimeError(f"ruckig failed with {result} for a finite target")
        new = self._out.new_position
        if result == Result.Finished:  # at rest on the target: take it exactly (no round-off)
            self._p = np.array(T_world_target[:3, 3], dtype=float)
            self._R = np.array(T_world_target[:3, :3], dtype=float)
            self._v = [0.0] * 6
            self._acc = [0.0] * 6
            self.status = MotionStatus.REJECTED if rejected else MotionStatus.ARRIVED
            return self.pose
        self._p = np.array(new[:3])
        mujoco.mju_quatIntegrate(q_cur, np.array(new[3:]), 1.0)
        mat = np.empty(9)
        mujoco.mju_quat2Mat(mat, q_cur)
        self._R = mat.reshape(3, 3)
        self._v = list(self._out.new_velocity)
        self._acc = list(self._out.new_acceleration)
        if rejected:
            self.status = MotionStatus.REJECTED
        elif result == Result.Finished:
            self.status = MotionStatus.ARRIVED
        else:
            self.status = MotionStatus.MOVING
        return self.pose
