"""The ECM's IK as the interpreter ran it before it was compiled (tests' reference).

A copy of ``endocam.robot.ecm`` at main before r5-perf (its ``clamp_angle_to_limits`` and the
``ECM`` class, renamed ``InterpretedECM``): ``tests/test_robot_kinematics.py`` pins the
compiled IK (``endocam.robot.ecm._solve_kernel``, ``_exact_kernel``) to it bit for bit. Its
link product and branch choice are the compiled ones, pinned to their own references there.
"""

# mypy: ignore-errors

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from endocam.geometry import FloatArray, invert_pose
from endocam.kernels import cross, dot, norm
from endocam.robot.dh import (
    DHChain,
    Pose12,
    compose_links,
    pose12_from_matrix,
    pose12_point,
    pose12_times,
    pose12_to_matrix,
)
from endocam.robot.ecm import _AXIS_MISS_RAD, _EPS_GEOM, _EXACT_TOL_RAD, ECM_CHAIN
from endocam.robot.ik import IKResult, IKStatus, pose12_error, within_tolerance
from endocam.robot.kinematics import LIMIT_SLACK, NEAREST_MAX_NFEV, RcmArm, branch_in_limits


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

    def circ_dist(a: float) -> float:
        return abs(math.remainder(a - angle, 2.0 * math.pi))

    return lower if circ_dist(lower) <= circ_dist(upper) else upper


