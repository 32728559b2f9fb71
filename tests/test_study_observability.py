import dataclasses
import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from endocam.camera import Intrinsics, StereoCamera
from endocam.geometry import R_from_euler_xyz, make_pose
from endocam.sim.render import WireChaserScene
from endocam.study.observability import (
    TouchObservation,
    in_image,
    load_summary,
    observability_csv,
    observability_json,
    observe_contact,
    pixel_scales,
    summarize,
)
from endocam.task.config import TaskConfig
from endocam.task.touches import contact_normal

CFG = TaskConfig()
CAMERA = StereoCamera(Intrinsics.from_fovy(160, 120, math.radians(60.0)))
R_MAJOR = CFG.ring.major_radius  # m
R_MINOR = CFG.ring.minor_radius  # m
ATOL_UNIT = 1e-12  # unitless, unit-vector components
RTOL_JACOBIAN = 1e-5  # relative, analytic vs finite-difference image velocity
FD_STEP_M = 1e-7  # m, finite-difference step
ATOL_DEG = 1e-6  # deg
# A free spot above the board, away from the wire (|y| < 30 mm) and the posts.
C_RING = np.array([0.0, 0.08, 0.08])  # m
LOOK_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # optical z = -world z
HEIGHT_M = 0.06  # m, eye height above the ring


@pytest.fixture(scope="module")
def scene() -> Iterator[WireChaserScene]:
    s = WireChaserScene(CFG, CAMERA)
    yield s
    s.close()


def camera_above(p_world: np.ndarray, height: float = HEIGHT_M) -> np.ndarray:
    """Camera looking straight down with its *left eye* exactly above ``p_world``."""
    T = make_pose(LOOK_DOWN, p_world + np.array([0.0, 0.0, height]))
    offset = (T @ CAMERA.T_cam_left)[:3, 3] - T[:3, 3]
    T[:3, 3] -= offset
    return T


