r"""Modified Denavit–Hartenberg (Craig) kinematic chains, pure numpy.

Each link transform is

.. math::

    T_{i-1,i} = R_x(\alpha_i)\, T_x(A_i)\, R_z(\theta_i)\, T_z(D_i)

where a revolute joint sets :math:`\theta_i = q_i + \mathrm{offset}_i` (``D`` fixed) and a
prismatic joint sets :math:`D_i = q_i + \mathrm{offset}_i` (``theta`` fixed). The chain product
is followed by a constant tool-tip offset. This is the convention of the dVRK's kinematics
files (``"convention": "modified"``), see ``docs/conventions.md``.

All lengths are in metres, all angles in radians. Frame ``base`` is the chain's base frame
(the RCM for the dVRK PSM and ECM); frame ``i`` is the frame attached to link ``i``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import ArrayLike

from endocam.geometry import FloatArray
from endocam.kernels import matmul4_into

__all__ = [
    "IDENTITY12",
    "DHChain",
    "DHLink",
    "JointType",
    "Pose12",
    "chain_forward",
    "chain_frames",
    "chain_points",
    "compose12",
    "compose12_kernel",
    "compose_links",
    "flat_rows",
    "geometric_jacobian",
    "jacobian_into",
    "link_transform",
    "points12",
    "pose12_between",
    "pose12_from_matrix",
    "pose12_point",
    "pose12_times",
    "pose12_to_matrix",
]


class JointType(enum.Enum):
    """Kind of joint actuating a DH link."""

    REVOLUTE = "revolute"
    PRISMATIC = "prismatic"


@dataclass(frozen=True)
class DHLink:
    """One modified-DH link and its joint.

    Attributes
    ----------
    name : str
        Joint name (e.g. ``"outer_yaw"``).
    alpha : float
        Twist about the previous x axis, rad.
    A : float
        Length along the previous x axis, m.
    D : float
        Offset along the new z axis, m (the constant part for a revolute joint).
    theta : float
        Rotation about the new z axis, rad (the constant part for a prismatic joint).
    offset : float
        Added to the joint value: rad for revolute, m for prismatic joints.
    joint_type : JointType
        Revolute (``q`` adds to ``theta``) or prismatic (``q`` adds to ``D``).
    lower, upper : float
        Joint position limits (rad or m), ``lower <= upper``.
    """

    name: str
    alpha: float
    A: float
    D: float
    theta: float
    offset: float
    joint_type: JointType
    lower: float
    upper: float

    def __post_init__(self) -> None:
        values = (self.alpha, self.A, self.D, self.theta, self.offset, self.lower, self.upper)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"link {self.name!r}: DH parameters and limits must be finite")
        if self.lower > self.upper:
            raise ValueError(f"link {self.name!r}: lower limit exceeds upper limit")


def _identity() -> FloatArray:
    return np.eye(4)


# (cos alpha, sin alpha, A, D, theta, offset, revolute) of one link, for the fast path
_LinkParams = tuple[float, float, float, float, float, float, bool]
_REVOLUTE_COLUMN = 6  # column of the (n, 7) parameter array: 1.0 revolute, 0.0 prismatic
# a rigid transform as 12 floats: rotation row-major, then translation
Pose12 = tuple[float, float, float, float, float, float, float, float, float, float, float, float]
IDENTITY12: Pose12 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class DHChain:
    """A serial chain of modified-DH links followed by a tool-tip offset.

    Attributes
    ----------
    links : tuple of DHLink
        Links from the base outwards.
    T_last_tip : (4, 4) ndarray
        Pose of the tool tip in the last link's frame (m). Not compared by ``==``.
    """

    links: tuple[DHLink, ...]
    T_last_tip: FloatArray = field(default_factory=_identity, compare=False)
    _params: tuple[_LinkParams, ...] = field(init=False, repr=False, compare=False)
    _tip_rows: tuple[tuple[float, ...], ...] = field(init=False, repr=False, compare=False)
    _param_array: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.links) == 0:
            raise ValueError("links: a chain needs at least one link")
        T = np.asarray(self.T_last_tip, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError("T_last_tip: expected a finite (4, 4) homogeneous matrix")
        T = T.copy()
        T.setflags(write=False)
        object.__setattr__(self, "T_last_tip", T)
        params = tuple(
            (
                math.cos(lk.alpha),
                math.sin(lk.alpha),
                lk.A,
                lk.D,
                lk.theta,
                lk.offset,
                lk.joint_type is JointType.REVOLUTE,
            )
            for lk in self.links
        )
        object.__setattr__(self, "_params", params)
        param_array = np.array([[*p[:6], 1.0 if p[6] else 0.0] for p in params])
        param_array.setflags(write=False)
        object.__setattr__(self, "_param_array", param_array)  # the compiled kernel's form
        object.__setattr__(self, "_tip_rows", tuple(tuple(row) for row in T[:3].tolist()))

    @property
    def param_array(self) -> FloatArray:
        """The chain as compiled kernels read it: (n, 7), read-only.

        Per link: cos and sin of ``alpha``, ``A`` (m), ``D`` (m), ``theta`` (rad), ``offset``
        (rad or m), then 1.0 for a revolute joint, 0.0 for a prismatic one.
        """
        return self._param_array

    @property
    def n_joints(self) -> int:
        """Number of joints (one per link)."""
        return len(self.links)

    @property
    def lower(self) -> FloatArray:
        """Lower joint limits, shape (n,), rad or m."""
        return np.array([lk.lower for lk in self.links])

    @property
    def upper(self) -> FloatArray:
        """Upper joint limits, shape (n,), rad or m."""
        return np.array([lk.upper for lk in self.links])

    @property
    def names(self) -> tuple[str, ...]:
        """Joint names, base outwards."""
        return tuple(lk.name for lk in self.links)


def link_transform(link: DHLink, q: float) -> FloatArray:
    """Modified-DH transform of one link at joint value ``q``.

    Parameters
    ----------
    link : DHLink
        The link.
    q : float
        Joint value, rad (revolute) or m (prismatic).

    Returns
    -------
    T_prev_link : (4, 4) ndarray
        Pose of the link frame in the previous link's frame, m.
    """
    if link.joint_type is JointType.REVOLUTE:
        theta, d = q + link.offset, link.D
    else:
        theta, d = link.theta, q + link.offset
    ca, sa = math.cos(link.alpha), math.sin(link.alpha)
    ct, st = math.cos(theta), math.sin(theta)
    return np.array(
        [
            [ct, -st, 0.0, link.A],
            [ca * st, ca * ct, -sa, -sa * d],
            [sa * st, sa * ct, ca, ca * d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def chain_frames(chain: DHChain, q: FloatArray) -> FloatArray:
    """Poses of every link frame and of the tool tip, unchecked input.

    Parameters
    ----------
    chain : DHChain
        The chain with ``n`` links.
    q : (n,) ndarray
        Joint values, rad or m. Not validated (callers validate at the boundary).

    Returns
    -------
    T_base_frames : (n + 1, 4, 4) ndarray
        ``[T_base_1, ..., T_base_n, T_base_tip]``, m.
    """
    n = chain.n_joints
    out = np.empty((n + 1, 4, 4))
    T = np.eye(4)
    for i, link in enumerate(chain.links):
        T = T @ link_transform(link, float(q[i]))
        out[i] = T
    out[n] = T @ chain.T_last_tip
    return out


def compose_links(
    chain: DHChain, q: list[float], start: int = 0, stop: int | None = None, T0: Pose12 = IDENTITY12
) -> Pose12:
    """Product ``T0 · T_start · … · T_(stop-1)`` of link transforms, in plain floats.

    The fast path of forward kinematics: the modified-DH product of repeated
    :func:`link_transform`, written column by column on floats and compiled
    (:func:`compose12`; about 6× cheaper per call than the same code in Python). Pinned to
    :func:`chain_frames`'s numpy product by a tolerance (``tests/test_robot_kinematics.py``).

    Parameters
    ----------
    chain : DHChain
        The chain.
    q : list of float
        Joint values for every link of the chain, rad / m.
    start, stop : int
        Range of links to compose (``stop`` defaults to all links).
    T0 : Pose12
        Pose to start from: rotation row-major then translation, m.

    Returns
    -------
    Pose12
        The composed pose, 12 floats (rotation row-major, then translation), m.
    """
    stop = len(chain._params) if stop is None else stop
    return compose12_kernel(chain._param_array, tuple(map(float, q)), start, stop, T0)


# register_jitable, not njit: a compiled caller's constant arguments (``c, 12``) are typed as
# plain ints then, one specialisation for all of them (an njit callee compiles one per literal)
@register_jitable
def flat_rows(c: FloatArray, i: int) -> tuple[tuple[float, ...], ...]:
    """Three rows of four floats stored flat from ``c[i]`` (a transform's top rows, m).

    Used by the PSM's and the ECM's compiled IK (their constants live in one flat array).
    """
    return (
        (c[i], c[i + 1], c[i + 2], c[i + 3]),
        (c[i + 4], c[i + 5], c[i + 6], c[i + 7]),
        (c[i + 8], c[i + 9], c[i + 10], c[i + 11]),
    )


@register_jitable  # compiled into its callers, one specialisation for constant start / stop
def compose12(
    params: FloatArray, q: tuple[float, ...] | FloatArray, start: int, stop: int, T0: Pose12
) -> Pose12:
    """``T0 · T_start · … · T_(stop-1)``: :func:`compose_links` for compiled callers.

    ``params``: the chain's (n, 7) :attr:`DHChain.param_array`; ``q``: the joint values (n,),
    a tuple or an array, rad / m; ``T0`` and the result: 12 floats (rotation row-major, then
    translation, m), in ``T0``'s frame.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = T0
    for i in range(start, stop):
        ca, sa, a_len = params[i, 0], params[i, 1], params[i, 2]
        d, theta, offset = params[i, 3], params[i, 4], params[i, 5]
        if params[i, _REVOLUTE_COLUMN] != 0.0:
            theta = q[i] + offset
        else:
            d = q[i] + offset
        c, s = math.cos(theta), math.sin(theta)
        e1, e2 = -sa * d, ca * d
        # translation: A · x + (-sa d) · y + (ca d) · z of the current frame
        px += a_len * r00 + e1 * r01 + e2 * r02
        py += a_len * r10 + e1 * r11 + e2 * r12
        pz += a_len * r20 + e1 * r21 + e2 * r22
        # RotX(alpha): y' = ca y + sa z, z' = -sa y + ca z; then RotZ(theta) on x, y'
        u0, u1, u2 = ca * r01 + sa * r02, ca * r11 + sa * r12, ca * r21 + sa * r22
        r02, r12, r22 = -sa * r01 + ca * r02, -sa * r11 + ca * r12, -sa * r21 + ca * r22
        r00, r01 = c * r00 + s * u0, -s * r00 + c * u0
        r10, r11 = c * r10 + s * u1, -s * r10 + c * u1
        r20, r21 = c * r20 + s * u2, -s * r20 + c * u2
    return (r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def compose12_kernel(
    params: FloatArray, q: tuple[float, ...], start: int, stop: int, T0: Pose12
) -> Pose12:
    """:func:`compose12` called from Python (:func:`compose_links`)."""
    return compose12(params, q, start, stop, T0)


def chain_points(
    chain: DHChain, q_rows: ArrayLike, T0: Pose12, point: tuple[float, float, float]
) -> FloatArray:
    """Where a point fixed to the last link goes, for many joint vectors at once.

    Row ``k`` is ``pose12_point(compose_links(chain, q_rows[k], T0=T0), rows)`` for ``rows``
    whose last column is ``point``, one compiled call for a whole path (e.g. a braking path's
    camera positions).

    Parameters
    ----------
    chain : DHChain
        The chain with ``n`` links.
    q_rows : (m, n) array_like
        Joint vectors, rad / m.
    T0 : Pose12
        Pose the chain starts from (rotation row-major, then translation), m.
    point : 3-tuple of float
        The point in the last link's frame, m.

    Returns
    -------
    (m, 3) ndarray
        The point in ``T0``'s frame for each row, m.
    """
    q = np.ascontiguousarray(q_rows, dtype=float).reshape(-1, len(chain._params))
    out = np.empty((q.shape[0], 3))
    points12(chain._param_array, q, T0, (point[0], point[1], point[2]), out)
    return out


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def points12(
    params: FloatArray,
    q_rows: FloatArray,
    T0: Pose12,
    point: tuple[float, float, float],
    out: FloatArray,
) -> None:
    """:func:`chain_points` for compiled callers, into ``out`` (m, 3): in ``T0``'s frame, m.

    ``params``: the chain's (n, 7) :attr:`DHChain.param_array`; ``q_rows`` (m, n): joint
    vectors, rad / m; ``T0``: 12 floats, m; ``point``: in the last link's frame, m.
    """
    a3, b3, c3 = point
    for k in range(q_rows.shape[0]):
        r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = compose12(
            params, q_rows[k], 0, params.shape[0], T0
        )
        out[k, 0] = r00 * a3 + r01 * b3 + r02 * c3 + px
        out[k, 1] = r10 * a3 + r11 * b3 + r12 * c3 + py
        out[k, 2] = r20 * a3 + r21 * b3 + r22 * c3 + pz


def pose12_from_matrix(T: FloatArray) -> Pose12:
    """The 12-float form of a (4, 4) pose (rotation row-major, then translation), m."""
    (r00, r01, r02, px), (r10, r11, r12, py), (r20, r21, r22, pz), _ = T.tolist()
    return (r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz)


@register_jitable  # also callable from compiled kernels (the same source)
def pose12_times(T: Pose12, rows: tuple[tuple[float, ...], ...]) -> Pose12:
    """Product ``T · B`` of a 12-float pose and a transform ``B`` given by its top 3 rows.

    Parameters
    ----------
    T : Pose12
        Rotation row-major, then translation, m.
    rows : tuple of 3 rows of 4 floats
        Top three rows of ``B`` (e.g. the tool-tip offset or a camera mount), m.

    Returns
    -------
    Pose12
        ``T · B``, m.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = T
    (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3) = rows
    return (
        r00 * a0 + r01 * b0 + r02 * c0,
        r00 * a1 + r01 * b1 + r02 * c1,
        r00 * a2 + r01 * b2 + r02 * c2,
        r10 * a0 + r11 * b0 + r12 * c0,
        r10 * a1 + r11 * b1 + r12 * c1,
        r10 * a2 + r11 * b2 + r12 * c2,
        r20 * a0 + r21 * b0 + r22 * c0,
        r20 * a1 + r21 * b1 + r22 * c1,
        r20 * a2 + r21 * b2 + r22 * c2,
        r00 * a3 + r01 * b3 + r02 * c3 + px,
        r10 * a3 + r11 * b3 + r12 * c3 + py,
        r20 * a3 + r21 * b3 + r22 * c3 + pz,
    )


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def pose12_between(pre: Pose12, T: FloatArray, post: tuple[tuple[float, ...], ...]) -> Pose12:
    """``pre · T · post`` as 12 floats (rotation row-major, then translation), m.

    ``T`` (4, 4): a pose, m; ``pre``: 12 floats; ``post``: the top 3 rows of a transform:
    ``pose12_times(pose12_times(pre, T's top rows), post)`` in one compiled call (e.g. a
    camera goal in world to its tool-tip goal in the RCM frame).
    """
    rows = (
        (T[0, 0], T[0, 1], T[0, 2], T[0, 3]),
        (T[1, 0], T[1, 1], T[1, 2], T[1, 3]),
        (T[2, 0], T[2, 1], T[2, 2], T[2, 3]),
    )
    return pose12_times(pose12_times(pre, rows), post)


def pose12_point(T: Pose12, rows: tuple[tuple[float, ...], ...]) -> list[float]:
    """Translation of ``T · B`` alone (3 floats, m): :func:`pose12_times`'s last three values.

    Without the rotation (for checks that only need where a point is, e.g. the camera on a
    braking path).
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = T
    (_, _, _, a3), (_, _, _, b3), (_, _, _, c3) = rows
    return [
        r00 * a3 + r01 * b3 + r02 * c3 + px,
        r10 * a3 + r11 * b3 + r12 * c3 + py,
        r20 * a3 + r21 * b3 + r22 * c3 + pz,
    ]


def pose12_to_matrix(T: Pose12, tip: tuple[tuple[float, ...], ...] | None = None) -> FloatArray:
    """Convert a 12-float pose to a (4, 4) matrix, optionally right-multiplied by ``tip``.

    Parameters
    ----------
    T : Pose12
        Rotation row-major, then translation, m.
    tip : tuple of 3 rows of 4 floats, optional
        Top three rows of a transform to append (e.g. the tool-tip offset).

    Returns
    -------
    (4, 4) ndarray
        The pose, m.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = T
    if tip is None:
        return np.array(
            [[r00, r01, r02, px], [r10, r11, r12, py], [r20, r21, r22, pz], [0.0, 0.0, 0.0, 1.0]]
        )
    (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3) = tip
    return np.array(
        [
            [
                r00 * a0 + r01 * b0 + r02 * c0,
                r00 * a1 + r01 * b1 + r02 * c1,
                r00 * a2 + r01 * b2 + r02 * c2,
                r00 * a3 + r01 * b3 + r02 * c3 + px,
            ],
            [
                r10 * a0 + r11 * b0 + r12 * c0,
                r10 * a1 + r11 * b1 + r12 * c1,
                r10 * a2 + r11 * b2 + r12 * c2,
                r10 * a3 + r11 * b3 + r12 * c3 + py,
            ],
            [
                r20 * a0 + r21 * b0 + r22 * c0,
                r20 * a1 + r21 * b1 + r22 * c1,
                r20 * a2 + r21 * b2 + r22 * c2,
                r20 * a3 + r21 * b3 + r22 * c3 + pz,
            ],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def chain_forward(chain: DHChain, q: FloatArray) -> FloatArray:
    """Forward kinematics: the tool-tip pose, unchecked input.

    Parameters
    ----------
    chain : DHChain
        The chain with ``n`` links.
    q : (n,) ndarray
        Joint values, rad or m.

    Returns
    -------
    T_base_tip : (4, 4) ndarray
        Tool-tip pose in the base frame, m.
    """
    return pose12_to_matrix(compose_links(chain, q.tolist()), chain._tip_rows)


def geometric_jacobian(chain: DHChain, q: FloatArray) -> FloatArray:
    """Geometric Jacobian of the tool tip in the base frame, unchecked input.

    Rows ``0:3`` are the linear velocity of the tip origin (m/s per joint unit/s), rows
    ``3:6`` the angular velocity (rad/s per joint unit/s), both expressed in the base frame.
    In modified DH, joint ``i`` moves about / along the z axis of link frame ``i``. Compiled
    (:func:`jacobian_into`).

    Parameters
    ----------
    chain : DHChain
        The chain with ``n`` links.
    q : (n,) ndarray
        Joint values, rad or m.

    Returns
    -------
    J : (6, n) ndarray
        ``[v; ω] = J @ qd``.
    """
    J = np.empty((6, chain.n_joints))
    jacobian_into(chain._param_array, chain.T_last_tip, q, J)
    return J


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def jacobian_into(params: FloatArray, T_last_tip: FloatArray, q: FloatArray, J: FloatArray) -> None:
    """The geometric Jacobian (6, n) of the chain's tip at ``q`` (n,), into ``J``.

    ``params``: the chain's (n, 7) parameter array (``DHChain._param_array``); ``T_last_tip``
    (4, 4), m. The link frames as :func:`chain_frames` (``T @ link_transform(...)`` from the
    identity), the tip ``T_n @ T_last_tip``, and ``z_i × (p_tip − o_i)`` for a revolute joint.
    """
    n = params.shape[0]
    frames = np.empty((n, 4, 4))
    T = np.eye(4)
    L = np.zeros((4, 4))
    L[3, 3] = 1.0
    for i in range(n):
        ca, sa, a_len = params[i, 0], params[i, 1], params[i, 2]
        d, theta = params[i, 3], params[i, 4]
        if params[i, _REVOLUTE_COLUMN] != 0.0:
            theta = q[i] + params[i, 5]
        else:
            d = q[i] + params[i, 5]
        ct, st = math.cos(theta), math.sin(theta)
        L[0, 0], L[0, 1], L[0, 3] = ct, -st, a_len
        L[1, 0], L[1, 1], L[1, 2], L[1, 3] = ca * st, ca * ct, -sa, -sa * d
        L[2, 0], L[2, 1], L[2, 2], L[2, 3] = sa * st, sa * ct, ca, ca * d
        matmul4_into(T, L, frames[i])
        T = frames[i]
    tip = np.empty((4, 4))
    matmul4_into(T, T_last_tip, tip)
    p0, p1, p2 = tip[0, 3], tip[1, 3], tip[2, 3]
    for i in range(n):
        z0, z1, z2 = frames[i, 0, 2], frames[i, 1, 2], frames[i, 2, 2]
        if params[i, _REVOLUTE_COLUMN] != 0.0:
            b0, b1, b2 = p0 - frames[i, 0, 3], p1 - frames[i, 1, 3], p2 - frames[i, 2, 3]
            J[0, i] = z1 * b2 - z2 * b1
            J[1, i] = z2 * b0 - z0 * b2
            J[2, i] = z0 * b1 - z1 * b0
            J[3, i], J[4, i], J[5, i] = z0, z1, z2
        else:
            J[0, i], J[1, i], J[2, i] = z0, z1, z2
            J[3, i], J[4, i], J[5, i] = 0.0, 0.0, 0.0
