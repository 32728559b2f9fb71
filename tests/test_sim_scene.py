import math
from collections.abc import Iterator

import mujoco
import numpy as np
import pytest

from endocam.camera import Intrinsics, StereoCamera
from endocam.geometry import make_pose, transform_points
from endocam.sim.render import WireChaserScene
from endocam.sim.scene import (
    EYE_CAMERAS,
    GROUP_BOARD,
    GeomSpec,
    add_mocap_link,
    build_model,
    build_spec,
    check_ideal_camera,
    torus_mesh,
    tube_mesh,
)
from endocam.task.config import TaskConfig
from endocam.task.layout import overview_camera_pose, psm1_tip_in_ring
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

CFG = TaskConfig()
CAMERA = StereoCamera()
D_F = 0.06  # m, working distance of the test goal pose
CENTROID_TOL_PX = 4.0  # px, ring-pixel centroid vs. projected ring centre
ATOL_M = 1e-9  # m


@pytest.fixture(scope="module")
def scene() -> Iterator[WireChaserScene]:
    s = WireChaserScene(CFG, CAMERA)
    yield s
    s.close()


def ring_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the bright orange ring: strong red, mid green, little blue."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (r > 170) & (g > 60) & (g < r - 40) & (b < 90)


def goal_pose(T_world_ring: np.ndarray, d_f: float = D_F) -> np.ndarray:
    """Camera on the ring's normal at d_f, looking at the ring centre, horizon level."""
    n = T_world_ring[:3, 2] * (1.0 if T_world_ring[2, 2] >= 0 else -1.0)
    z = -n
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return make_pose(np.column_stack([x, np.cross(z, x), z]), T_world_ring[:3, 3] + d_f * n)


def test_model_lint_every_element_named_cameras_present() -> None:
    m = build_model(CFG, CAMERA)
    for kind, count in (("body", m.nbody), ("geom", m.ngeom), ("camera", m.ncam)):
        names = [getattr(m, kind)(i).name for i in range(count)]
        assert all(names[1 if kind == "body" else 0 :]), f"unnamed {kind}"
        assert len(set(names)) == len(names), f"duplicate {kind} names"
    assert all(m.light(i).name for i in range(m.nlight))
    assert all(m.site(i).name for i in range(m.nsite))
    cams = {m.camera(i).name for i in range(m.ncam)}
    assert set(EYE_CAMERAS) <= cams
    assert m.nmocap == 4 and m.nv == 0  # kinematic only (ring, psm2, camera, observer)
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    fovy = np.degrees(CAMERA.intrinsics.fovy)
    np.testing.assert_allclose(m.cam_fovy, fovy)
    assert m.vis.global_.offwidth >= CAMERA.intrinsics.width
    # eyes at ∓baseline/2 along the camera x axis
    np.testing.assert_allclose(m.cam_pos[m.camera("left").id], [-CAMERA.baseline / 2, 0, 0])
    np.testing.assert_allclose(m.cam_pos[m.camera("right").id], [CAMERA.baseline / 2, 0, 0])


def test_shadows_off(scene: WireChaserScene) -> None:
    assert not np.any(scene.model.light_castshadow)
    assert scene._renderer is not None
    assert scene._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] == 0


@pytest.mark.parametrize("t", [5.0, 30.0, 52.0])
def test_ring_seen_at_image_centre_from_goal_pose(scene: WireChaserScene, t: float) -> None:
    traj = make_trajectory(CFG, TrajectoryKind.NOISY, 36, seed=2)
    T_ring = traj.pose(t)
    T_ring[2, 3] += 0.08  # lift the ring clear of the wire, which would hide part of it
    T_cam = goal_pose(T_ring)
    scene.set_ring_pose(T_ring)
    scene.set_camera_pose(T_cam)
    centroids = {}
    for eye in EYE_CAMERAS:
        img = scene.render(eye)
        assert img.shape == (CAMERA.intrinsics.height, CAMERA.intrinsics.width, 3)
        assert img.dtype == np.uint8
        mask = ring_mask(img)
        assert mask.sum() > 200, "ring not visible"
        v, u = np.nonzero(mask)
        centroids[eye] = np.array([u.mean() + 0.5, v.mean() + 0.5])
        expected = CAMERA.project(T_cam, T_ring[:3, 3], eye)
        assert np.linalg.norm(centroids[eye] - expected) < CENTROID_TOL_PX
    # stereo disparity has the right sign and size: the right eye sees the ring further left
    disparity = centroids["left"][0] - centroids["right"][0]
    expected = CAMERA.intrinsics.fx * CAMERA.baseline / D_F
    assert abs(disparity - expected) < CENTROID_TOL_PX


