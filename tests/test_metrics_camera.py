"""Tracking metrics on hand-computed cases, and the pinhole stereo camera."""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam import (
    Intrinsics,
    StereoCamera,
    center_error_3d,
    image_centering_error,
    orientation_error,
)
from endocam.geometry import make_pose
from endocam.metrics import summarize

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

ATOL_M = 1e-12  # m
ATOL_PX = 1e-9  # px
ATOL_RAD = 1e-12  # rad

CAM = StereoCamera(Intrinsics.from_fovy(640, 480, math.radians(60.0)), baseline=0.005)
IDENTITY = np.eye(4)  # camera at the origin looking along +z (world = optical frame)


def test_center_error_is_distance_to_optical_axis() -> None:
    p = np.array([[0.01, 0.0, 0.1], [0.003, -0.004, 0.2], [0.0, 0.0, 0.5]])
    np.testing.assert_allclose(
        center_error_3d(np.stack([IDENTITY] * 3), p), [0.01, 0.005, 0.0], atol=ATOL_M
    )


def test_image_error_uses_left_eye_principal_point() -> None:
    # Ring on the optical axis of the camera centre, 0.1 m ahead: the left eye (at x = −b/2)
    # sees it b/2 to the right, i.e. fx·(b/2)/z pixels from its principal point.
    fx = CAM.intrinsics.fx
    err = image_centering_error(CAM, IDENTITY, np.array([0.0, 0.0, 0.1]))
    assert err[0] == pytest.approx(fx * 0.0025 / 0.1, abs=ATOL_PX)
    # Ring on the left eye's own axis: zero.
    err = image_centering_error(CAM, IDENTITY, np.array([-0.0025, 0.0, 0.1]))
    assert err[0] == pytest.approx(0.0, abs=ATOL_PX)
    # 3-4-5 triangle in pixels.
    p = np.array([-0.0025 + 3 * 0.1 / fx, 4 * 0.1 / CAM.intrinsics.fy, 0.1])
    assert image_centering_error(CAM, IDENTITY, p)[0] == pytest.approx(5.0, abs=ATOL_PX)
    # Behind the camera: undefined.
    assert np.isnan(image_centering_error(CAM, IDENTITY, np.array([0.0, 0.0, -0.1]))[0])


def test_orientation_error_is_acute_angle() -> None:
    n = np.array(
        [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, math.sin(0.5), math.cos(0.5)], [1.0, 0.0, 0.0]]
    )
    got = orientation_error(np.stack([IDENTITY] * 4), n)
    np.testing.assert_allclose(got, [0.0, 0.0, 0.5, math.pi / 2], atol=ATOL_RAD)


def test_metrics_follow_camera_pose() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        R *= np.sign(np.linalg.det(R))
        T = make_pose(R, rng.uniform(-0.1, 0.1, 3))
        p = T[:3, 3] + 0.08 * R[:, 2]  # on the axis, 8 cm ahead
        assert center_error_3d(T, p)[0] == pytest.approx(0.0, abs=1e-12)
        assert orientation_error(T, R[:, 2])[0] == pytest.approx(0.0, abs=1e-7)


def test_summarize_reports_units_and_undefined() -> None:
    s = summarize(np.array([0.001, 0.002, 0.003, np.nan]), scale=1e3)
    assert s["mean"] == pytest.approx(2.0)
    assert s["max"] == pytest.approx(3.0)
    assert s["p95"] == pytest.approx(np.percentile([1.0, 2.0, 3.0], 95))
    assert s["n"] == 3
    assert s["n_undefined"] == 1
    empty = summarize(np.array([np.nan]))
    assert math.isnan(empty["mean"])


def test_intrinsics_from_fovy_and_K_agree() -> None:
    intr = Intrinsics.from_fovy(640, 480, math.radians(60.0))
    assert intr.fy == pytest.approx(240.0 / math.tan(math.radians(30.0)))
    assert intr.fovy == pytest.approx(math.radians(60.0))
    again = Intrinsics.from_K(intr.K, 640, 480)
    assert again == intr
    with pytest.raises(ValueError, match="fovy"):
        Intrinsics.from_fovy(640, 480, 0.0)
    with pytest.raises(ValueError, match="K"):
        Intrinsics.from_K(np.ones((3, 3)), 640, 480)
    with pytest.raises(ValueError, match="image size"):
        Intrinsics(0, 480, 1.0, 1.0, 0.0, 0.0)


def test_stereo_eyes_and_projection() -> None:
    np.testing.assert_allclose(CAM.T_cam_left[:3, 3], [-0.0025, 0.0, 0.0])
    np.testing.assert_allclose(CAM.T_cam_right[:3, 3], [0.0025, 0.0, 0.0])
    p = np.array([[0.0, 0.0, 0.1]])
    uv_l = CAM.project(IDENTITY, p, "left")[0]
    uv_r = CAM.project(IDENTITY, p, "right")[0]
    disparity = uv_l[0] - uv_r[0]
    assert disparity == pytest.approx(CAM.intrinsics.fx * CAM.baseline / 0.1)
    assert uv_l[1] == pytest.approx(CAM.intrinsics.cy)
    with pytest.raises(ValueError, match="eye"):
        CAM.project(IDENTITY, p, "middle")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="baseline"):
        StereoCamera(baseline=-1.0)


def test_saturated_image_error_counts_a_lost_ring_as_the_worst_in_view_error() -> None:
    from endocam.metrics import image_error_bound, saturate_image_error

    k = CAM.intrinsics
    bound = image_error_bound(CAM)
    assert bound == pytest.approx(math.hypot(k.width / 2, k.height / 2), abs=ATOL_PX)
    raw = np.array([0.0, 12.5, bound - 1.0, bound + 1.0, 1e9, np.nan, np.inf])
    got = saturate_image_error(CAM, raw)
    np.testing.assert_array_equal(got, [0.0, 12.5, bound - 1.0, bound, bound, bound, bound])
    # a ring behind the camera: raw NaN, saturated to the bound
    behind = image_centering_error(CAM, IDENTITY, np.array([0.0, 0.0, -0.1]))
    assert saturate_image_error(CAM, behind)[0] == bound


def test_ring_out_of_view_is_outside_the_image_not_only_beyond_the_corner() -> None:
    from endocam.metrics import ring_out_of_view, saturate_image_error

    k = CAM.intrinsics
    depth = 0.1  # m
    x_left_eye = -0.5 * CAM.baseline  # the left eye sits half a baseline to the left

    def at_pixel(u: float, v: float) -> np.ndarray:
        return np.array([x_left_eye + (u - k.cx) * depth / k.fx, (v - k.cy) * depth / k.fy, depth])

    inside, beyond_edge = at_pixel(k.width - 10.0, k.cy), at_pixel(k.width + 10.0, k.cy)
    behind = np.array([0.0, 0.0, -0.1])
    out = [ring_out_of_view(CAM, IDENTITY, p)[0] for p in (inside, beyond_edge, behind)]
    assert out == [False, True, True]
    # just past the right edge the raw error (330 px) is below the corner bound (400 px),
    # but the saturated error counts the ring as lost
    raw = image_centering_error(CAM, IDENTITY, beyond_edge)
    assert raw[0] < image_error_bound_px()
    sat = saturate_image_error(CAM, raw, ring_out_of_view(CAM, IDENTITY, beyond_edge))
    assert sat[0] == image_error_bound_px()


def image_error_bound_px() -> float:
    from endocam.metrics import image_error_bound

    return image_error_bound(CAM)
