"""dVRK Classic ECM (endoscope camera manipulator, 4 DoF): FK and best-effort IK.

Joint order: ``yaw, pitch, insertion, roll`` (rad, rad, m, rad). Base frame: the RCM.

Tool-tip frame: the dVRK's. The chain ends with the dVRK's straight-scope tool-tip offset
``Rz(−π/2)`` (:data:`~endocam.robot.dvrk_frames.ECM_TOOLTIP_OFFSET_STRAIGHT`), so
``forward(q)`` is the dVRK's ``local/measured_cp`` at ``q``: an ISI camera frame (x left,
y up), origin on the scope axis at ``insertion + (0.3829 − 0.3822)`` m from the RCM, **z along
the scope, away from the RCM** — the viewing direction of a 0° endoscope. endocam's camera
(OpenCV optical frame) sits on it at
:data:`~endocam.robot.dvrk_frames.T_TIP_CAM_ECM` (``Rz(π)``), under the RCM frame
``T_world_rcm · T_RCM_RCMECM`` (:func:`endocam.robot.carriers.arm_mount`). Whatever the
mount, the optical axis of a straight scope passes through the RCM.

IK (position first, closed form). With 4 DoF the ECM cannot reach a general 6-DoF goal:

1. the scope axis is put through the goal position ``p``: shaft direction ``p / |p|``,
   insertion ``|p| − 0.0007`` m, yaw and pitch from the direction
   ``(sin q1 cos q2, −sin q2, −cos q1 cos q2)``;
2. the roll maximises ``trace(R_goal^T R(q))``, i.e. minimises the remaining orientation error
   (closed form ``atan2``).

The residual orientation error is therefore zero exactly when the goal's optical axis passes
through the RCM (``z_goal = p / |p|``), and it is reported otherwise (status
``UNREACHABLE``). Joint limits clamp yaw/pitch/insertion (then a bounded least-squares
solve restores the closest reachable position) and roll (to its nearer limit).

**Least insertion** (:data:`ECM_IK_MIN_INSERTION`): the IK keeps the insertion at 40 mm or
deeper, as the dVRK's does. ``mtsIntuitiveResearchKitECM::InverseKinematics``
(jhu-dvrk/sawIntuitiveResearchKit commit 9e535e68, ``core/components/code/
mtsIntuitiveResearchKitECM.cpp``) solves, then "make sure we are away from RCM point": an
insertion below ``40.0 * cmn_mm`` is raised to 40 mm. It acts on the Cartesian commands only
(``servo_cp``, ``move_cp``: the IK), not on ``servo_jp`` or the joint limits (0-0.255 m).
endocam applies it the way its IK applies any joint limit: as the IK's lower insertion bound,
the closest pose at 40 mm and status ``CLAMPED_TO_LIMITS`` (the dVRK moves there too, but
reports success); joint commands and :meth:`ECM.clamp` keep the joint limit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from endocam.geometry import FloatArray, invert_pose
from endocam.kernels import cross, dot, norm, wrap_angle
from endocam.robot.dh import (
    IDENTITY12,
    DHChain,
    DHLink,
    JointType,
    Pose12,
    compose12,
    compose_links,
    flat_rows,
    pose12_from_matrix,
    pose12_point,
    pose12_times,
    pose12_to_matrix,
)
from endocam.robot.dvrk_frames import ECM_TOOLTIP_OFFSET_STRAIGHT
from endocam.robot.ik import (
    IK_ORIENTATION_TOL_RAD,
    IK_POSITION_TOL_M,
    IKResult,
    IKStatus,
    pose12_error,
)
from endocam.robot.kinematics import (
    LIMIT_SLACK,
    NEAREST_MAX_NFEV,
    RcmArm,
    branch_in_limits,
)

__all__ = [
    "ECM",
    "ECM_CHAIN",
    "ECM_IK_MIN_INSERTION",
    "SOLVE_DONE",
    "SOLVE_NEED_NEAREST",
    "EcmSolve",
    "exact12",
    "solve12",
]


_HALF_PI = math.pi / 2.0  # rad; the dVRK's 1.5708, as its parser reads it
_R = JointType.REVOLUTE
_P = JointType.PRISMATIC

ECM_CHAIN = DHChain(
    links=(
        DHLink("yaw", _HALF_PI, 0.0, 0.0, 0.0, _HALF_PI, _R, -1.5708, 1.5708),
        DHLink("pitch", -_HALF_PI, 0.0, 0.0, 0.0, -_HALF_PI, _R, -0.76794, 1.1344),
        DHLink("insertion", _HALF_PI, 0.0, 0.0, 0.0, -0.3822, _P, 0.0, 0.255),
        DHLink("roll", 0.0, 0.0, 0.3829, 0.0, 0.0, _R, -1.552, 1.552),
    ),
    T_last_tip=ECM_TOOLTIP_OFFSET_STRAIGHT,
)
"""The Classic ECM's modified-DH chain, base frame = RCM, the dVRK's straight-scope tool tip.

