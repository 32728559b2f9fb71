"""dVRK Classic PSM carrying a PROGRASP_FORCEPS_420093 tool: FK, closed-form IK, Jacobian.

Joint order: ``outer_yaw, outer_pitch, outer_insertion, roll, wrist_pitch, wrist_yaw``
(rad, rad, m, rad, rad, rad). The jaw opening is not modelled. Base frame: the RCM.

Closed-form IK (geometry of the modified-DH table below):

1. ``T_rcm_6 = T_rcm_tip · T_tooltip⁻¹``; its origin ``p`` is the wrist-yaw frame origin and
   its z axis ``z6`` the wrist-yaw axis.
2. The wrist-pitch point ``p_w`` lies on the shaft (through the RCM) and
   ``p = p_w + L · x5`` with ``L = 0.0107`` m and ``x5 ⟂ z6``; the shaft direction lies in
   ``span(x5, z6)``, so ``x5`` is the unit component of ``p`` perpendicular to ``z6``
   (``x5 · shaft = cos(wrist_pitch) > 0`` selects the sign).
3. From ``p_w``: insertion ``= |p_w| − (D_roll + offset_insertion)``, and outer yaw / pitch
   from the shaft direction ``(sin q1 cos q2, −sin q2, −cos q1 cos q2)``.
4. With ``R_rcm_3`` known, ``z6`` expressed in frame 3 gives roll and wrist pitch; the rest
   of the rotation gives wrist yaw.

Revolute joints are moved by ±2π onto the branch inside the limits closest to ``q_seed``.
The result is verified against ``forward``; if the exact solution violates joint limits,
a bounded least-squares solve returns the nearest feasible configuration.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from endocam.geometry import FloatArray, invert_pose
from endocam.robot.dh import (
    IDENTITY12,
    DHChain,
    DHLink,
    JointType,
    Pose12,
    chain_forward,
    compose12,
    flat_rows,
    pose12_from_matrix,
    pose12_times,
    pose12_to_matrix,
)
from endocam.robot.ik import (
    IK_ORIENTATION_TOL_RAD,
    IK_POSITION_TOL_M,
    IKResult,
    IKStatus,
    pose12_error,
    pose_error,
    within_tolerance,
)
from endocam.robot.kinematics import (
    LIMIT_SLACK,
    NEAREST_MAX_NFEV,
    RcmArm,
    branch_in_limits,
)

__all__ = ["PSM", "PSM_CHAIN", "PSM_TOOLTIP_OFFSET", "exact12"]


# The dVRK files write ±1.5708; cisst's robManipulator parser replaces that value by π/2,
# so the kinematics the dVRK actually runs (and this module) use π/2 exactly.
_HALF_PI = math.pi / 2.0  # rad
_R = JointType.REVOLUTE
_P = JointType.PRISMATIC

PSM_TOOLTIP_OFFSET = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""T_wristyaw_tip, (4, 4): rotation only (ISI tool-tip convention)."""

PSM_CHAIN = DHChain(
    links=(
        DHLink("outer_yaw", _HALF_PI, 0.0, 0.0, 0.0, _HALF_PI, _R, -1.588, 1.588),
        DHLink("outer_pitch", -_HALF_PI, 0.0, 0.0, 0.0, -_HALF_PI, _R, -0.925025, 0.925025),
        DHLink("outer_insertion", _HALF_PI, 0.0, 0.0, 0.0, -0.4318, _P, 0.0, 0.24),
        DHLink("roll", 0.0, 0.0, 0.4670, 0.0, 0.0, _R, -4.53786, 4.53786),
        DHLink("wrist_pitch", -_HALF_PI, 0.0, 0.0, 0.0, -_HALF_PI, _R, -1.39626, 1.39626),
        DHLink("wrist_yaw", -_HALF_PI, 0.0107, 0.0, 0.0, -_HALF_PI, _R, -1.39626, 1.39626),
    ),
    T_last_tip=PSM_TOOLTIP_OFFSET,
)
"""The PSM's modified-DH chain, base frame = RCM.

Values from jhu-dvrk/sawIntuitiveResearchKit: the arm's first three joints from
``share/kinematic/psm.json`` (commit bb73358d: outer yaw ±1.588 rad = ±91°, outer pitch
±0.925025 rad = ±53°, insertion 0-0.24 m), the tool's from
``share/tool/PROGRASP_FORCEPS_420093.json`` (commit 23f23dbe: roll ±4.53786 rad = ±260°, wrist
pitch and yaw ±1.39626 rad = ±80°, D = 0.4670 m, A = 0.0107 m). Another stored version of
psm.json (commit 47f86f38) gives outer yaw ±4.71239 rad (±270°); the ±91° of bb73358d agrees
with the dVRK's own no-tool limits (``mtsIntuitiveResearchKitPSM.cpp``) and the dVRK 1.x
``share/arm/psm-pro-grasp.json``, so it is used (docs/robot.md).
"""

