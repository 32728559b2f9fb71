"""Common machinery for arms with a remote centre of motion (dVRK PSM and ECM).

:class:`RcmArm` wraps a :class:`~endocam.robot.dh.DHChain` whose base frame is the RCM. It
validates inputs, evaluates FK and the Jacobian, and provides a bounded nearest-feasible
solver used when the closed-form IK of a subclass cannot return an exact, in-limit solution.
"""

from __future__ import annotations

import abc
import math

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from endocam.geometry import FloatArray, as_finite_array, as_pose, invert_pose, so3_log
from endocam.kernels import so3_log as so3_log_rows
from endocam.kernels import tmatmul3_into
from endocam.robot.dh import (
    IDENTITY12,
    DHChain,
    JointType,
    Pose12,
    chain_forward,
    chain_frames,
    compose12,
    geometric_jacobian,
    jacobian_into,
    pose12_to_matrix,
)
from endocam.robot.ik import (
    IKResult,
    IKStatus,
    UnreachableError,
    pose_error,
    within_tolerance,
)

__all__ = [
    "NEAREST_MAX_NFEV",
    "ORIENTATION_WEIGHT_M_PER_RAD",
    "RcmArm",
]


ORIENTATION_WEIGHT_M_PER_RAD = 0.05  # m/rad: 1 rad of orientation error weighs like 5 cm
LIMIT_SLACK = 1e-12  # rad or m: round-off tolerated at a joint limit
_DLS_DAMPING = 1e-6  # damping (m) of the damped-least-squares polish
_DLS_STEPS = 5  # polish iterations after a closed-form solution
NEAREST_MAX_NFEV = 200  # count: default residual evaluations of the nearest-feasible solve


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _round_half_even(x: float) -> float:
    """Python's ``round(x)`` of a finite float (ties to even), as a float."""
    k = float(math.floor(x))
    d = x - k  # exact: the fraction of x
    if d > 0.5 or (d == 0.5 and k % 2.0 != 0.0):
        k += 1.0
    return k


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def wrap_to_nearest(angle: float, reference: float) -> float:
    """Add a multiple of 2π to ``angle`` to bring it closest to ``reference`` (rad).

    Compiled: ``angle + 2π · round((reference − angle) / 2π)`` (ties to even), with
    Python's errors: ``ValueError`` for NaN, ``OverflowError`` for an infinite quotient.
    """
    x = (reference - angle) / (2.0 * math.pi)
    if math.isnan(x):
        raise ValueError("cannot convert float NaN to integer")
    if math.isinf(x):
        raise OverflowError("cannot convert float infinity to integer")
    return angle + 2.0 * math.pi * _round_half_even(x)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def branch_in_limits(angle: float, reference: float, lower: float, upper: float) -> float:
    """The 2π-equivalent of ``angle`` inside ``[lower, upper]`` closest to ``reference``.

    Falls back to the equivalent closest to ``reference`` when none is inside the limits.
    Compiled (called from the compiled PSM closed form and from Python); among equally close
    equivalents the lowest wins.

    Parameters
    ----------
    angle, reference, lower, upper : float
        Angles, rad.

    Returns
    -------
    float
        The chosen angle, rad.
    """
    two_pi = 2.0 * math.pi
    best = wrap_to_nearest(angle, reference)
    if lower - LIMIT_SLACK <= best <= upper + LIMIT_SLACK:
        return best
    k = float(math.ceil((lower - LIMIT_SLACK - angle) / two_pi))
    k_hi = float(math.floor((upper + LIMIT_SLACK - angle) / two_pi))
    chosen, error = best, math.inf
    found = False
    while k <= k_hi:  # the candidates from the lowest up; the first closest is kept
        a = angle + two_pi * k
        e = abs(a - reference)
        if not found or e < error:
            chosen, error, found = a, e, True
        k += 1.0
    return chosen


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _residual_into(
    params: FloatArray,
    T_last_tip: FloatArray,
    q: FloatArray,
    T_goal: FloatArray,
    weight: float,
    out: FloatArray,
) -> None:
    """The nearest-feasible solve's residual (6,) at ``q`` (n,), into ``out``, m.

    ``[p(q) - p_goal, w · so3_log(R_goal^T R(q))]`` with ``T(q)`` the chain's tip pose
    (``params``: ``DHChain.param_array``; ``T_last_tip`` (4, 4)) and ``T_goal`` (4, 4), RCM
    frame, m; ``weight`` m/rad: ``chain_forward``'s product, then ``T_goal[:3, :3].T @ R``.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = compose12(
        params, q, 0, params.shape[0], IDENTITY12
    )
    R = np.empty((3, 3))
    tip = T_last_tip
    for c in range(3):  # pose12_to_matrix's product with the tip offset
        a, b, d = tip[0, c], tip[1, c], tip[2, c]
        R[0, c] = r00 * a + r01 * b + r02 * d
        R[1, c] = r10 * a + r11 * b + r12 * d
        R[2, c] = r20 * a + r21 * b + r22 * d
    a3, b3, c3 = tip[0, 3], tip[1, 3], tip[2, 3]
    out[0] = r00 * a3 + r01 * b3 + r02 * c3 + px - T_goal[0, 3]
    out[1] = r10 * a3 + r11 * b3 + r12 * c3 + py - T_goal[1, 3]
    out[2] = r20 * a3 + r21 * b3 + r22 * c3 + pz - T_goal[2, 3]
    M = np.empty((3, 3))
    tmatmul3_into(T_goal, R, M)
    rot = so3_log_rows(
        (
            (M[0, 0], M[0, 1], M[0, 2]),
            (M[1, 0], M[1, 1], M[1, 2]),
            (M[2, 0], M[2, 1], M[2, 2]),
        )
    )
    out[3], out[4], out[5] = weight * rot[0], weight * rot[1], weight * rot[2]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _residual_jac_into(
    params: FloatArray,
    T_last_tip: FloatArray,
    q: FloatArray,
    T_goal: FloatArray,
    weight: float,
    out: FloatArray,
) -> None:
    """Jacobian (6, n) of :func:`_residual_into` at ``q``, into ``out``.

    ``[J_v; w · R_goal^T J_ω]`` with ``J`` the geometric Jacobian (``dh.jacobian_into``); the
    product ``T_goal[:3, :3].T @ J[3:]`` column by
    column in place (plain loops: a fraction of the compile time of slices and a temporary).
    """
    jacobian_into(params, T_last_tip, q, out)
    for c in range(params.shape[0]):
        w0, w1, w2 = out[3, c], out[4, c], out[5, c]
        for r in range(3):
            out[3 + r, c] = weight * (T_goal[0, r] * w0 + T_goal[1, r] * w1 + T_goal[2, r] * w2)


class RcmArm(abc.ABC):
    """An arm whose kinematic base frame is its remote centre of motion.

    Parameters
    ----------
    chain : DHChain
        Modified-DH chain, base frame = RCM, followed by the tool-tip offset.
    nearest_max_nfev : int
        Default iteration budget (residual evaluations) of :meth:`nearest_feasible`; a
        control loop that must stay fast lowers it (the result is then a coarser, still
        in-limit, approach of the nearest feasible configuration).
    """

    def __init__(self, chain: DHChain, nearest_max_nfev: int = NEAREST_MAX_NFEV) -> None:
        if not (isinstance(nearest_max_nfev, int) and nearest_max_nfev >= 1):
            raise ValueError("nearest_max_nfev: must be a positive integer")
        self.nearest_max_nfev = nearest_max_nfev
        self._chain = chain
        self._lower = chain.lower
        self._upper = chain.upper
        self._lower.setflags(write=False)
        self._upper.setflags(write=False)
        self._lower_slack = self._lower - LIMIT_SLACK
        self._limit_pairs = tuple(zip(self._lower.tolist(), self._upper.tolist(), strict=True))
        self._upper_slack = self._upper + LIMIT_SLACK
        self._consts: FloatArray = np.zeros(0)  # the compiled IK's constants (subclasses)

    # ------------------------------------------------------------------ properties
    @property
    def chain(self) -> DHChain:
        """The modified-DH chain (base = RCM frame)."""
        return self._chain

    @property
    def ik_constants(self) -> FloatArray:
        """The constants the subclass's compiled IK reads (its closed form's), read-only.

        Empty for an arm without a compiled IK; the layout is the subclass's (``psm.exact12``,
        ``ecm.exact12`` and ``ecm.solve12`` take it with the chain's ``param_array``).
        """
        return self._consts

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return self._chain.n_joints

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names from the base outwards."""
        return self._chain.names

    @property
    def lower(self) -> FloatArray:
        """Lower joint limits, (n,), rad / m (read-only)."""
        return self._lower

    @property
    def upper(self) -> FloatArray:
        """Upper joint limits, (n,), rad / m (read-only)."""
        return self._upper

    @property
    def prismatic(self) -> tuple[bool, ...]:
        """Per joint, True for a prismatic (m) joint, False for a revolute (rad) one."""
        return tuple(lk.joint_type is JointType.PRISMATIC for lk in self._chain.links)

    # ------------------------------------------------------------------ helpers
    def check_q(self, q: object, name: str = "q") -> FloatArray:
        """Validate joint values: shape (n,), finite. Raises ValueError naming ``name``."""
        return as_finite_array(q, name, (self.n_joints,))

    def within_limits(self, q: FloatArray) -> bool:
        """True if every joint of ``q`` (n,) lies within its limits (round-off tolerated)."""
        return bool((q >= self._lower_slack).all() and (q <= self._upper_slack).all())

    def clamp_floats(self, q: list[float]) -> tuple[list[float], bool]:
        """Clip joint values given as floats into the limits.

        Parameters
        ----------
        q : list of float
            Joint values, rad / m.

        Returns
        -------
        clipped : list of float
            ``q`` clipped into the limits.
        inside : bool
            True if ``q`` was within the limits (round-off of ``LIMIT_SLACK`` tolerated).
        """
        inside = True
        out = list(q)
        for i, (lo, hi) in enumerate(self._limit_pairs):
            v = out[i]
            if v < lo:
                inside = inside and v >= lo - LIMIT_SLACK
                out[i] = lo
            elif v > hi:
                inside = inside and v <= hi + LIMIT_SLACK
                out[i] = hi
        return out, inside

    def clamp(self, q: FloatArray) -> FloatArray:
        """Clip ``q`` (n,) into the joint limits, rad / m."""
        return np.clip(q, self._lower, self._upper)

    def default_seed(self) -> FloatArray:
        """Seed used when none is given: zero clipped into the limits, (n,)."""
        return self.clamp(np.zeros(self.n_joints))

    # ------------------------------------------------------------------ kinematics
    def forward(self, q: object) -> FloatArray:
        """Forward kinematics.

        Parameters
        ----------
        q : (n,) array_like
            Joint values, rad (revolute) / m (prismatic).

        Returns
        -------
        T_rcm_tip : (4, 4) ndarray
            Tool-tip pose in the RCM frame, m.
        """
        return chain_forward(self._chain, self.check_q(q))

    def frames(self, q: object) -> FloatArray:
        """Poses of all link frames and the tip, ``(n + 1, 4, 4)``, RCM frame, m."""
        return chain_frames(self._chain, self.check_q(q))

    def jacobian(self, q: object) -> FloatArray:
        """Geometric Jacobian of the tool tip, expressed in the RCM frame.

        Parameters
        ----------
        q : (n,) array_like
            Joint values, rad / m.

        Returns
        -------
        J : (6, n) ndarray
            Rows 0–2: linear velocity of the tip origin (m/s); rows 3–5: angular velocity
            (rad/s); both in the RCM frame, per unit joint velocity (rad/s or m/s).
        """
        return geometric_jacobian(self._chain, self.check_q(q))

    def forward_camera(self, q: object, T_tip_cam: object) -> FloatArray:
        """Camera pose for a camera mounted at ``T_tip_cam`` on the tip.

        Parameters
        ----------
        q : (n,) array_like
            Joint values, rad / m.
        T_tip_cam : (4, 4) array_like
            Camera pose in the tool-tip frame, m.

        Returns
        -------
        T_rcm_cam : (4, 4) ndarray
            Camera pose in the RCM frame, m.
        """
        return self.forward(q) @ as_pose(T_tip_cam, "T_tip_cam")

    # ------------------------------------------------------------------ inverse
    def solve(self, T_rcm_tip: object, q_seed: object | None = None) -> IKResult:
        """Inverse kinematics that never raises for a valid, unreachable pose.

        Parameters
        ----------
        T_rcm_tip : (4, 4) array_like
            Goal tool-tip pose in the RCM frame, m.
        q_seed : (n,) array_like, optional
            Joint values whose solution branch is preferred (e.g. the current joints);
            default zero clipped into the limits.

        Returns
        -------
        IKResult
            Joint values inside the limits, status and residual errors (see the subclass's
            :meth:`solve_unchecked` for what each status means for that arm).

        Raises
        ------
        ValueError
            If ``T_rcm_tip`` is not a finite rigid transform or ``q_seed`` is malformed.
        """
        return self.solve_unchecked(as_pose(T_rcm_tip, "T_rcm_tip"), self._seed(q_seed))

    @abc.abstractmethod
    def solve_unchecked(self, T_goal: FloatArray, seed: FloatArray) -> IKResult:
        """:meth:`solve` without input validation, for callers that validated already.

        Parameters
        ----------
        T_goal : (4, 4) ndarray
            A valid rigid transform: goal tip pose in the RCM frame, m.
        seed : (n,) ndarray
            Finite joint values of the preferred branch, rad / m.

        Returns
        -------
        IKResult
            As :meth:`solve`.
        """

    def exact_unchecked(self, T_goal: FloatArray, seed: FloatArray) -> list[float] | None:
        """Joint values reaching ``T_goal`` exactly within the joint limits, else ``None``.

        The cheap question a control loop asks many times (no nearest-feasible search).

        Parameters
        ----------
        T_goal : (4, 4) ndarray
            A valid rigid transform: goal tip pose in the RCM frame, m.
        seed : (n,) ndarray
            Finite joint values of the preferred branch, rad / m.

        Returns
        -------
        list of float or None
            ``n`` joint values (rad / m) when IK status would be ``OK``.
        """
        result = self.solve_unchecked(T_goal, seed)
        return result.q.tolist() if result.ok else None

    def exact12_unchecked(self, goal12: Pose12, seed: FloatArray) -> list[float] | None:
        """:meth:`exact_unchecked` for a goal given as 12 floats (rotation row-major, then m)."""
        return self.exact_unchecked(pose12_to_matrix(goal12), seed)

    def inverse(self, T_rcm_tip: object, q_seed: object | None = None) -> FloatArray:
        """Inverse kinematics that raises when the pose cannot be reached exactly.

        Parameters
        ----------
        T_rcm_tip : (4, 4) array_like
            Goal tool-tip pose in the RCM frame, m.
        q_seed : (n,) array_like, optional
            Joint values whose solution branch is preferred.

        Returns
        -------
        q : (n,) ndarray
            Joint values within the limits, rad / m.

        Raises
        ------
        UnreachableError
            Carrying the nearest feasible ``q``, its pose and the residual errors.
        ValueError
            For malformed or non-finite input.
        """
        result = self.solve(T_rcm_tip, q_seed)
        if result.status is not IKStatus.OK:
            raise UnreachableError(result)
        return result.q

    def solve_camera(
        self, T_rcm_cam: object, T_tip_cam: object, q_seed: object | None = None
    ) -> IKResult:
        """IK for a camera mounted on the tip: goal camera pose → joint values.

        Parameters
        ----------
        T_rcm_cam : (4, 4) array_like
            Goal camera pose in the RCM frame, m.
        T_tip_cam : (4, 4) array_like
            Camera pose in the tool-tip frame, m.
        q_seed : (n,) array_like, optional
            Preferred branch.

        Returns
        -------
        IKResult
            As :meth:`solve`; ``T_rcm_tip`` and the errors refer to the tip. Because the
            mount is rigid, the orientation error equals the camera's, and the position error
            is the camera's when the tip orientation is reached.
        """
        T_goal = as_pose(T_rcm_cam, "T_rcm_cam")
        T_mount = as_pose(T_tip_cam, "T_tip_cam")
        return self.solve(T_goal @ invert_pose(T_mount), q_seed)

    # ------------------------------------------------------------------ shared solvers
    def _seed(self, q_seed: object | None) -> FloatArray:
        if q_seed is None:
            return self.default_seed()
        return self.check_q(q_seed, "q_seed")

    def _result(
        self,
        q: FloatArray,
        T_goal: FloatArray,
        status: IKStatus,
        T: FloatArray | None = None,
    ) -> IKResult:
        if T is None:
            T = chain_forward(self._chain, q)
        pos_err, ang_err = pose_error(T_goal, T)
        return IKResult(
            q=q, status=status, position_error=pos_err, orientation_error=ang_err, T_rcm_tip=T
        )

    def _reached(self, T_goal: FloatArray, T: FloatArray) -> bool:
        return within_tolerance(*pose_error(T_goal, T))

    def _polish(self, q: FloatArray, T_goal: FloatArray) -> FloatArray:
        """A few damped-least-squares steps from ``q`` towards ``T_goal`` (no limits)."""
        for _ in range(_DLS_STEPS):
            T = chain_forward(self._chain, q)
            if self._reached(T_goal, T):
                break
            R_err = T_goal[:3, :3] @ T[:3, :3].T
            err = np.concatenate(
                [
                    T_goal[:3, 3] - T[:3, 3],
                    so3_log(R_err),
                ]
            )
            J = geometric_jacobian(self._chain, q)
            JJt = J @ J.T + _DLS_DAMPING**2 * np.eye(6)
            q = q + J.T @ np.linalg.solve(JJt, err)
        return q

    def _pose_residual(self, q: FloatArray, T_goal: FloatArray, weight: float) -> FloatArray:
        """``[p(q) - p_goal, w · rotvec(R_goal^T R(q))]`` (6,), m (:func:`_residual_into`).

        A new array per call: scipy's solver keeps the residuals it was given.
        """
        out = np.empty(6)
        _residual_into(self._chain.param_array, self._chain.T_last_tip, q, T_goal, weight, out)
        return out

    def _pose_residual_jac(self, q: FloatArray, T_goal: FloatArray, weight: float) -> FloatArray:
        """Jacobian (6, n) of :meth:`_pose_residual` (position rows exact, rotation first order).

        The rotation rows ``R_goal^T J_ω`` are exact at zero orientation error. Compiled
        (:func:`_residual_jac_into`); a new array per call.
        """
        out = np.empty((6, self.n_joints))
        _residual_jac_into(self._chain.param_array, self._chain.T_last_tip, q, T_goal, weight, out)
        return out

    def nearest_feasible(
        self,
        T_goal: FloatArray,
        q_start: FloatArray,
        weight: float = ORIENTATION_WEIGHT_M_PER_RAD,
    ) -> FloatArray:
        """Joint values within limits minimising the weighted pose error to ``T_goal``.

        Bounded nonlinear least squares (``scipy.optimize.least_squares``, trust-region
        reflective) on ``[p(q) - p_goal, w · rotvec(R_goal^T R(q))]`` with the geometric
        Jacobian, started from ``q_start`` clipped into the limits. A local minimum: start close
        to the goal's branch.

        Parameters
        ----------
        T_goal : (4, 4) ndarray
            Goal tip pose, RCM frame, m.
        q_start : (n,) ndarray
            Starting joint values, rad / m.
        weight : float
            Orientation weight ``w``, m/rad.

        Returns
        -------
        q : (n,) ndarray
            Joint values inside the limits, rad / m.
        """
        span = self._upper - self._lower
        x0 = np.clip(q_start, self._lower + 1e-9 * span, self._upper - 1e-9 * span)
        sol = least_squares(
            self._pose_residual,
            x0,
            bounds=(self._lower, self._upper),
            args=(T_goal, weight),
            jac=self._pose_residual_jac,
            method="trf",
            x_scale=1.0,
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
            max_nfev=self.nearest_max_nfev,
        )
        return self.clamp(np.asarray(sol.x, dtype=np.float64))