class InterpretedECM(RcmArm):
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
        self._T_tip_inv = invert_pose(chain.T_last_tip)
        self._tip_inv_rows = tuple(tuple(row) for row in self._T_tip_inv[:3].tolist())
        self._R_tool = chain.T_last_tip[:3, :3].copy()
        self._tool_rows = self._R_tool.tolist()
        rows4 = np.hstack([self._R_tool, np.zeros((3, 1))])
        self._tool_rows4 = tuple(tuple(row) for row in rows4.tolist())
        self._shaft_offset = links[2].offset + links[3].D  # m, tip on axis at insertion 0

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
            prevent it. ``q`` is always within the limits.
        """
        goal = pose12_from_matrix(T_goal)
        q, p_goal, theta4, exact_orientation, T_rcm_3 = self._aim(goal)
        q_axis = q[:3]
        clamped = False
        if not self._axis_in_limits(q):
            clamped = True
            q_clip = self.clamp(np.array(q))[:3]
            q[:3] = self._nearest_position(np.array(p_goal), q_clip).tolist()
            theta4, _, _ = self._best_roll(goal, q)
        if not self._set_roll(q, theta4, seed):
            clamped = True
        q, _ = self.clamp_floats(q)
        if not exact_orientation:
            status = IKStatus.UNREACHABLE
        elif clamped:
            status = IKStatus.CLAMPED_TO_LIMITS
        else:
            status = IKStatus.OK
        T12 = self._forward12(q, q_axis, T_rcm_3)
        errors = pose12_error(goal, T12)
        if status is IKStatus.OK and not within_tolerance(*errors):
            status = IKStatus.UNREACHABLE
        return IKResult(np.array(q), status, errors[0], errors[1], pose12_to_matrix(T12))

    def exact12_unchecked(self, goal12: Pose12, seed: FloatArray) -> list[float] | None:
        """:meth:`solve_unchecked`'s joints when its status is ``OK``, else ``None``.

        The same steps as :meth:`solve_unchecked`, stopping at the first that rules ``OK``
        out (an optical axis that misses the RCM, a joint limit): the control loop asks this
        several times per step, mostly of goals the 4-DoF scope cannot reach.
        """
        if self._axis_misses_rcm(goal12):
            return None
        q, _, theta4, exact_orientation, T_rcm_3 = self._aim(goal12)
        if not (exact_orientation and self._axis_in_limits(q) and self._set_roll(q, theta4, seed)):
            return None
        q_axis = q[:3]
        q, _ = self.clamp_floats(q)
        T12 = self._forward12(q, q_axis, T_rcm_3)
        return q if within_tolerance(*pose12_error(goal12, T12)) else None

    def _forward12(self, q: list[float], q_axis: list[float], T_rcm_3: Pose12) -> Pose12:
        """``forward(q)`` (12 floats), reusing ``T_rcm_3``, the first three links at ``q_axis``.

        The same products in the same order as composing all four links (the roll is the
        last), so the same floats; ``q_axis`` is the yaw, pitch and insertion ``T_rcm_3`` was
        composed for (recomposed if ``q`` no longer has them, e.g. after clamping).
        """
        if q[:3] == q_axis:
            T = compose_links(self._chain, q, 3, 4, T_rcm_3)
        else:
            T = compose_links(self._chain, q)
        return pose12_times(T, self._chain._tip_rows)

    def _axis_misses_rcm(self, goal: Pose12) -> bool:
        """Whether the goal's optical axis is clearly off the ray from the RCM: no exact solve.

        The scope's last DH frame always has its z on the ray from the RCM through its origin
        (the shaft), so a goal whose z is more than ``_AXIS_MISS_RAD`` off that ray is at least
        as far from every orientation the ECM reaches, far beyond ``_EXACT_TOL_RAD``: the
        cheap first test of :meth:`exact12_unchecked` (most goals of a 6-DoF controller).
        """
        g = pose12_times(goal, self._tip_inv_rows)  # last DH frame at the goal
        p = (g[9], g[10], g[11])
        if not norm(p) > _EPS_GEOM:
            return False  # at the RCM: no shaft direction to compare with
        z = (g[2], g[5], g[8])
        return math.atan2(norm(cross(z, p)), dot(z, p)) > _AXIS_MISS_RAD

    def _aim(
        self, goal: Pose12
    ) -> tuple[list[float], tuple[float, float, float], float, bool, Pose12]:
        """Joints aiming the optical axis at the goal, unclamped, and the roll that fits best.

        Returns ``q`` (yaw, pitch, insertion, roll 0; rad / m), the goal position of the last
        DH frame (m, RCM frame), the best roll θ4 (rad), whether that roll reaches the
        goal's orientation exactly (with unlimited joints: the axis passes through the RCM),
        and the product of the first three links at ``q`` (12 floats, m).
        """
        g = pose12_times(goal, self._tip_inv_rows)  # last DH frame at the goal
        p0, p1, p2 = g[9], g[10], g[11]
        r = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        s0, s1, s2 = (p0 / r, p1 / r, p2 / r) if r > _EPS_GEOM else (g[2], g[5], g[8])
        q = [math.atan2(s0, -s2), -math.asin(max(-1.0, min(1.0, s1))), r - self._shaft_offset, 0.0]
        # reachable with unlimited joints iff the best roll on the unclamped axis is exact
        theta4, R_free, T_rcm_3 = self._best_roll(goal, q)
        exact = pose12_error(goal, R_free)[1] <= _EXACT_TOL_RAD
        return q, (p0, p1, p2), theta4, exact, T_rcm_3

    def _axis_in_limits(self, q: list[float]) -> bool:
        """Whether yaw, pitch and insertion ``q[:3]`` lie within their limits (± round-off)."""
        return all(
            lo - LIMIT_SLACK <= v <= hi + LIMIT_SLACK
            for v, (lo, hi) in zip(q[:3], self._limit_pairs, strict=False)
        )

    def _set_roll(self, q: list[float], theta4: float, seed: FloatArray) -> bool:
        """Set ``q[3]`` to the roll θ4 (rad) within its limits; False if it had to be clamped."""
        link = self._chain.links[3]
        q[3] = clamp_angle_to_limits(theta4 - link.offset, float(seed[3]), link.lower, link.upper)
        return abs(math.remainder(q[3] + link.offset - theta4, 2.0 * math.pi)) <= LIMIT_SLACK

    def _best_roll(self, goal: Pose12, q: list[float]) -> tuple[float, Pose12, Pose12]:
        """Roll angle θ4 (rad) maximising trace(R_goal^T R), and the pose's rotation it gives.

        ``goal`` is the goal tip pose (12 floats); the rotation is returned in the same form
        (translation 0), then the product of the first three links at ``q`` (12 floats, m).
        With ``M = R_tool · R_goalᵀ · R_rcm_3``, ``θ4 = atan2(M01 − M10, M00 + M11)``.
        """
        a = compose_links(self._chain, q, 0, 3)
        R3 = (*a[:9], 0.0, 0.0, 0.0)
        # N = R_goal^T R3 (rows of R_goal^T = columns of R_goal)
        g00, g01, g02, g10, g11, g12, g20, g21, g22 = goal[:9]
        a00, a01, _, a10, a11, _, a20, a21, _ = a[:9]
        n = [
            [g00 * a00 + g10 * a10 + g20 * a20, g00 * a01 + g10 * a11 + g20 * a21],
            [g01 * a00 + g11 * a10 + g21 * a20, g01 * a01 + g11 * a11 + g21 * a21],
            [g02 * a00 + g12 * a10 + g22 * a20, g02 * a01 + g12 * a11 + g22 * a21],
        ]
        t = self._tool_rows
        m = [
            [t[i][0] * n[0][j] + t[i][1] * n[1][j] + t[i][2] * n[2][j] for j in (0, 1)]
            for i in (0, 1)
        ]
        theta4 = math.atan2(m[0][1] - m[1][0], m[0][0] + m[1][1])
        c, s = math.cos(theta4), math.sin(theta4)
        rz = ((c, -s, 0.0, 0.0), (s, c, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0))
        return theta4, pose12_times(pose12_times(R3, rz), self._tool_rows4), a

    def _nearest_position(self, p_goal: FloatArray, q0: FloatArray) -> FloatArray:
        """Yaw, pitch, insertion within limits whose tip is closest to ``p_goal`` (m)."""
        lo, hi = self._lower[:3], self._upper[:3]
        span = hi - lo
        x0 = np.clip(q0, lo + 1e-9 * span, hi - 1e-9 * span)

        def residual(x: FloatArray) -> FloatArray:  # the tip position of chain_forward
            T = compose_links(self._chain, [*x.tolist(), 0.0])
            return np.array(pose12_point(T, self._chain._tip_rows)) - p_goal

        sol = least_squares(residual, x0, bounds=(lo, hi), method="trf", xtol=1e-12, ftol=1e-12)
        return np.clip(np.asarray(sol.x, dtype=np.float64), lo, hi)