_EPS_GEOM = 1e-9  # m: below this the wrist geometry is singular


class PSM(RcmArm):
    """dVRK Classic PSM with a PROGRASP_FORCEPS_420093 tool (6 DoF).

    Parameters
    ----------
    chain : DHChain, optional
        Kinematic chain; defaults to :data:`PSM_CHAIN`. A different chain must keep the
        structure of the PSM table (the closed form depends on it).
    nearest_max_nfev : int
        Iteration budget of the nearest-feasible fallback (see :class:`RcmArm`).
    """

    def __init__(
        self, chain: DHChain = PSM_CHAIN, nearest_max_nfev: int = NEAREST_MAX_NFEV
    ) -> None:
        super().__init__(chain, nearest_max_nfev)
        links = chain.links
        if len(links) != 6:
            raise ValueError("chain: the PSM closed form needs 6 links")
        T_tip_inv = invert_pose(chain.T_last_tip)
        self._consts = np.array(  # the compiled closed form's constants (_C_* below)
            [
                *T_tip_inv[:3].ravel().tolist(),
                *chain.T_last_tip[:3].ravel().tolist(),
                links[5].A,  # m, wrist pitch → wrist yaw axis
                links[3].D + links[2].offset,  # m, wrist point at insertion 0
                math.cos(links[5].alpha),
                math.sin(links[5].alpha),
                *self._lower.tolist(),
                *self._upper.tolist(),
            ]
        )
        self._consts.setflags(write=False)

    def solve_unchecked(self, T_goal: FloatArray, seed: FloatArray) -> IKResult:
        """Closed-form IK verified by FK; nearest feasible configuration when needed.

        Parameters
        ----------
        T_goal : (4, 4) ndarray
            Goal tool-tip pose in the RCM frame, m (validated by :meth:`solve`).
        seed : (6,) ndarray
            Preferred branch for the yaw and roll joints (±2π).

        Returns
        -------
        IKResult
            ``OK`` with the exact solution; ``CLAMPED_TO_LIMITS`` when the exact solution
            violates a joint limit; ``UNREACHABLE`` when the geometry is singular (tip on the
            wrist-yaw axis line through the RCM, or wrist point at the RCM) and the numeric
            fallback cannot reach the pose. Non-OK results hold the nearest feasible ``q``.
        """
        goal12 = pose12_from_matrix(T_goal)
        sol = self._closed_form(goal12, seed)
        if sol is not None:
            q_list, T12 = sol
            errors = pose12_error(goal12, T12)
            if within_tolerance(*errors):  # the usual case: plain floats, one matrix built
                T = pose12_to_matrix(T12)
                q = np.array(q_list)
            else:  # round-off: polish a few DLS steps
                q = self._polish(np.array(q_list), T_goal)
                T = chain_forward(self._chain, q)
                errors = pose_error(T_goal, T)
            if within_tolerance(*errors):
                q_in, inside = self.clamp_floats(q.tolist())
                if inside:
                    return IKResult(
                        q=np.array(q_in),
                        status=IKStatus.OK,
                        position_error=errors[0],
                        orientation_error=errors[1],
                        T_rcm_tip=T,
                    )
                q_near = self.nearest_feasible(T_goal, self.clamp(q))
                return self._result(q_near, T_goal, IKStatus.CLAMPED_TO_LIMITS)
        # singular wrist geometry (or a failed closed form): bounded numeric solve
        seed_near = seed if sol is None else self.clamp(np.array(sol[0]))
        q_near = self.nearest_feasible(T_goal, seed_near)
        T = chain_forward(self._chain, q_near)
        status = IKStatus.OK if self._reached(T_goal, T) else IKStatus.UNREACHABLE
        return self._result(q_near, T_goal, status, T)

    def exact_unchecked(self, T_goal: FloatArray, seed: FloatArray) -> list[float] | None:
        """The closed form alone: exact joint values within the limits, else ``None``.

        No polish and no nearest-feasible search, so a ``None`` costs no more than a success
        (see :meth:`RcmArm.exact_unchecked`).
        """
        return self.exact12_unchecked(pose12_from_matrix(T_goal), seed)

    def exact12_unchecked(self, goal12: Pose12, seed: FloatArray) -> list[float] | None:
        """:meth:`exact_unchecked` for a goal given as 12 floats (rotation row-major, then m).

        One compiled call (:func:`exact12`).
        """
        ok, q = exact12(
            self._chain.param_array, self._consts, goal12, float(seed[0]), float(seed[3])
        )
        return list(q) if ok else None

    def _closed_form(self, goal: Pose12, seed: FloatArray) -> tuple[list[float], Pose12] | None:
        """Exact joint values for the goal ``T_rcm_tip`` (12 floats, m) ignoring limits.

        Returns ``(q, forward(q))`` (6 joint values, 12 floats), or None when the wrist
        geometry is singular. One compiled call (:func:`_closed_form_kernel`); ``ValueError``
        for a non-finite goal.
        """
        found, q, T = _closed_form_kernel(
            self._chain.param_array, self._consts, goal, float(seed[0]), float(seed[3])
        )
        return (list(q), T) if found else None


