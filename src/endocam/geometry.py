"""Rigid-body geometry on numpy arrays: validation, homogeneous transforms and quaternions.

Conventions (``docs/conventions.md``): ``T_a_b`` is the (4, 4) pose of frame b in frame a;
quaternions are scalar-first (w, x, y, z); Tait–Bryan angles are ``R = Rx(α) Ry(β) Rz(γ)``.
Rotation algebra is delegated to :class:`scipy.spatial.transform.Rotation`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]

UP = np.array([0.0, 0.0, 1.0])  # world up, unitless direction
EPS_NORM = 1e-12  # below this a vector has no direction (unitless)


def as_finite_array(value: object, name: str, shape: tuple[int, ...]) -> FloatArray:
    """Return ``value`` as a finite float array of ``shape``, or raise ``ValueError`` naming it.

    Parameters
    ----------
    value : array_like
        Input values.
    name : str
        Argument name used in the error message.
    shape : tuple of int
        Required shape.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numbers of shape {shape}") from exc
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def as_vector3(value: ArrayLike, name: str) -> FloatArray:
    """Return ``value`` as a finite float (3,) array, or raise ``ValueError`` naming ``name``.

    Parameters
    ----------
    value : array_like, shape (3,)
        Any 3-vector.
    name : str
        Argument name used in the error message.
    """
    return as_finite_array(value, name, (3,))


def unit_vector(value: ArrayLike, name: str) -> FloatArray:
    """Return ``value`` normalised to unit length; zero, NaN or inf raise ``ValueError``.

    Parameters
    ----------
    value : array_like, shape (3,)
        Direction, any non-zero length.
    name : str
        Argument name used in the error message.
    """
    arr = as_vector3(value, name)
    norm = float(np.linalg.norm(arr))
    if norm < EPS_NORM:
        raise ValueError(f"{name} must be non-zero, got {arr.tolist()}")
    return arr / norm


ROTATION_ORTHO_TOL = 1e-6  # unitless: largest |R^T R − I| entry (and bottom-row offset) accepted


def as_pose(value: object, name: str) -> FloatArray:
    """Validate a homogeneous transform: the one pose checker of the package.

    Parameters
    ----------
    value : array_like, shape (4, 4)
        Candidate ``T_a_b``, m.
    name : str
        Argument name used in the error message.

    Returns
    -------
    (4, 4) ndarray
        ``value`` as float64.

    Raises
    ------
    ValueError
        Naming ``name``, unless ``value`` is a finite (4, 4) matrix whose bottom row is
        (0, 0, 0, 1) and whose upper-left block is a proper rotation, each within
        ``ROTATION_ORTHO_TOL``.
    """
    arr = as_finite_array(value, name, (4, 4))
    (a, b, c, _), (d, e, f, _), (g, h, i, _), bottom = arr.tolist()
    if (
        max(abs(bottom[0]), abs(bottom[1]), abs(bottom[2]), abs(bottom[3] - 1.0))
        > ROTATION_ORTHO_TOL
    ):
        raise ValueError(f"{name}: bottom row must be (0, 0, 0, 1)")
    gram = (
        a * a + d * d + g * g - 1.0,
        b * b + e * e + h * h - 1.0,
        c * c + f * f + i * i - 1.0,
        a * b + d * e + g * h,
        a * c + d * f + g * i,
        b * c + e * f + h * i,
    )
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if max(abs(x) for x in gram) > ROTATION_ORTHO_TOL or det < 0.0:
        raise ValueError(f"{name}: upper-left 3x3 block is not a rotation matrix")
    return arr


def make_pose(R: ArrayLike, p: ArrayLike) -> FloatArray:
    """Assemble ``T`` (4, 4) from a rotation ``R`` (3, 3) and a translation ``p`` (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def invert_pose(T_a_b: FloatArray) -> FloatArray:
    """Return ``T_b_a``, the inverse of a rigid transform ``T_a_b`` (4, 4)."""
    R = T_a_b[:3, :3]
    T = np.eye(4)
    T[:3, :3] = R.T
    T[:3, 3] = -R.T @ T_a_b[:3, 3]
    return T


def transform_points(T_a_b: FloatArray, p_b: FloatArray) -> FloatArray:
    """Map points from frame b to frame a: ``p_a = R p_b + t``; ``p_b`` is (N, 3) or (3,)."""
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def quat_wxyz_from_R(R: FloatArray) -> FloatArray:
    """Scalar-first unit quaternion (w, x, y, z) with w ≥ 0 from ``R`` (3, 3) or (N, 3, 3)."""
    q = Rotation.from_matrix(R).as_quat(canonical=True, scalar_first=True)
    return np.asarray(q, dtype=float)


def R_from_quat_wxyz(q: ArrayLike) -> FloatArray:
    """Rotation matrix (3, 3) or (N, 3, 3) from scalar-first quaternion(s) (w, x, y, z)."""
    return np.asarray(Rotation.from_quat(q, scalar_first=True).as_matrix(), dtype=float)


def R_from_euler_xyz(angles: ArrayLike) -> FloatArray:
    """Paper's Tait–Bryan ``R = Rx(α) Ry(β) Rz(γ)`` from (α, β, γ), rad, (3,) or (N, 3)."""
    return np.asarray(Rotation.from_euler("XYZ", angles).as_matrix(), dtype=float)


def euler_xyz_from_R(R: FloatArray) -> FloatArray:
    """Inverse of :func:`R_from_euler_xyz`: (α, β, γ) in rad from ``R`` (3, 3) or (N, 3, 3)."""
    return np.asarray(Rotation.from_matrix(R).as_euler("XYZ"), dtype=float)


def rotation_angle(R_a_b: FloatArray, R_a_c: FloatArray) -> float:
    """Angle (rad, in [0, π]) of the relative rotation between two orientations (3, 3)."""
    return float(Rotation.from_matrix(R_a_b.T @ R_a_c).magnitude())


def so3_log(R: FloatArray) -> FloatArray:
    """Rotation vector (3,) or (N, 3), rad, |θ| ≤ π, of rotation matrices (3, 3) or (N, 3, 3)."""
    return np.asarray(Rotation.from_matrix(R).as_rotvec(), dtype=float)


def so3_exp(theta: ArrayLike) -> FloatArray:
    """Rotation matrix (3, 3) or (N, 3, 3) of rotation vectors (3,) or (N, 3), rad."""
    return np.asarray(Rotation.from_rotvec(theta).as_matrix(), dtype=float)


def angle_between(u: FloatArray, v: FloatArray) -> float:
    """Angle (rad, in [0, π]) between two non-zero vectors (3,), robust near 0 and π."""
    return float(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v)))


def frame_with_z(n: FloatArray) -> FloatArray:
    """(3, 3) a rotation whose third column is the unit vector ``n`` (3,).

    Its first two columns span the plane normal to ``n`` (a circle about ``n``: ``cos φ x +
    sin φ y``); the rotation about ``n`` is arbitrary (the world axis least aligned with ``n``
    crossed with it).
    """
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, n)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(n, x), n])
