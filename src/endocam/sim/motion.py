"""The camera's actuator model: Cartesian motion under speed and acceleration limits (ruckig).

A policy commands a pose; the camera does not teleport there. Each control step,
:class:`CartesianLimiter` asks ruckig (online trajectory generation) for the next state of six
degrees of freedom, the position and the rotation vector relative to the current orientation,
under per-axis velocity, acceleration and jerk limits. The per-axis limits are the configured
norms divided by √3, so the speed and acceleration *norms* never exceed the configured limits.
The rotation-vector map (SO(3) log and exp) is done on plain floats: on this machine scipy's
``Rotation.from_matrix`` costs ~150 µs per call and each MuJoCo ``mju_*`` call ~3 µs of binding
overhead, too much for a 1 kHz loop. The kernels are checked against scipy in the tests.
"""

from __future__ import annotations

import enum
import math

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


Rows = list[list[float]]
_SMALL_ANGLE = 1e-8  # rad, below this the first-order series of log/exp is exact in floats


def so3_log(R: Rows) -> list[float]:
    """Rotation vector (3,) of a rotation matrix given as rows, rad; |θ| ≤ π.

    Uses the quaternion of ``R`` (Shepperd's branch choice, stable for every angle) and
    ``θ = 2 atan2(|v|, w) v/|v|`` with ``w ≥ 0``.
    """
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
    tr = r00 + r11 + r22
    if tr > 0.0:
        k = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * k, (r21 - r12) / k, (r02 - r20) / k, (r10 - r01) / k
    elif r00 > r11 and r00 > r22:
        k = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        w, x, y, z = (r21 - r12) / k, 0.25 * k, (r01 + r10) / k, (r02 + r20) / k
    elif r11 > r22:
        k = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        w, x, y, z = (r02 - r20) / k, (r01 + r10) / k, 0.25 * k, (r12 + r21) / k
    else:
        k = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
        w, x, y, z = (r10 - r01) / k, (r02 + r20) / k, (r12 + r21) / k, 0.25 * k
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s < _SMALL_ANGLE:
        return [2.0 * x, 2.0 * y, 2.0 * z]
    scale = 2.0 * math.atan2(s, w) / s
    return [scale * x, scale * y, scale * z]


def so3_exp(theta: list[float]) -> Rows:
    """Rotation matrix (rows) of a rotation vector (3,), rad (Rodrigues' formula)."""
    x, y, z = theta
    a2 = x * x + y * y + z * z
    if a2 < _SMALL_ANGLE * _SMALL_ANGLE:
        s, c = 1.0, 0.5  # sin(a)/a and (1 − cos a)/a² to first order
    else:
        a = math.sqrt(a2)
        s, c = math.sin(a) / a, (1.0 - math.cos(a)) / a2
    return [
        [1.0 - c * (y * y + z * z), c * x * y - s * z, c * x * z + s * y],
        [c * x * y + s * z, 1.0 - c * (x * x + z * z), c * y * z - s * x],
        [c * x * z - s * y, c * y * z + s * x, 1.0 - c * (x * x + y * y)],
    ]


def _matmul(A: Rows, B: Rows) -> Rows:
    """``A B`` for 3×3 row lists (unrolled: this runs every control step)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = B
    return [
        [a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21,
         a00 * b02 + a01 * b12 + a02 * b22],
        [a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21,
         a10 * b02 + a11 * b12 + a12 * b22],
        [a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21,
         a20 * b02 + a21 * b12 + a22 * b22],
    ]  # fmt: skip


def _tmatmul(A: Rows, B: Rows) -> Rows:
    """``A^T B`` for 3×3 row lists."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    return _matmul([[a00, a10, a20], [a01, a11, a21], [a02, a12, a22]], B)


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
        self.status = MotionStatus.ARRIVED

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
        self.status = MotionStatus.ARRIVED
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
        if self.status is MotionStatus.ARRIVED and flat == self._arrived_at:
            return self._pose_array.copy()  # at rest on an unchanged target: nothing to do
        # Re-anchor the orientation DoFs at the current orientation: current rotation vector 0,
        # target = log(R_cur^T R_target) (body frame, |θ| ≤ π).
        R_tgt = [flat[0:3], flat[4:7], flat[8:11]]
        theta = so3_log(_tmatmul(self._R, R_tgt))
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
            self.status = MotionStatus.REJECTED if rejected else MotionStatus.ARRIVED
            self._arrived_at = flat
            self._pose_array = self.pose
            return self._pose_array
        new = self._out.new_position
        self._p = new[:3]
        self._R = _matmul(self._R, so3_exp(new[3:]))
        self._v = self._out.new_velocity
        self._acc = self._out.new_acceleration
        self.status = MotionStatus.REJECTED if rejected else MotionStatus.MOVING
        return self.pose
