"""The camera arm's port view, target and camera-space path as the interpreter ran them.

A copy of ``endocam.robot.camera_arm`` at main before r7-arm (``_port_rotvec``, ``_turned``,
``CameraArm._exact``, ``target``, ``_view_search``, ``_path_target`` and ``step``'s errors,
with ``view``'s ``look_at_unchecked``), as functions of a ``CameraArm``:
``tests/test_carrier_fast_paths.py`` pins the compiled ones (``_port_rotvec_kernel``,
``_turned_kernel``, ``_exact_into``, ``_ecm_target_kernel``, ``_path_kernel``,
``_target_error_kernel``) to them bit for bit. numpy's products here go through its BLAS; the
kernels take them from ``endocam.blasfloat``.
"""

# mypy: ignore-errors

from __future__ import annotations

import math

import numpy as np

from endocam.geometry import FloatArray
from endocam.kernels import cross, norm, rotation_angle, scaled, so3_exp
from endocam.robot.actuator import ActuatorStatus
from endocam.robot.camera_arm import (
    _EPS_AXIS,
    VIEW_POSITION_TOL_M,
    VIEW_STEPS,
    _path_engage_kernel,
)
from endocam.robot.dh import pose12_between
from endocam.view import pose_from_columns, rotation_columns, vec


def look_at_unchecked(p_cam, p_target, fallback, previous):
    """``view.look_at_unchecked`` as it was."""
    p = vec(p_cam)
    d = vec(p_target)
    d = (d[0] - p[0], d[1] - p[1], d[2] - p[2])
    length = norm(d)
    if not length > 1e-9:
        return fallback
    x_prev = None if previous is None else vec(previous[:3, 0])
    x, y, z = rotation_columns(scaled(d, 1.0 / length), (0.0, 0.0, 1.0), x_prev)
    return pose_from_columns(x, y, z, p)


def _norm(v: FloatArray) -> float:
    return math.sqrt(v.dot(v))


def _cross(a: list[float], b: list[float]) -> FloatArray:
    return np.array(cross((a[0], a[1], a[2]), (b[0], b[1], b[2])), dtype=float)


def port_rotvec(T: FloatArray, look_distance: float, p_rcm: FloatArray) -> FloatArray | None:
    """``camera_arm._port_rotvec`` as it was."""
    z = T[:3, 2]
    v = T[:3, 3] + look_distance * z - p_rcm
    norm_v = _norm(v)
    if norm_v <= _EPS_AXIS:
        return None
    v = v / norm_v
    axis = _cross(z.tolist(), v.tolist())
    sin_t, cos_t = _norm(axis), float(z @ v)
    if sin_t <= _EPS_AXIS:
        if cos_t > 0.0:
            return np.zeros(3)
        axis, sin_t = T[:3, 1].copy(), 1.0
    return axis * (math.atan2(sin_t, cos_t) / sin_t)


def turned(T: FloatArray, look_distance: float, rotvec: FloatArray, fraction: float) -> FloatArray:
    """``camera_arm._turned`` as it was."""
    R_turn = so3_exp([fraction * x for x in rotvec.tolist()])
    t = T.tolist()
    z = [t[0][2], t[1][2], t[2][2]]
    z_t = [R_turn[i][0] * z[0] + R_turn[i][1] * z[1] + R_turn[i][2] * z[2] for i in range(3)]
    c = [t[i][3] + look_distance * z[i] for i in range(3)]
    p_t = [c[i] - look_distance * z_t[i] for i in range(3)]
    return look_at_unchecked(np.array(p_t), np.array(c), T, T)


def exact(arm, T_world_cam):
    """``CameraArm._exact`` as it was."""
    goal12 = pose12_between(arm._rcm_world12, T_world_cam, arm._cam_tip_rows)
    return arm.model.exact12_unchecked(goal12, arm._q)


def tip_goal(arm, T_world_cam):
    return arm._T_rcm_world @ T_world_cam @ arm._T_cam_tip