def test_camera_looking_away_sees_no_ring(scene: WireChaserScene) -> None:
    T_ring = make_trajectory(CFG, TrajectoryKind.IDEAL, 36).pose(30.0)
    T_cam = goal_pose(T_ring)
    flip = make_pose(np.diag([1.0, -1.0, -1.0]), np.zeros(3))
    scene.set_ring_pose(T_ring)
    scene.set_camera_pose(T_cam @ flip)  # same place, looking the other way
    assert ring_mask(scene.render("left")).sum() == 0


def test_ring_moves_with_handle_and_psm1(scene: WireChaserScene) -> None:
    T_ring = make_trajectory(CFG, TrajectoryKind.NOISY, 71, seed=4).pose(17.0)
    scene.set_ring_pose(T_ring)
    tips = scene.tool_tips()
    assert tips.shape == (2, 3)
    expected = transform_points(T_ring, psm1_tip_in_ring(CFG.ring, CFG.instruments))
    np.testing.assert_allclose(tips[0], expected, atol=1e-7)
    np.testing.assert_allclose(tips[1], CFG.instruments.psm2_tip, atol=1e-7)
    np.testing.assert_allclose(scene.T_world_ring, T_ring, atol=1e-7)
    with pytest.raises(ValueError, match="T_world_ring"):
        scene.set_ring_pose(np.eye(3))


def test_psm2_drawn_where_the_log_puts_its_tip(scene: WireChaserScene) -> None:
    p_tip = np.array([-0.02, -0.03, 0.05])  # m, somewhere beside the wire
    scene.set_psm2_tip(p_tip)
    np.testing.assert_allclose(scene.tool_tips()[1], p_tip, atol=1e-7)
    shaft = np.asarray(CFG.instruments.psm2_direction) / np.linalg.norm(
        CFG.instruments.psm2_direction
    )
    p_shaft = p_tip + 0.03 * shaft  # m, a point on the drawn shaft
    ray_from = p_shaft + np.array([0.05, 0.0, 0.0])
    geomid = np.full(1, -1, dtype=np.int32)
    mujoco.mj_ray(scene.model, scene.data, ray_from, [-1.0, 0.0, 0.0], None, 1, -1, geomid)
    assert scene.geom_name(int(geomid[0])).startswith("psm2")
    scene.set_psm2_tip(CFG.instruments.psm2_tip)
    np.testing.assert_allclose(scene.tool_tips()[1], CFG.instruments.psm2_tip, atol=1e-7)
    with pytest.raises(ValueError, match="p_world_tip"):
        scene.set_psm2_tip([0.0, 0.0])


def test_ray_visible(scene: WireChaserScene) -> None:
    T_cam = overview_camera_pose(CFG, CAMERA)
    scene.set_camera_pose(T_cam)
    scene.set_ring_pose(make_pose(np.eye(3), [0.3, 0.3, 0.05]))  # out of the way
    on_board = np.array([0.0, -0.06, 0.0])
    below_board = np.array([0.0, -0.06, -0.01])
    assert scene.ray_visible(on_board, T_cam)
    assert not scene.ray_visible(below_board, T_cam)
    assert scene.ray_visible(below_board, T_cam, exclude_groups=[GROUP_BOARD])
    # a point behind the wire, seen through it, is hidden by it; on the wire it is visible
    wire = Wire(CFG.wire)
    p_wire = wire.point(0.5 * wire.length)
    eye = (T_cam @ CAMERA.T_cam_left)[:3, 3]
    direction = (p_wire - eye) / np.linalg.norm(p_wire - eye)
    assert scene.ray_visible(p_wire, T_cam)
    assert not scene.ray_visible(p_wire + 0.01 * direction, T_cam)
    # and the occluder is named: the wire in front of the point, the board above the other
    assert scene.occluder(p_wire, T_cam) is None
    assert scene.occluder(p_wire + 0.01 * direction, T_cam) == "wire"
    assert scene.occluder(below_board, T_cam) == "board"
    assert scene.occluder(below_board, T_cam, exclude_groups=[GROUP_BOARD]) is None
    with pytest.raises(ValueError, match="exclude_groups"):
        scene.ray_visible(on_board, T_cam, exclude_groups=[9])