def ring_pose(normal_euler: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    return make_pose(R_from_euler_xyz(normal_euler), C_RING)


# ----------------------------------------------------------------------------- pure parts
def test_contact_normal_points_from_wire_to_ring_core() -> None:
    T = ring_pose()
    outside = C_RING + np.array([-(R_MAJOR + R_MINOR), 0.0, 0.0])  # on the outer rim, -x side
    np.testing.assert_allclose(contact_normal(outside, T, R_MAJOR), [1, 0, 0], atol=ATOL_UNIT)
    inside = C_RING + np.array([0.0, R_MAJOR - R_MINOR, 0.0])  # on the inner rim, +y side
    np.testing.assert_allclose(contact_normal(inside, T, R_MAJOR), [0, 1, 0], atol=ATOL_UNIT)
    above = C_RING + np.array([0.0, -R_MAJOR, R_MINOR])  # on top of the tube
    np.testing.assert_allclose(contact_normal(above, T, R_MAJOR), [0, 0, -1], atol=ATOL_UNIT)
    with pytest.raises(ValueError, match="axis"):
        contact_normal(C_RING + np.array([0.0, 0.0, 0.01]), T, R_MAJOR)
    with pytest.raises(ValueError, match="core circle"):
        contact_normal(C_RING + np.array([R_MAJOR, 0.0, 0.0]), T, R_MAJOR)


def test_in_image_front_edge_and_behind() -> None:
    T = camera_above(C_RING)
    assert in_image(CAMERA, T, C_RING)
    assert not in_image(CAMERA, T, C_RING + np.array([0.0, 0.0, 2 * HEIGHT_M]))  # behind the eye
    assert not in_image(
        CAMERA, T, C_RING + np.array([0.2, 0.0, 0.0])
    )  # far outside the field of view


def test_pixel_scales_match_finite_differences() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        T = make_pose(R_from_euler_xyz(rng.uniform(-0.5, 0.5, 3)) @ LOOK_DOWN, [0, 0, 0.2])
        p = T[:3, 3] + T[:3, :3] @ np.array([*rng.uniform(-0.02, 0.02, 2), 0.1])
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        px_per_m, step = pixel_scales(CAMERA, T, p, u)
        fd = (CAMERA.project(T, p + FD_STEP_M * u) - CAMERA.project(T, p)) / FD_STEP_M
        assert step == pytest.approx(float(np.linalg.norm(fd)), rel=RTOL_JACOBIAN)
        depth = ((np.linalg.inv(T @ CAMERA.T_cam_left)) @ np.append(p, 1.0))[2]
        assert px_per_m == pytest.approx(CAMERA.intrinsics.K[1, 1] / depth)


def test_pixel_scales_along_the_line_of_sight_is_zero_and_behind_is_nan() -> None:
    T = camera_above(C_RING)
    px_per_m, step = pixel_scales(CAMERA, T, C_RING, [0.0, 0.0, 1.0])
    assert px_per_m == pytest.approx(CAMERA.intrinsics.K[1, 1] / HEIGHT_M)
    assert step == pytest.approx(0.0, abs=1e-9 * px_per_m)
    assert all(
        math.isnan(v) for v in pixel_scales(CAMERA, T, C_RING + np.array([0, 0, 1.0]), [1, 0, 0])
    )


# -------------------------------------------------------------------------- with the scene
def test_looking_along_the_normal_gives_angle_zero_and_full_gap(scene: WireChaserScene) -> None:
    p = C_RING + np.array([-(R_MAJOR + R_MINOR), 0.0, 0.0])  # outer rim, away from the handle
    view = observe_contact(scene, ring_pose(), camera_above(p), p)
    assert view.visible and view.in_image and view.unoccluded
    assert view.view_angle_deg == pytest.approx(0.0, abs=ATOL_DEG)
    # the gap opens across the view: 1 mm spans f / depth px
    expected = CAMERA.intrinsics.K[0, 0] / HEIGHT_M / 1e3
    assert view.gap_px_per_mm == pytest.approx(expected, rel=1e-9)
    assert view.px_per_mm == pytest.approx(expected, rel=1e-9)


def test_edge_on_ring_gives_ninety_degrees_and_no_gap(scene: WireChaserScene) -> None:
    T_ring = ring_pose((math.pi / 2, 0.0, 0.0))  # normal along world -y: seen edge-on from above
    p = C_RING + np.array([0.0, 0.0, R_MAJOR + R_MINOR])  # top of the standing ring
    view = observe_contact(scene, T_ring, camera_above(p), p)
    assert view.view_angle_deg == pytest.approx(90.0, abs=ATOL_DEG)
    assert view.gap_px_per_mm == pytest.approx(0.0, abs=1e-9)  # the gap opens along the view
    assert view.visible


def test_point_behind_the_camera_is_not_visible(scene: WireChaserScene) -> None:
    p = C_RING + np.array([-(R_MAJOR + R_MINOR), 0.0, 0.0])
    T_up = make_pose(np.eye(3), camera_above(p)[:3, 3])  # same place, optical z = world +z
    view = observe_contact(scene, ring_pose(), T_up, p)
    assert not view.in_image and not view.visible
    assert math.isnan(view.px_per_mm)


def test_point_under_the_ring_tube_is_occluded_but_visible_through_the_hole(
    scene: WireChaserScene,
) -> None:
    below = np.array([0.0, 0.0, -4.0 * R_MINOR])  # m, 4 mm under the plane of the ring
    under_tube = C_RING + np.array([-R_MAJOR, 0.0, 0.0]) + below
    view = observe_contact(scene, ring_pose(), camera_above(under_tube), under_tube)
    assert view.in_image and not view.unoccluded and not view.visible
    through_hole = C_RING + below  # the ray passes through the ring's hole
    view = observe_contact(scene, ring_pose(), camera_above(through_hole), through_hole)
    assert view.visible


def test_point_under_the_board_is_occluded(scene: WireChaserScene) -> None:
    p = np.array([0.0, 0.08, -0.005])  # m, 5 mm under the board's surface
    view = observe_contact(scene, ring_pose(), camera_above(p, 0.1), p)
    assert view.in_image and not view.visible
    above = p + np.array([0.0, 0.0, 0.01])
    assert observe_contact(scene, ring_pose(), camera_above(above, 0.1), above).visible


# ------------------------------------------------------------------------------- summary
def _record(
    condition: str, visible: bool, angle: float, frames: int, seen: int
) -> TouchObservation:
    return TouchObservation(
        video_id=f"v-{condition}",
        condition=condition,
        trajectory="t",
        touch=0,
        t_start_s=0.0,
        t_end_s=0.1,
        in_image=True,
        unoccluded=visible,
        visible=visible,
        view_angle_deg=angle,
        px_per_mm=2.0,
        gap_px_per_mm=math.nan if angle > 80 else 1.0,
        frames=frames,
        visible_frames=seen,
    )


RECORDS = [
    _record("fixed", True, 10.0, 2, 2),
    _record("fixed", False, 30.0, 0, 0),
    _record("fixed", False, 85.0, 4, 1),
    _record("orientation", True, 5.0, 3, 3),
]


def test_summarize_per_condition() -> None:
    s = summarize(RECORDS)
    fixed = s.conditions["fixed"]
    assert fixed.touches == 3
    assert fixed.visible_share == pytest.approx(1 / 3)
    assert fixed.median_view_angle_deg == pytest.approx(30.0)
    assert fixed.median_gap_px_per_mm == pytest.approx(1.0)  # NaN ignored
    assert fixed.visible_frame_share == pytest.approx(3 / 6)
    assert fixed.touches_without_frame == 1
    assert s.conditions["orientation"].visible_share == pytest.approx(1.0)
    empty = s.conditions["centering"]
    assert empty.touches == 0 and empty.visible_share is None and empty.median_px_per_mm is None


def test_json_round_trip_csv_and_bad_files(tmp_path: Path) -> None:
    s = summarize(RECORDS)
    path = tmp_path / "observability.json"
    path.write_text(observability_json(s, RECORDS), encoding="utf-8")
    assert load_summary(path) == s
    doc = json.loads(path.read_text())
    assert len(doc["touches"]) == len(RECORDS)
    assert doc["touches"][2]["gap_px_per_mm"] is None  # NaN → null
    lines = observability_csv(RECORDS).splitlines()
    assert len(lines) == 1 + len(RECORDS)
    assert lines[0].startswith("video_id,condition,trajectory,touch")
    path.write_text("{not json", encoding="utf-8")
    with pytest.raises(ValueError, match="cannot read"):
        load_summary(path)
    path.write_text('{"eye": "left"}', encoding="utf-8")
    with pytest.raises(ValueError, match="instant"):
        load_summary(path)


def test_gap_in_sight_is_false_for_a_camera_looking_away() -> None:
    """The flag needs the closing gap in the image: a camera turned round never has it.

    And what hides it is named: the image's edge for that camera, the box's wall for one outside.
    """
    from endocam.config import ExperimentConfig
    from endocam.runner.episode import EpisodeSpec, run_episode
    from endocam.sim.render import WireChaserScene
    from endocam.study.observability import OUTSIDE_IMAGE, gap_hidden_by, gap_in_sight
    from endocam.task.trajectory import TrajectoryKind

    data = ExperimentConfig().model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = 20.0
    data["episode"]["arm"] = "free"
    cfg = ExperimentConfig.model_validate(data)
    result = run_episode(cfg, EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    assert result.touches.events
    with WireChaserScene(cfg.task, result.camera) as scene:
        facing = [gap_in_sight(result, scene, e.t_start) for e in result.touches.events]
        turned = result.log.T_world_cam.copy()
        turned[:, :3, :3] = turned[:, :3, :3] @ np.diag([-1.0, 1.0, -1.0])  # look backwards
        away = dataclasses.replace(result, log=dataclasses.replace(result.log, T_world_cam=turned))
        assert not any(gap_in_sight(away, scene, e.t_start) for e in result.touches.events)
        assert {gap_hidden_by(away, scene, e.t_start) for e in result.touches.events} == {
            OUTSIDE_IMAGE
        }
        # outside the training box, level with the ring, looking at it through the front wall
        behind = result.log.T_world_cam.copy()
        behind[:, :3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # z: +y
        wall_y = -0.5 * cfg.task.scene.board_size[1]  # m, the front wall's inner face
        for k in range(len(behind)):
            p_ring = result.trajectory.pose(k / cfg.episode.control_rate)[:3, 3]
            behind[k, :3, 3] = (p_ring[0], wall_y - 0.05, p_ring[2])  # 5 cm beyond the wall
        walled = dataclasses.replace(
            result, log=dataclasses.replace(result.log, T_world_cam=behind)
        )
        hidden = {gap_hidden_by(walled, scene, e.t_start) for e in result.touches.events}
        assert hidden == {"wall_front"}
    assert any(facing)  # the tracking camera sees some of its gaps close