def target(arm, T_world_goal, look_distance):
    """``CameraArm.target`` as it was (reads and sets ``arm._k_prev`` as it did)."""
    q = exact(arm, T_world_goal)
    if q is not None:
        arm._k_prev = None
        T_target = np.array(T_world_goal, dtype=float)
        T_target.setflags(write=False)
        return q, T_target, ActuatorStatus.EXACT
    rotvec = port_rotvec(T_world_goal, look_distance, arm._p_world_rcm)
    if rotvec is not None:
        if not arm._is_psm:
            T_port = turned(T_world_goal, look_distance, rotvec, 1.0)
            port = arm.model.solve_unchecked(tip_goal(arm, T_port), arm._q)
            if port.position_error <= VIEW_POSITION_TOL_M:
                T_reached = arm._T_world_rcm @ port.T_rcm_tip @ arm._T_tip_cam
                return port.q.tolist(), T_reached, ActuatorStatus.VIEW
        else:
            found = view_search(arm, T_world_goal, look_distance, rotvec)
            if found is not None:
                return found[0], found[1], ActuatorStatus.VIEW
    arm._k_prev = None
    result = arm.model.solve_unchecked(tip_goal(arm, T_world_goal), arm._q)
    T_near = arm._T_world_rcm @ result.T_rcm_tip @ arm._T_tip_cam
    return result.q.tolist(), T_near, ActuatorStatus.NEAREST


def target_errors(answer, T_goal):
    """``CameraArm.step``'s errors of a target as they were: m, rad (0 when exact)."""
    _, T_target, status = answer
    if status is ActuatorStatus.EXACT:
        return 0.0, 0.0
    d = T_target[:3, 3] - T_goal[:3, 3]
    return _norm(d), rotation_angle(T_target[:3, :3].tolist(), T_goal[:3, :3].tolist())


def view_search(arm, T_goal, look_distance, rotvec):
    """``CameraArm._view_search`` as it was."""
    cache = {}

    def reach(k):
        if k not in cache:
            T = turned(T_goal, look_distance, rotvec, k / VIEW_STEPS)
            q = exact(arm, T)
            cache[k] = None if q is None else (q, T)
        return cache[k]

    guess = arm._k_prev
    if guess is None:
        if reach(VIEW_STEPS) is None:
            return None
        lo, hi = 0, VIEW_STEPS
    elif reach(guess) is not None:
        hi, step = guess, 1
        while True:
            lo = max(hi - step, 0)
            if lo == 0 or reach(lo) is None:
                break
            hi, step = lo, 2 * step
    else:
        lo, step = guess, 1
        while True:
            hi = min(lo + step, VIEW_STEPS)
            if reach(hi) is not None:
                break
            if hi == VIEW_STEPS:
                arm._k_prev = None
                return None
            lo, step = hi, 2 * step
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if reach(mid) is None:
            lo = mid
        else:
            hi = mid
    arm._k_prev = hi
    return reach(hi)


def path_target(arm, T_target, look_distance):
    """``CameraArm._path_target`` as it was (the camera: ``arm._T_cam``)."""
    engage, r_cur, alpha, u0, u1, u2, c0, c1, c2 = _path_engage_kernel(
        arm._T_cam, T_target, look_distance
    )
    if not engage:
        return None
    u, c = [u0, u1, u2], [c0, c1, c2]
    z_t = [float(T_target[0, 2]), float(T_target[1, 2]), float(T_target[2, 2])]
    c_arr = np.array(c)
    u_cur = np.array(u)
    u_goal = -np.array(z_t)
    axis = _cross(u, [-x for x in z_t])
    sin_a = _norm(axis)
    ang = math.atan2(sin_a, float(u_cur @ u_goal))
    if sin_a > _EPS_AXIS:
        rotvec = axis * (alpha * ang / sin_a)
    elif u_cur @ u_goal > 0.0:
        rotvec = np.zeros(3)
    else:
        k = _cross(u, [0.0, 0.0, 1.0])
        k_norm = _norm(k)
        if not k_norm > _EPS_AXIS:
            return None
        rotvec = k * (alpha * ang / k_norm)
    R = np.array(so3_exp(rotvec.tolist()))
    r = r_cur + alpha * (look_distance - r_cur)
    p = c_arr + r * (R @ u_cur)
    T_via = look_at_unchecked(p, c_arr, T_target, T_target)
    return exact(arm, T_via)
