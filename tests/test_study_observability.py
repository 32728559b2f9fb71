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
from endocam.study.visibility import (
    GAP_SEEN,
    OUTSIDE_IMAGE,
    RESOLVED_PX,
    ClosingGap,
    EyeGap,
    gap_row,
    hider_kind,
    seed_bootstrap_ci,
    share_ci,
    view_gap,
)
from endocam.task.config import TaskConfig
from endocam.task.touches import clearances, contact_normal
from endocam.task.wire import Wire
from endocam.view import look_at_pose

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
    s = summarize(RECORDS, conditions=("fixed", "centering", "orientation"))
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
    assert empty.resolved is None
    assert list(summarize(RECORDS).conditions) == ["fixed", "orientation"]  # as recorded


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
    from endocam.study.visibility import OUTSIDE_IMAGE, gap_hidden_by, gap_in_sight
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


# ------------------------------------------------------------------- the closing gap (issue 27)
WIRE = Wire(CFG.wire)
S_GAP_M = 0.5 * WIRE.length  # m, arc length where the analytic gap closes
S_BEHIND_M = 15e-3  # m, a farther wire point lies this far along the wire
BEYOND_M = 20e-3  # m, the eye sits this far beyond that point
FY_PX = float(CAMERA.intrinsics.K[1, 1])  # px, focal length
Z_RESOLVED_M = FY_PX * GAP_SEEN / RESOLVED_PX  # m, depth at which the gap spans RESOLVED_PX
ATOL_CLEARANCE_M = 1e-6  # m, the placed gap against the exact clearance query


def closing_ring() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ring around the wire at ``S_GAP_M``, its rim ``GAP_SEEN`` from it on one side.

    Returns ``T_world_ring``, the gap's midpoint ``p`` (3,) and the direction it opens, ``e``.
    """
    w, t = WIRE.points(np.array([S_GAP_M]))[0], WIRE.tangent(np.array([S_GAP_M]))[0]
    e = np.cross(t, [0.0, 0.0, 1.0])
    e /= np.linalg.norm(e)  # horizontal, across the wire
    T = make_pose(
        np.column_stack([-e, np.cross(t, -e), t]),
        w - e * (R_MAJOR - R_MINOR - WIRE.radius - GAP_SEEN),
    )
    p = w + e * (WIRE.radius + 0.5 * GAP_SEEN)
    return T, p, e


def eye_at(p_eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera pose whose left eye sits at ``p_eye`` looking at ``target``."""
    T = look_at_pose(p_eye, target)
    T[:3, 3] -= (T @ CAMERA.T_cam_left)[:3, 3] - T[:3, 3]
    return T


def test_the_analytic_gap_is_the_exact_closest_approach() -> None:
    T, p, e = closing_ring()
    c, p_exact = clearances(T[None], WIRE, CFG.ring)
    assert c[0] == pytest.approx(GAP_SEEN, abs=ATOL_CLEARANCE_M)
    np.testing.assert_allclose(p_exact[0], p, atol=ATOL_CLEARANCE_M)
    np.testing.assert_allclose(contact_normal(p, T, R_MAJOR), e, atol=1e-9)


def _beside(distance: float) -> np.ndarray:
    """Eye ``distance`` from the gap, 45° off the ring normal, across the opening (above)."""
    T, p, e = closing_ring()
    t = T[:3, 2]
    v = np.cross(t, e)
    v *= np.sign(v[2])  # upwards
    d = (t + v) / np.linalg.norm(t + v)
    return eye_at(p + distance * d, p)


def test_a_camera_behind_the_wire_has_the_gap_hidden_by_the_wire(scene: WireChaserScene) -> None:
    T_ring, p, _ = closing_ring()
    b = WIRE.points(np.array([S_GAP_M + S_BEHIND_M]))[0]  # the wire's own far part
    ray = (b - p) / np.linalg.norm(b - p)
    gap = view_gap(scene, T_ring, eye_at(b + BEYOND_M * ray, p), p)
    # both eyes look along the wire: its own near part covers the gap beside it
    assert gap.left.hidden_by == gap.right.hidden_by == gap.hidden_by == "wire"
    assert not gap.in_sight_either and not gap.resolved