def test_overview_pose_shows_whole_wire_level() -> None:
    T = overview_camera_pose(CFG, CAMERA)
    uv = CAMERA.project(T, Wire(CFG.wire).polyline(), "left")
    k = CAMERA.intrinsics
    assert np.all(np.isfinite(uv))
    assert np.all((uv[:, 0] > 0) & (uv[:, 0] < k.width) & (uv[:, 1] > 0) & (uv[:, 1] < k.height))
    assert abs(T[2, 0]) < ATOL_M  # camera x horizontal: level horizon
    assert T[2, 1] < 0.0 and T[2, 2] < 0.0  # image down is world down; looking down
    assert T[2, 3] > 0.1  # above the board


def test_extra_mocap_link_can_be_added_and_moved() -> None:
    spec = build_spec(CFG, CAMERA)
    add_mocap_link(
        spec,
        "ecm_link_1",
        [GeomSpec("ecm_link_1_tube", "capsule", (0.005,), fromto=(0, 0, 0, 0, 0, 0.1))],
    )
    with WireChaserScene(CFG, CAMERA, spec=spec) as s:
        T = make_pose(np.eye(3), [0.01, 0.02, 0.03])
        s.set_mocap_pose("ecm_link_1", T)
        b = s.model.body("ecm_link_1").id
        np.testing.assert_allclose(s.data.xpos[b], [0.01, 0.02, 0.03])
        with pytest.raises(ValueError, match="does not exist"):
            s.set_mocap_pose("nope", T)
    with pytest.raises(ValueError, match="kind"):
        add_mocap_link(build_spec(CFG, CAMERA), "x", [GeomSpec("x_g", "cone", (1.0,))])


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def test_meshes_closed_and_outward() -> None:
    R, r = 5e-3, 1e-3
    v, f, n = torus_mesh(R, r, 128, 64)
    exact = 2 * math.pi**2 * R * r**2
    assert abs(_signed_volume(v, f) - exact) / exact < 0.01
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    line = np.column_stack([np.linspace(0, 0.1, 50), np.zeros(50), np.full(50, 0.03)])
    v, f, _ = tube_mesh(line, r, 64)
    exact = math.pi * r**2 * 0.1
    assert abs(_signed_volume(v, f) - exact) / exact < 0.01


def test_non_ideal_intrinsics_rejected() -> None:
    k = Intrinsics(640, 480, 500.0, 500.0, 300.0, 240.0)
    with pytest.raises(ValueError, match="principal point"):
        check_ideal_camera(StereoCamera(intrinsics=k))
    with pytest.raises(ValueError, match="principal point"):
        build_model(CFG, StereoCamera(intrinsics=k))


NEAR_BLACK = 30  # 8-bit level below which a pixel reads as the unrendered void


@pytest.mark.parametrize("direction", [(0.0, 1.0, 0.0), (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0)])
def test_lit_backdrop_above_the_board(scene: WireChaserScene, direction: tuple) -> None:
    # issue 11: the space above the board was black, and the dark wire merged with it. Looking
    # level over the board towards the training box's walls shows the lit backdrop instead.
    z = np.array(direction)
    x = np.cross(z, [0.0, 0.0, 1.0])
    T = make_pose(np.column_stack([x, np.cross(z, x), z]), (0.0, 0.0, 0.10))
    scene.set_camera_pose(T)
    img = scene.render("left")
    top = img[: img.shape[0] // 2]  # above the horizon: walls only, no board
    assert (top.max(axis=-1) < NEAR_BLACK).mean() < 0.01
    backdrop = np.array(CFG.scene.backdrop_rgba[:3])
    # the walls' colour: hue of the configured backdrop (R > G > B), not grey or black
    r, g, b = (np.median(top[..., i]) for i in range(3))
    assert r > g > b and b > NEAR_BLACK
    assert backdrop[0] > backdrop[1] > backdrop[2]
