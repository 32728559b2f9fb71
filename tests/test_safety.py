"""Cone workspace, tool-in-view windows (paper Sec. III-C) and the observation gate's state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam import StereoCamera, look_at_pose
from endocam.control.gate import GATE_STATE, RingGate, RingLimits
from endocam.control.windows import (
    D_F_STEP,
    ImageWindows,
    WindowStatus,
    adjust_working_distance,
    window_status,
)
from endocam.geometry import transform_points
from endocam.workspace.cone import ConeWorkspace

ATOL_M = 1e-12  # m, round-off at 0.1 m scale
N_PATHS = 2000  # count: random point sequences checked, path check vs scalar margins
PX_EPS = 1e-3  # px, how far past a window edge a test tip is placed

CAM = StereoCamera()
WINDOWS = ImageWindows(inner_frac=0.5, outer_frac=0.9)


def _cone() -> ConeWorkspace:
    return ConeWorkspace.from_rcm([0.0, 0.0, 0.3], [0.0, 0.0, 0.0], height=0.25, base_radius=0.1)


def test_cone_axis_is_fixed_towards_initial_feature() -> None:
    cone = _cone()
    np.testing.assert_allclose(cone.axis, [0, 0, -1])
    np.testing.assert_allclose(cone.apex, [0, 0, 0.3])


def test_cone_inside_outside() -> None:
    cone = _cone()
    assert cone.contains(np.array([0.0, 0.0, 0.2]))  # on the axis
    assert not cone.contains(np.array([0.0, 0.0, 0.31]))  # behind the tip
    assert not cone.contains(np.array([0.0, 0.0, 0.04]))  # past the base (0.25 below the tip)
    assert not cone.contains(np.array([0.09, 0.0, 0.1]))  # outside laterally at h = 0.2
    assert not cone.contains(np.array([np.nan, 0.0, 0.2]))


def test_cone_surface_has_zero_margin() -> None:
    cone = _cone()
    rng = np.random.default_rng(5)
    for _ in range(100):
        h = rng.uniform(0.01, 0.25)
        phi = rng.uniform(0, 2 * math.pi)
        r = h * 0.1 / 0.25  # radius of the lateral surface at depth h
        p = np.array([r * math.cos(phi), r * math.sin(phi), 0.3 - h])
        assert cone.margin(p) == pytest.approx(0.0, abs=1e-12)
        inward = p + np.array([0, 0, -1e-6])  # deeper along the axis: strictly inside
        assert cone.margin(inward) > 0


def test_cone_margin_is_distance_to_lateral_surface() -> None:
    cone = _cone()
    # At depth h the surface radius is 0.4 h; a point on the axis is 0.4 h cos(α) from it.
    h = 0.1
    alpha = math.atan(0.1 / 0.25)
    assert cone.margin(np.array([0.0, 0.0, 0.3 - h])) == pytest.approx(
        min(0.4 * h * math.cos(alpha), 0.25 - h, h), abs=ATOL_M
    )


def test_cone_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="height"):
        ConeWorkspace.from_rcm([0, 0, 0.3], [0, 0, 0], height=0.0)
    with pytest.raises(ValueError, match="feature - rcm"):
        ConeWorkspace.from_rcm([0, 0, 0.3], [0, 0, 0.3], height=0.2)


def _tip_at_pixel(T_world_cam: np.ndarray, u: float, v: float, depth: float) -> np.ndarray:
    """World point seen by the camera centre at pixel (u, v) (the stereo eyes shift it)."""
    K = CAM.intrinsics
    p_cam = np.array([(u - K.cx) / K.fx * depth, (v - K.cy) / K.fy * depth, depth])
    return transform_points(T_world_cam, p_cam)


def _window_edge_u(frac: float) -> float:
    return 0.5 * CAM.intrinsics.width * (1 + frac)


def test_window_logic_at_edges() -> None:
    T = look_at_pose([0.0, -0.1, 0.1], [0.0, 0.0, 0.0])
    depth = 0.1
    half_b_px = CAM.intrinsics.fx * 0.5 * CAM.baseline / depth  # stereo shift of each eye, px
    cy = CAM.intrinsics.cy
    centre = _tip_at_pixel(T, CAM.intrinsics.cx, cy, depth)
    assert window_status(CAM, T, centre[None], WINDOWS) is WindowStatus.INSIDE_INNER
    # Just inside the outer edge in the eye that sees it farthest out: between the windows.
    u_out = _window_edge_u(0.9) - half_b_px - PX_EPS
    tip = _tip_at_pixel(T, u_out, cy, depth)
    assert window_status(CAM, T, np.stack([centre, tip]), WINDOWS) is WindowStatus.BETWEEN
    # Just past it: outside.
    tip = _tip_at_pixel(T, u_out + 2 * PX_EPS, cy, depth)
    assert window_status(CAM, T, np.stack([centre, tip]), WINDOWS) is WindowStatus.OUTSIDE_OUTER
    # Inner edge: just inside → inside inner; just past → between.
    u_in = _window_edge_u(0.5) - half_b_px
    tip = _tip_at_pixel(T, u_in - PX_EPS, cy, depth)
    assert window_status(CAM, T, tip[None], WINDOWS) is WindowStatus.INSIDE_INNER
    tip = _tip_at_pixel(T, u_in + PX_EPS, cy, depth)
    assert window_status(CAM, T, tip[None], WINDOWS) is WindowStatus.BETWEEN


def test_tip_behind_camera_is_outside_and_nan_tip_ignored() -> None:
    T = look_at_pose([0.0, -0.1, 0.1], [0.0, 0.0, 0.0])
    behind = transform_points(T, np.array([0.0, 0.0, -0.05]))
    assert window_status(CAM, T, behind[None], WINDOWS) is WindowStatus.OUTSIDE_OUTER
    centre = _tip_at_pixel(T, CAM.intrinsics.cx, CAM.intrinsics.cy, 0.1)
    tips = np.stack([centre, [np.nan, 0.0, 0.0]])
    assert window_status(CAM, T, tips, WINDOWS) is WindowStatus.INSIDE_INNER


def test_working_distance_steps_and_clamps() -> None:
    d = 0.05
    assert adjust_working_distance(d, WindowStatus.OUTSIDE_OUTER, 0.03, 0.12) == pytest.approx(
        d + D_F_STEP
    )
    assert adjust_working_distance(d, WindowStatus.INSIDE_INNER, 0.03, 0.12) == pytest.approx(
        d - D_F_STEP
    )
    assert adjust_working_distance(d, WindowStatus.BETWEEN, 0.03, 0.12) == d
    assert adjust_working_distance(0.12, WindowStatus.OUTSIDE_OUTER, 0.03, 0.12) == 0.12
    assert adjust_working_distance(0.03, WindowStatus.INSIDE_INNER, 0.03, 0.12) == 0.03
    assert D_F_STEP == pytest.approx(1e-3)  # the paper's ±1 mm


def test_windows_validate() -> None:
    with pytest.raises(ValueError, match="inner_frac"):
        ImageWindows(0.9, 0.5)


def test_no_usable_tip_holds() -> None:
    T = look_at_pose([0.0, -0.1, 0.1], [0.0, 0.0, 0.0])
    assert window_status(CAM, T, np.zeros((0, 3)), WINDOWS) is WindowStatus.BETWEEN
    assert window_status(CAM, T, np.full((2, 3), np.nan), WINDOWS) is WindowStatus.BETWEEN


def _first_outside_scalar(cone: ConeWorkspace, path: np.ndarray, floor: float) -> int:
    """The scalar margins in turn (``ConeWorkspace.margin``, the floor), as ``Workspace.margin``."""
    for i, p in enumerate(path.tolist()):
        if not min(cone.margin(p), p[2] - floor) >= 0.0:
            return i
    return len(path)


def test_cone_first_outside_is_the_scalar_decision() -> None:
    """The compiled path check finds the scalar margins' first point outside, every time.

    Points near the cone's lateral surface, its base, its tip and the floor (some exactly on
    the floor), and non-finite ones.
    """
    cone = _cone()
    floor = 0.08  # m
    rng = np.random.default_rng(11)
    apex, axis = np.asarray(cone.apex), np.asarray(cone.axis)
    for _ in range(N_PATHS):
        n = int(rng.integers(1, 30))
        h = rng.uniform(-0.01, 0.26, n)
        r = h * cone.base_radius / cone.height * rng.uniform(0.9, 1.02, n)
        phi = rng.uniform(0.0, 2.0 * math.pi, n)
        path = apex + h[:, None] * axis
        path[:, 0] += r * np.cos(phi)
        path[:, 1] += r * np.sin(phi)
        path[rng.random(n) < 0.1, 2] = floor
        path[rng.random(n) < 0.02, int(rng.integers(0, 3))] = rng.choice([math.nan, math.inf])
        expected = _first_outside_scalar(cone, path, floor)
        assert cone.first_outside(path, floor) == expected
    assert cone.first_outside(np.zeros((0, 3))) == 0


def test_the_gate_remembers_by_name_and_forgets_at_reset() -> None:
    """``RingGate.state``'s named fields: the accepted and the last seen pose, the rejections."""
    gate = RingGate(RingLimits(0.1, 1.0, 1.0, 10.0, 0.005, 0.05, 0.5, 1.0, 0.009, 0.12, 0.03))
    up = (0.0, 0.0, 1.0)
    assert gate.accept(0.0, (0.0, 0.0, 0.05), up)
    assert not gate.accept(0.01, (0.5, 0.0, 0.05), up)  # 50 m/s: refused
    state = gate.state[0]
    assert state["accepted"]["held"] and state["accepted"]["t"] == 0.0
    np.testing.assert_array_equal(state["accepted"]["centre"], [0.0, 0.0, 0.05])
    np.testing.assert_array_equal(state["seen"]["centre"], [0.5, 0.0, 0.05])
    np.testing.assert_array_equal(state["seen"]["normal"], up)
    assert state["seen"]["t"] == 0.01 and gate.rejected == 1
    gate.reset()
    assert gate.state.dtype == GATE_STATE and gate.rejected == 0
    assert not gate.state[0]["accepted"]["held"] and not gate.state[0]["seen"]["held"]
    assert gate.accept(5.0, (0.5, 0.0, 0.05), up)  # nothing to compare with: accepted