DH values and joint limits from jhu-dvrk/sawIntuitiveResearchKit ``share/kinematic/ecm.json``
(commit 09fdffe8): yaw ±1.5708 rad (±90°), pitch −0.76794-1.1344 rad (−44°-65°), insertion
0-0.255 m, roll ±1.552 rad (±88°).
"""

ECM_IK_MIN_INSERTION = 0.04  # m: the dVRK ECM IK's least insertion (module docstring)
_EPS_GEOM = 1e-9  # m: a goal this close to the RCM has no defined shaft direction
_EXACT_TOL_RAD = 1e-9  # rad: orientation residual counted as zero with unlimited joints
_AXIS_MISS_RAD = 1e-6  # rad: an optical axis this far off the RCM's ray is not exact (≫ round-off)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def clamp_angle_to_limits(angle: float, reference: float, lower: float, upper: float) -> float:
    """In-limit angle closest (on the circle) to ``angle``.

    Parameters
    ----------
    angle : float
        Desired angle, rad.
    reference : float
        Preferred branch when several 2π-equivalents lie inside the limits, rad.
    lower, upper : float
        Joint limits, rad.

    Returns
    -------
    float
        An angle in ``[lower, upper]``, rad: an exact equivalent of ``angle`` when one
        exists, otherwise the limit with the smaller angular distance.
    """
    chosen = branch_in_limits(angle, reference, lower, upper)
    if lower - LIMIT_SLACK <= chosen <= upper + LIMIT_SLACK:
        return min(max(chosen, lower), upper)
    to_lower = abs(wrap_angle(lower - angle))
    to_upper = abs(wrap_angle(upper - angle))
    return lower if to_lower <= to_upper else upper


# ECM._consts, the compiled IK's constants: T_tip_last's rows, the tool-tip rows, the tool's
# rotation (row-major), the shaft offset (m), then the lower and upper joint limits
_C_TIP_INV, _C_TIP, _C_TOOL, _C_SHAFT, _C_LOWER, _C_UPPER = 0, 12, 24, 33, 34, 38
SOLVE_DONE = 0
"""A :func:`solve12` outcome: the solve is done."""
SOLVE_NEED_NEAREST = 1
"""A :func:`solve12` outcome: the axis is out of its limits; the caller solves the nearest
in-limit position (scipy) and asks again with it."""
# IK statuses as solve12 returns them (EcmSolve.status indexes this)
_STATUSES = (IKStatus.OK, IKStatus.CLAMPED_TO_LIMITS, IKStatus.UNREACHABLE)


class EcmSolve(NamedTuple):
    """What :func:`solve12` found (the ECM's IK, compiled).

    Attributes
    ----------
    outcome : int
        :data:`SOLVE_DONE` or :data:`SOLVE_NEED_NEAREST`.
    status : int
        0 ``OK``, 1 ``CLAMPED_TO_LIMITS``, 2 ``UNREACHABLE`` (``IKStatus``).
    q : 4-tuple of float
        Joints, rad / m (the unclamped aim with ``SOLVE_NEED_NEAREST``).
    position_error : float
        m.
    orientation_error : float
        rad.
    T12 : Pose12
        ``forward(q)``: the tip in the RCM frame, 12 floats, m.
    p_goal : 3-tuple of float
        The goal position of the last DH frame, RCM frame, m.
    """

    outcome: int
    status: int
    q: tuple[float, float, float, float]
    position_error: float
    orientation_error: float
    T12: Pose12
    p_goal: tuple[float, float, float]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _best_roll(
    params: FloatArray, c: FloatArray, goal: Pose12, q0: float, q1: float, q2: float
) -> tuple[float, Pose12, Pose12]:
    """Roll angle θ4 (rad) maximising trace(R_goal^T R), and the pose's rotation it gives.

    ``goal`` is the goal tip pose (12 floats); the rotation is returned in the same form
    (translation 0), then the product of the first three links at ``q0, q1, q2`` (12 floats,
    m). With ``M = R_tool · R_goalᵀ · R_rcm_3``, ``θ4 = atan2(M01 − M10, M00 + M11)``.
    """
    a = compose12(params, (q0, q1, q2, 0.0), 0, 3, IDENTITY12)
    R3 = (a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], 0.0, 0.0, 0.0)
    # N = R_goal^T R3 (rows of R_goal^T = columns of R_goal)
    g00, g01, g02, g10, g11, g12, g20, g21, g22 = goal[:9]
    a00, a01, _, a10, a11, _, a20, a21, _ = a[:9]
    n00, n01 = g00 * a00 + g10 * a10 + g20 * a20, g00 * a01 + g10 * a11 + g20 * a21
    n10, n11 = g01 * a00 + g11 * a10 + g21 * a20, g01 * a01 + g11 * a11 + g21 * a21
    n20, n21 = g02 * a00 + g12 * a10 + g22 * a20, g02 * a01 + g12 * a11 + g22 * a21
    t = _C_TOOL
    m00 = c[t] * n00 + c[t + 1] * n10 + c[t + 2] * n20
    m01 = c[t] * n01 + c[t + 1] * n11 + c[t + 2] * n21
    m10 = c[t + 3] * n00 + c[t + 4] * n10 + c[t + 5] * n20
    m11 = c[t + 3] * n01 + c[t + 4] * n11 + c[t + 5] * n21
    theta4 = math.atan2(m01 - m10, m00 + m11)
    cos4, sin4 = math.cos(theta4), math.sin(theta4)
    rz = ((cos4, -sin4, 0.0, 0.0), (sin4, cos4, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0))
    tool4 = (
        (c[t], c[t + 1], c[t + 2], 0.0),
        (c[t + 3], c[t + 4], c[t + 5], 0.0),
        (c[t + 6], c[t + 7], c[t + 8], 0.0),
    )
    return theta4, pose12_times(pose12_times(R3, rz), tool4), a


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _aim(
    params: FloatArray, c: FloatArray, goal: Pose12
) -> tuple[tuple[float, float, float], tuple[float, float, float], float, bool, Pose12]:
    """Joints aiming the optical axis at the goal, unclamped, and the roll that fits best.

    Returns yaw, pitch, insertion (rad, rad, m; roll 0), the goal position of the last DH
    frame (m, RCM frame), the best roll θ4 (rad), whether that roll reaches the goal's
    orientation exactly (with unlimited joints: the axis passes through the RCM), and the
    product of the first three links (12 floats, m).
    """
    g = pose12_times(goal, flat_rows(c, _C_TIP_INV))  # last DH frame at the goal
    p0, p1, p2 = g[9], g[10], g[11]
    r = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if r > _EPS_GEOM:
        s0, s1, s2 = p0 / r, p1 / r, p2 / r
    else:
        s0, s1, s2 = g[2], g[5], g[8]
    s1_in = max(-1.0, min(1.0, s1))
    q = (math.atan2(s0, -s2), -math.asin(s1_in), r - c[_C_SHAFT])
    # reachable with unlimited joints iff the best roll on the unclamped axis is exact
    theta4, R_free, T_rcm_3 = _best_roll(params, c, goal, q[0], q[1], q[2])
    exact = pose12_error(goal, R_free)[1] <= _EXACT_TOL_RAD
    return q, (p0, p1, p2), theta4, exact, T_rcm_3


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _axis_in_limits(c: FloatArray, q: tuple[float, float, float]) -> bool:
    """Whether yaw, pitch and insertion ``q`` lie within their limits (± round-off)."""
    for i in range(3):
        if not (c[_C_LOWER + i] - LIMIT_SLACK <= q[i] <= c[_C_UPPER + i] + LIMIT_SLACK):
            return False
    return True


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _roll(params: FloatArray, c: FloatArray, theta4: float, seed3: float) -> tuple[float, bool]:
    """The roll joint for θ4 (rad) within its limits, and False if it had to be clamped."""
    offset, lower, upper = params[3, 5], c[_C_LOWER + 3], c[_C_UPPER + 3]
    q3 = clamp_angle_to_limits(theta4 - offset, seed3, lower, upper)
    return q3, abs(wrap_angle(q3 + offset - theta4)) <= LIMIT_SLACK


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _clip(v: float, lower: float, upper: float) -> float:
    """``RcmArm.clamp_floats``'s clip of one joint value into its limits."""
    if v < lower:
        return lower
    if v > upper:
        return upper
    return v


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _clamped_forward(
    params: FloatArray,
    c: FloatArray,
    q: tuple[float, float, float, float],
    q_axis: tuple[float, float, float],
    T_rcm_3: Pose12,
) -> tuple[tuple[float, float, float, float], Pose12]:
    """``q`` clipped into the limits and ``forward`` of it (12 floats, m).

    Reuses ``T_rcm_3``, the first three links at ``q_axis``, if the clip left those joints
    alone (the roll is the last link, so the product is the same as composing all four).
    """
    lo, hi = _C_LOWER, _C_UPPER
    qc = (
        _clip(q[0], c[lo], c[hi]),
        _clip(q[1], c[lo + 1], c[hi + 1]),
        _clip(q[2], c[lo + 2], c[hi + 2]),
        _clip(q[3], c[lo + 3], c[hi + 3]),
    )
    if qc[0] == q_axis[0] and qc[1] == q_axis[1] and qc[2] == q_axis[2]:
        T = compose12(params, qc, 3, 4, T_rcm_3)
    else:
        T = compose12(params, qc, 0, 4, IDENTITY12)
    return qc, pose12_times(T, flat_rows(c, _C_TIP))


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def solve12(
    params: FloatArray,
    c: FloatArray,
    goal: Pose12,
    seed3: float,
    near: tuple[float, float, float] | None,
) -> EcmSolve:
    """:meth:`ECM.solve_unchecked` (module docstring), compiled.

    ``params``: the chain's (4, 7) :attr:`~endocam.robot.dh.DHChain.param_array`; ``c``:
    :attr:`ECM.ik_constants`; ``goal``: the tip goal in the RCM frame (12 floats, m);
    ``seed3``: the preferred roll, rad. With :data:`SOLVE_NEED_NEAREST` (axis out of its
    limits, ``near`` None) ``q`` is the unclamped aim; the caller finds the nearest in-limit
    yaw, pitch, insertion (rad, rad, m) and calls again with them as ``near``.
    """
    q_axis, p_goal, theta4, exact, T_rcm_3 = _aim(params, c, goal)
    q = (q_axis[0], q_axis[1], q_axis[2], 0.0)
    clamped = False
    if not _axis_in_limits(c, q_axis):
        if near is None:
            return EcmSolve(SOLVE_NEED_NEAREST, 0, q, 0.0, 0.0, IDENTITY12, p_goal)
        clamped = True
        theta4 = _best_roll(params, c, goal, near[0], near[1], near[2])[0]
        q = (near[0], near[1], near[2], 0.0)
    q3, roll_ok = _roll(params, c, theta4, seed3)
    clamped = clamped or not roll_ok
    q, T12 = _clamped_forward(params, c, (q[0], q[1], q[2], q3), q_axis, T_rcm_3)
    status = 2 if not exact else (1 if clamped else 0)
    pos_err, ang_err = pose12_error(goal, T12)
    if status == 0 and not (pos_err <= IK_POSITION_TOL_M and ang_err <= IK_ORIENTATION_TOL_RAD):
        status = 2
    return EcmSolve(SOLVE_DONE, status, q, pos_err, ang_err, T12, p_goal)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def exact12(
    params: FloatArray, c: FloatArray, goal: Pose12, seed3: float
) -> tuple[bool, tuple[float, float, float, float]]:
    """:meth:`ECM.exact12_unchecked`, compiled: ``(True, q)`` for an ``OK`` solve.

    ``params``, ``c``, ``goal`` (12 floats, RCM frame, m), ``seed3`` (rad) as :func:`solve12`;
    ``q``: rad / m (not meaningful with False).
    """
    none = (0.0, 0.0, 0.0, 0.0)
    g = pose12_times(goal, flat_rows(c, _C_TIP_INV))  # last DH frame at the goal
    p = (g[9], g[10], g[11])
    if norm(p) > _EPS_GEOM:  # else at the RCM: no shaft direction to compare with
        z = (g[2], g[5], g[8])
        if math.atan2(norm(cross(z, p)), dot(z, p)) > _AXIS_MISS_RAD:
            return False, none  # the optical axis clearly misses the RCM
    q_axis, _, theta4, exact, T_rcm_3 = _aim(params, c, goal)
    if not (exact and _axis_in_limits(c, q_axis)):
        return False, none
    q3, roll_ok = _roll(params, c, theta4, seed3)
    if not roll_ok:
        return False, none
    q, T12 = _clamped_forward(params, c, (q_axis[0], q_axis[1], q_axis[2], q3), q_axis, T_rcm_3)
    pos_err, ang_err = pose12_error(goal, T12)
    return pos_err <= IK_POSITION_TOL_M and ang_err <= IK_ORIENTATION_TOL_RAD, q


class ECM(RcmArm):
    """dVRK Classic ECM (4 DoF) with a straight scope.

    Parameters
    ----------
    chain : DHChain, optional
        Kinematic chain; defaults to :data:`ECM_CHAIN` (structure must match).
    nearest_max_nfev : int
        Iteration budget of the nearest-feasible fallback (see :class:`RcmArm`).
    """

    def __init__(
        self, chain: DHChain = ECM_CHAIN, nearest_max_nfev: int = NEAREST_MAX_NFEV
    ) -> None:
        super().__init__(chain, nearest_max_nfev)
        if len(chain.links) != 4:
            raise ValueError("chain: the ECM closed form needs 4 links")
        links = chain.links
        tool = chain.T_last_tip[:3, :3]
        ik_lower = self._lower.copy()  # the IK's bounds: the joint limits, insertion ≥ 40 mm
        ik_lower[2] = min(max(ik_lower[2], ECM_IK_MIN_INSERTION), self._upper[2])
        ik_lower.setflags(write=False)
        self.ik_lower = ik_lower
        """(4,) the IK's lower bounds, rad / m: the joint limits, the insertion raised to
        :data:`ECM_IK_MIN_INSERTION`."""
        self._consts = np.array(  # the compiled IK's constants (_C_* above)
            [
                *invert_pose(chain.T_last_tip)[:3].ravel().tolist(),
                *chain.T_last_tip[:3].ravel().tolist(),
                *tool.ravel().tolist(),
                links[2].offset + links[3].D,  # m, tip on axis at insertion 0
                *ik_lower.tolist(),
                *self._upper.tolist(),
            ]
        )
        self._consts.setflags(write=False)

    def solve_unchecked(self, T_goal: FloatArray, seed: FloatArray) -> IKResult:
        """Position-first IK; the residual orientation error is reported, never hidden.

        Parameters
        ----------
        T_goal : (4, 4) ndarray
            Goal camera (tip) pose in the RCM frame, m; z = viewing direction (validated by
            :meth:`solve`).
        seed : (4,) ndarray
            Preferred roll branch.

        Returns
        -------
        IKResult
            ``OK`` when the goal is reached (its optical axis passes through the RCM and the
            joints are in limits); ``UNREACHABLE`` when the optical axis misses the RCM
            (residual orientation error > 0); ``CLAMPED_TO_LIMITS`` when only joint limits
            prevent it (the insertion's IK bound, 40 mm, included). ``q`` is always within
            the limits and :attr:`ik_lower`. Compiled (:func:`solve12`)
            but for the nearest in-limit position of an axis out of its limits (scipy).
        """
        goal = pose12_from_matrix(T_goal)
        args = (self._chain.param_array, self._consts, goal, float(seed[3]))
        found = solve12(*args, None)
        if found.outcome == SOLVE_NEED_NEAREST:
            q_clip = self.clamp(np.array(found.q))[:3]
            shallow = found.q[2] < self.ik_lower[2]  # the aim's insertion: the bound binds
            near = self._nearest_position(np.array(found.p_goal), q_clip, shallow).tolist()
            found = solve12(*args, (near[0], near[1], near[2]))
        return IKResult(
            np.array(found.q),
            _STATUSES[found.status],
            found.position_error,
            found.orientation_error,
            pose12_to_matrix(found.T12),
        )

    def exact12_unchecked(self, goal12: Pose12, seed: FloatArray) -> list[float] | None:
        """:meth:`solve_unchecked`'s joints when its status is ``OK``, else ``None``.

        The same steps as :meth:`solve_unchecked`, stopping at the first that rules ``OK``
        out (an optical axis clearly off the ray from the RCM, more than ``_AXIS_MISS_RAD``,
        far beyond ``_EXACT_TOL_RAD``; a joint limit): the control loop asks this several
        times per step, mostly of goals the 4-DoF scope cannot reach. One compiled call
        (:func:`exact12`).
        """
        ok, q = exact12(self._chain.param_array, self._consts, goal12, float(seed[3]))
        return list(q) if ok else None

    def _nearest_position(self, p_goal: FloatArray, q0: FloatArray, shallow: bool) -> FloatArray:
        """Yaw, pitch, insertion within :attr:`ik_lower` and the limits, tip closest to ``p_goal``.

        Solved within the joint limits first and, only if that insertion is below the IK's
        40 mm, again within the IK's bounds: the solver's steps depend on its bounds, so an
        insertion the bound does not touch is found exactly as without it (episodes that stay
        deeper than 40 mm are bit-identical to the joint-limit IK's). ``shallow``: the goal is
        nearer the RCM than the tip at 40 mm, so the nearest position is at the bound (the
        first solve is skipped).
        """

        def residual(x: FloatArray) -> FloatArray:  # the tip position of chain_forward
            T = compose_links(self._chain, [*x.tolist(), 0.0])
            return np.array(pose12_point(T, self._chain._tip_rows)) - p_goal

        hi = self._upper[:3]
        for lo in (self.ik_lower[:3],) if shallow else (self._lower[:3], self.ik_lower[:3]):
            span = hi - lo
            x0 = np.clip(q0, lo + 1e-9 * span, hi - 1e-9 * span)
            sol = least_squares(residual, x0, bounds=(lo, hi), method="trf", xtol=1e-12, ftol=1e-12)
            q = np.clip(np.asarray(sol.x, dtype=np.float64), lo, hi)
            if q[2] >= self.ik_lower[2]:
                break
        return q