def test_either_eye_and_resolved_combine_the_two_eyes() -> None:
    seen_wide, seen_narrow = EyeGap(True, None, 3.0), EyeGap(True, None, 1.0)
    hidden_wide = EyeGap(False, "wire", 3.0)
    one = ClosingGap(math.nan, hidden_wide, seen_wide)  # only the right eye sees it
    assert one.in_sight_either and one.resolved and one.hidden_by is None
    other = ClosingGap(math.nan, seen_narrow, hidden_wide)  # wide only where it is hidden
    assert other.in_sight_either and not other.resolved and other.gap_px == 1.0
    neither = ClosingGap(math.nan, hidden_wide, EyeGap(False, "ring_torus", 2.5))
    assert not neither.in_sight_either and not neither.resolved
    assert neither.hidden_by == "wire" and neither.gap_px == 3.0  # the left eye names it


def test_a_camera_beside_the_gap_sees_it_resolved(scene: WireChaserScene) -> None:
    T_ring, p, _ = closing_ring()
    distance = 0.6 * Z_RESOLVED_M
    gap = view_gap(scene, T_ring, _beside(distance), p)
    assert gap.left.in_sight and gap.right.in_sight and gap.resolved
    # the gap opens across the left eye's view: GAP_SEEN spans f / depth of it
    assert gap.left.gap_px == pytest.approx(GAP_SEEN * FY_PX / distance, rel=1e-9)
    assert gap.gap_px >= gap.left.gap_px >= RESOLVED_PX


def test_a_camera_far_away_sees_the_gap_but_does_not_resolve_it(scene: WireChaserScene) -> None:
    T_ring, p, _ = closing_ring()
    gap = view_gap(scene, T_ring, _beside(4.0 * Z_RESOLVED_M), p)
    assert gap.left.in_sight and gap.in_sight_either
    assert not gap.resolved and gap.gap_px < RESOLVED_PX
    row = gap_row(gap)
    assert row["in_sight_either"] and not row["resolved"] and row["hidden_by_left"] is None


def test_a_gap_outside_the_image_is_named_so(scene: WireChaserScene) -> None:
    T_ring, p, _ = closing_ring()
    T = _beside(0.6 * Z_RESOLVED_M)
    T[:3, :3] = T[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # turned round
    gap = view_gap(scene, T_ring, T, p)
    assert gap.left.hidden_by == gap.right.hidden_by == OUTSIDE_IMAGE and not gap.resolved


def test_hider_kinds_name_the_scene_geoms() -> None:
    names = ["wire", "ring_torus", "ring_handle", "psm2_shaft", "board", "wall_front", "post_left"]
    kinds = ["wire", "rim", "handle", "instrument", "board", "box", "post"]
    assert [hider_kind(n) for n in names] == kinds
    assert hider_kind(OUTSIDE_IMAGE) == OUTSIDE_IMAGE


def test_the_bootstrap_resamples_seeds_not_touches() -> None:
    # two seeds, one all seen and one all hidden: seed-level resampling spans 0..1 (a touch-level
    # one would give about 0.5 ± 0.2)
    assert seed_bootstrap_ci([10, 0], [10, 10]) == (0.0, 1.0)
    rng = np.random.default_rng(3)
    totals = rng.integers(1, 12, size=8)
    hits = rng.integers(0, totals + 1)
    lo, hi = seed_bootstrap_ci(hits, totals)
    assert lo <= hits.sum() / totals.sum() <= hi
    assert seed_bootstrap_ci(hits, totals) == (lo, hi)  # seeded: reproducible
    assert seed_bootstrap_ci([3, 6], [6, 12]) == (0.5, 0.5)  # equal shares: no spread
    assert seed_bootstrap_ci([3], [6]) is None  # one seed: nothing to resample
    share = share_ci({"a": [True, False], "b": [True, True], "c": []})
    assert share is not None and share.share == pytest.approx(0.75) and share.seeds == 2
    with pytest.raises(ValueError, match="hits"):
        seed_bootstrap_ci([3], [2])