# _closed_form_kernel's constants (PSM._consts): T_tip_wristyaw's rows, the tool-tip rows,
# the wrist length (m), the shaft offset (m), cos / sin of alpha6, then lower, upper limits
_C_TIP_INV, _C_TIP, _C_WRIST, _C_SHAFT, _C_CA6, _C_SA6, _C_LOWER, _C_UPPER = (
    0,
    12,
    24,
    25,
    26,
    27,
    28,
    34,
)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _closed_form_kernel(
    params: FloatArray, c: FloatArray, goal: Pose12, seed0: float, seed3: float
) -> tuple[bool, tuple[float, ...], Pose12]:
    """:meth:`PSM._closed_form` (module docstring, steps 1-4), compiled.

    ``params``: the chain's (6, 7) parameter array; ``c``: ``PSM._consts``; ``goal``: the
    tool-tip goal (rotation row-major, then m); ``seed0``, ``seed3``: the yaw and roll seeds,
    rad. Returns ``(found, q, forward(q))``; ``found`` is False when the wrist geometry is
    singular.
    """
    lower, upper = c[_C_LOWER : _C_LOWER + 6], c[_C_UPPER : _C_UPPER + 6]
    x0, _, z0, x1, _, z1, x2, _, z2, p0, p1, p2 = pose12_times(goal, flat_rows(c, _C_TIP_INV))
    none = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    # step 2: wrist-pitch point on the shaft
    pz = p0 * z0 + p1 * z1 + p2 * z2
    e0, e1, e2 = p0 - pz * z0, p1 - pz * z1, p2 - pz * z2
    n_perp = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    L = c[_C_WRIST]
    if n_perp - L <= _EPS_GEOM:
        return False, none, IDENTITY12
    k = L / n_perp
    w0, w1, w2 = p0 - k * e0, p1 - k * e1, p2 - k * e2
    r = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if r <= _EPS_GEOM:
        return False, none, IDENTITY12
    # step 3: outer yaw, pitch, insertion from the shaft direction
    q3 = r - c[_C_SHAFT]
    q2 = -math.asin(max(-1.0, min(1.0, w1 / r)))
    q1 = branch_in_limits(math.atan2(w0, -w2), seed0, lower[0], upper[0])
    T_rcm_3 = compose12(params, (q1, q2, q3, 0.0, 0.0, 0.0), 0, 3, IDENTITY12)
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = T_rcm_3[:9]
    # step 4: wrist-yaw axis in frame 3 = (-cos θ4 sin θ5, -sin θ4 sin θ5, -cos θ5)
    v0 = a00 * z0 + a10 * z1 + a20 * z2
    v1 = a01 * z0 + a11 * z1 + a21 * z2
    v2 = a02 * z0 + a12 * z1 + a22 * z2
    theta5 = math.atan2(-math.hypot(v0, v1), -v2)  # sin θ5 < 0 inside the limits
    theta4 = math.atan2(v1, v0)
    q4 = branch_in_limits(theta4 - params[3, 5], seed3, lower[3], upper[3])
    q5 = branch_in_limits(theta5 - params[4, 5], 0.0, lower[4], upper[4])
    b = compose12(params, (q1, q2, q3, q4, q5, 0.0), 3, 5, IDENTITY12)
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = b[:9]
    # x6 in frame 3, then in frame 5; RotX(alpha6)^T of it is (cos θ6, sin θ6, 0)
    c0 = a00 * x0 + a10 * x1 + a20 * x2
    c1 = a01 * x0 + a11 * x1 + a21 * x2
    c2 = a02 * x0 + a12 * x1 + a22 * x2
    u0 = b00 * c0 + b10 * c1 + b20 * c2
    u1 = b01 * c0 + b11 * c1 + b21 * c2
    u2 = b02 * c0 + b12 * c1 + b22 * c2
    theta6 = math.atan2(c[_C_CA6] * u1 + c[_C_SA6] * u2, u0)
    q6 = branch_in_limits(theta6 - params[5, 5], 0.0, lower[5], upper[5])
    q = (q1, q2, q3, q4, q5, q6)
    # forward(q), reusing the product of the first three links (unchanged since)
    T_rcm_6 = compose12(params, q, 3, 6, T_rcm_3)
    return True, q, pose12_times(T_rcm_6, flat_rows(c, _C_TIP))


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def exact12(
    params: FloatArray, c: FloatArray, goal: Pose12, seed0: float, seed3: float
) -> tuple[bool, tuple[float, ...]]:
    """:meth:`PSM.exact12_unchecked`, compiled: ``(True, q)`` for an exact, in-limit solution.

    ``params``: the chain's (6, 7) :attr:`~endocam.robot.dh.DHChain.param_array`; ``c``:
    :attr:`PSM.ik_constants`; ``goal``: the tool-tip goal in the RCM frame (12 floats, m);
    ``seed0``, ``seed3``: the preferred outer yaw and roll, rad. The closed form
    (:func:`_closed_form_kernel`), its pose error within the IK tolerances
    (:func:`pose12_error`), and ``RcmArm.clamp_floats``'s clip and limit test (``LIMIT_SLACK``
    tolerated, the clipped values returned; ``q``: 6 joints, rad / m).
    """
    found, q, T12 = _closed_form_kernel(params, c, goal, seed0, seed3)
    if not found:
        return False, q
    pos_err, ang_err = pose12_error(goal, T12)
    if not (pos_err <= IK_POSITION_TOL_M and ang_err <= IK_ORIENTATION_TOL_RAD):
        return False, q
    inside = True
    out = [q[0], q[1], q[2], q[3], q[4], q[5]]
    for i in range(6):
        lo, hi = c[_C_LOWER + i], c[_C_UPPER + i]
        v = out[i]
        if v < lo:
            inside = inside and v >= lo - LIMIT_SLACK
            out[i] = lo
        elif v > hi:
            inside = inside and v <= hi + LIMIT_SLACK
            out[i] = hi
    return inside, (out[0], out[1], out[2], out[3], out[4], out[5])
