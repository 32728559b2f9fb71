"""The plain-float kernels against the checked numpy API (scipy's Rotation), over random inputs.

The kernel rule (docs/conventions.md): every hot-path float kernel has a numpy counterpart in
``endocam.geometry`` or ``endocam.camera``, and these property tests pin the two together.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from endocam import geometry, kernels
from endocam.camera import StereoCamera, inside_image
from endocam.control.windows import ImageWindows, WindowGeometry, WindowStatus, window_status_rows
from endocam.view import look_at_pose, look_at_unchecked

ATOL_RAD = 1e-9  # rad: float round-off on angles of order 1, far below any real error
ATOL_UNIT = 1e-12  # unitless: rotation-matrix entries and unit vectors
ATOL_M = 1e-12  # m: positions of order 0.1 m
EDGE_PX = 1e-6  # px: tips closer than this to a window edge are skipped (either answer is fine)

finite = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
vectors = st.tuples(finite, finite, finite)
rotvecs = st.tuples(finite, finite, finite).filter(lambda v: math.hypot(*v) < math.pi - 1e-6)
seeds = st.integers(0, 2**31 - 1)


def _rotation(seed: int) -> np.ndarray:
    return Rotation.random(random_state=np.random.default_rng(seed).integers(1 << 30)).as_matrix()


@settings(max_examples=300, deadline=None)
@given(rotvecs)
@example((0.0, 0.0, 0.0))
@example((1e-12, 0.0, 0.0))
@example((0.0, 0.0, math.pi - 1e-6))
def test_so3_log_and_exp_match_geometry(theta: tuple[float, float, float]) -> None:
    R = geometry.so3_exp(np.array(theta))
    np.testing.assert_allclose(kernels.so3_exp(list(theta)), R, atol=ATOL_UNIT)
    np.testing.assert_allclose(kernels.so3_log(R.tolist()), geometry.so3_log(R), atol=ATOL_RAD)


def test_so3_log_at_pi_is_either_sign() -> None:
    for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.6, 0.8])):
        R = geometry.so3_exp(math.pi * axis)
        got = np.array(kernels.so3_log(R.tolist()))
        err = min(np.linalg.norm(got - math.pi * axis), np.linalg.norm(got + math.pi * axis))
        assert err < ATOL_RAD


@settings(max_examples=200, deadline=None)
@given(seeds, seeds)
def test_rotation_angle_and_products_match_numpy(a: int, b: int) -> None:
    A, B = _rotation(a), _rotation(b)
    got = kernels.rotation_angle(A.tolist(), B.tolist())
    assert math.isclose(got, geometry.rotation_angle(A, B), abs_tol=ATOL_RAD)
    np.testing.assert_allclose(kernels.matmul(A.tolist(), B.tolist()), A @ B, atol=ATOL_UNIT)
    np.testing.assert_allclose(kernels.tmatmul(A.tolist(), B.tolist()), A.T @ B, atol=ATOL_UNIT)


@settings(max_examples=200, deadline=None)
@given(vectors, vectors)
def test_vector_kernels_match_numpy(a: tuple[float, ...], b: tuple[float, ...]) -> None:
    u, v = np.array(a), np.array(b)
    np.testing.assert_allclose(kernels.cross(a, b), np.cross(u, v), atol=ATOL_UNIT * 10)  # type: ignore[arg-type]
    assert math.isclose(kernels.dot(a, b), float(u @ v), abs_tol=ATOL_UNIT * 10)  # type: ignore[arg-type]
    assert math.isclose(kernels.norm(a), float(np.linalg.norm(u)), abs_tol=ATOL_UNIT)  # type: ignore[arg-type]


def test_finite_rows_rejects_what_is_not_a_finite_pose() -> None:
    assert kernels.finite_rows(np.eye(4)) == np.eye(4).tolist()
    bad = np.eye(4)
    bad[1, 2] = math.nan
    assert kernels.finite_rows(bad) is None
    assert kernels.finite_rows(None) is None
    assert kernels.finite_rows(np.eye(3)) is None


@settings(max_examples=200, deadline=None)
@given(vectors, vectors)
def test_look_at_kernel_matches_the_numpy_formula(
    p: tuple[float, ...], q: tuple[float, ...]
) -> None:
    """Away from the vertical, the look-at is z = (q − p)/|q − p|, x = z × up normalised."""
    p_cam, target = np.array(p), np.array(q)
    d = target - p_cam
    if np.linalg.norm(d) < 1e-3:
        return
    z = d / np.linalg.norm(d)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < math.sin(math.radians(25.0)):  # the roll-blend zone: no closed form
        return
    x /= np.linalg.norm(x)
    expected = np.eye(4)
    expected[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    expected[:3, 3] = p_cam
    np.testing.assert_allclose(
        look_at_unchecked(p_cam, target, np.eye(4), None), expected, atol=1e-9
    )
    np.testing.assert_allclose(look_at_pose(p_cam, target), expected, atol=1e-9)


CAMERA = StereoCamera()
WINDOWS = ImageWindows()


def _expected_status(T: np.ndarray, tips: np.ndarray) -> WindowStatus | None:
    """The window rule from StereoCamera.project in both eyes (None: a tip on an edge)."""
    k = CAMERA.intrinsics
    half = np.array([k.width, k.height]) / 2.0
    all_inner = True
    for eye in ("left", "right"):
        uv = CAMERA.project(T, tips, eye)
        if not np.all(np.isfinite(uv)):
            return WindowStatus.OUTSIDE_OUTER
        off = np.abs(uv - half)
        for frac, inner in ((WINDOWS.outer_frac, False), (WINDOWS.inner_frac, True)):
            edge = np.abs(off - frac * half)
            if np.any(edge < EDGE_PX):
                return None
            inside = np.all(off <= frac * half, axis=1)
            if not inner and not np.all(inside):
                return WindowStatus.OUTSIDE_OUTER
            if inner and not np.all(inside):
                all_inner = False
    return WindowStatus.INSIDE_INNER if all_inner else WindowStatus.BETWEEN


@settings(max_examples=300, deadline=None)
@given(seeds)
def test_window_kernel_agrees_with_stereo_projection(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = _rotation(seed)
    T[:3, 3] = rng.uniform(-0.05, 0.05, 3)
    # tips ahead of the camera, spread across and beyond the image
    depth = rng.uniform(-0.01, 0.12, 2)
    lateral = rng.uniform(-0.08, 0.08, (2, 2))
    p_cam = np.column_stack([lateral, depth])
    tips = p_cam @ T[:3, :3].T + T[:3, 3]
    expected = _expected_status(T, tips)
    if expected is None:
        return
    got = window_status_rows(WindowGeometry.of(CAMERA, WINDOWS), T.tolist(), tips.tolist())
    assert got is expected


def test_image_edge_rule_is_half_open() -> None:
    k = CAMERA.intrinsics
    u = np.array([0.0, k.width - 1e-9, k.width, -1e-9, math.nan])
    v = np.full(5, 1.0)
    np.testing.assert_array_equal(inside_image(k, u, v), [True, True, False, False, False])


# The small array kernels of compiled code (endocam.kernels), compiled here as the kernels that
# inline them are, against numpy and math.
ATOL_PRODUCT = 1e-12  # unitless: entries of products of order-1 matrices (a few ulp of 10)


def _products(
    a: np.ndarray, b: np.ndarray, A: np.ndarray, B: np.ndarray, M: np.ndarray
) -> tuple[float, float, tuple[float, float, float], np.ndarray, np.ndarray]:
    out4 = np.empty((4, 4))
    kernels.matmul4_into(A, B, out4)
    out3 = np.empty((3, M.shape[1]))
    kernels.tmatmul3_into(A, M, out3)
    return (
        kernels.dot3(a[0], a[1], a[2], b[0], b[1], b[2]),
        kernels.dist3(a[0], a[1], a[2], b[0], b[1], b[2]),
        kernels.matvec3(A, b),
        out4,
        out3,
    )


def _wrap(angle: float) -> float:
    return kernels.wrap_angle(angle)


@functools.cache
def _compiled(fn: Callable[..., object]) -> Callable[..., object]:
    """``fn`` compiled as the kernels that inline the small kernels are (not cached on disk).

    numba is imported here, after endocam: importing endocam first points numba's cache at
    endocam's folder (endocam._numba_cache).
    """
    from numba import njit

    return njit(cache=False)(fn)


@settings(max_examples=200, deadline=None)
@given(seeds)
def test_array_kernels_match_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    scale = 10.0 ** float(rng.integers(-3, 2))  # m: from millimetres to tens of metres
    a, b = rng.normal(size=3) * scale, rng.normal(size=3) * scale
    A, B = rng.normal(size=(4, 4)), rng.normal(size=(4, 4))
    M = rng.normal(size=(3, int(rng.integers(1, 6))))
    tol = ATOL_PRODUCT * scale * scale  # m²: a product of two lengths
    tol_m = ATOL_PRODUCT * scale  # m: a distance, a rotated vector
    for form in ("python", "compiled"):
        if form == "python":
            d = kernels.dot3(*a, *b)
            r = kernels.dist3(*a, *b)
            v = kernels.matvec3(A, b)
            out4, out3 = np.empty((4, 4)), np.empty((3, M.shape[1]))
            kernels.matmul4_into(A, B, out4)
            kernels.tmatmul3_into(A, M, out3)
        else:
            d, r, v, out4, out3 = _compiled(_products)(a, b, A, B, M)  # type: ignore[misc]
        assert math.isclose(d, float(a @ b), rel_tol=0.0, abs_tol=tol)
        assert math.isclose(r, math.dist(a, b), rel_tol=0.0, abs_tol=tol_m)
        assert math.isclose(r, float(np.linalg.norm(a - b)), rel_tol=0.0, abs_tol=tol_m)
        np.testing.assert_allclose(v, A[:3, :3] @ b, rtol=0.0, atol=tol_m)
        np.testing.assert_allclose(out4, A @ B, rtol=0.0, atol=ATOL_PRODUCT)
        np.testing.assert_allclose(out3, A[:3, :3].T @ M, rtol=0.0, atol=ATOL_PRODUCT)


WRAP_ATOL_RAD = 1e-12  # rad: round-off of angle − 2π k for |angle| up to ~100 rad


@settings(max_examples=300, deadline=None)
@given(st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False))
@example(math.pi)
@example(-math.pi)
@example(3 * math.pi)
@example(0.0)
def test_wrap_angle_is_math_remainder(angle: float) -> None:
    want = math.remainder(angle, 2.0 * math.pi)
    for got in (kernels.wrap_angle(angle), _compiled(_wrap)(angle)):
        assert -math.pi - WRAP_ATOL_RAD <= got <= math.pi + WRAP_ATOL_RAD
        if abs(abs(want) - math.pi) < 1e-9:  # a tie at ±π: either end is the same angle
            assert math.isclose(abs(got), math.pi, abs_tol=WRAP_ATOL_RAD)
        else:
            assert math.isclose(got, want, rel_tol=0.0, abs_tol=WRAP_ATOL_RAD)
        # the same direction as the angle it wraps
        assert math.isclose(math.cos(got), math.cos(angle), abs_tol=WRAP_ATOL_RAD)
        assert math.isclose(math.sin(got), math.sin(angle), abs_tol=WRAP_ATOL_RAD)


def test_the_kernel_boundary_gives_one_numba_type_for_read_only_and_writable_arrays() -> None:
    """A read-only pose or tips array reaches the compiled steps as the writable type.

    numba compiles a kernel once per argument type; a read-only array is another type, so
    without the boundary a policy given a read-only observation compiles its step twice.
    """
    from numba import typeof

    from endocam.control.checks import pose_array, tips_array

    rng = np.random.default_rng(3)
    T = rng.normal(size=(4, 4))
    tips = rng.normal(size=(2, 3))
    for convert, a in ((pose_array, T), (tips_array, tips), (kernels.kernel_array, T)):
        frozen = a.copy()
        frozen.setflags(write=False)
        assert typeof(convert(frozen)) == typeof(convert(a.copy()))
        np.testing.assert_array_equal(convert(frozen), a)
        writable = a.copy()
        assert convert(writable) is writable  # no copy on the hot path
    assert typeof(tips_array(np.zeros((0, 3)).T.T)) == typeof(tips_array(tips))
    assert typeof(pose_array(np.asfortranarray(T))) == typeof(pose_array(T))
