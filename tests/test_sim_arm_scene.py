"""The camera arm drawn in the MuJoCo scene (endocam.sim.arm_scene, issue 4 §3)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np
import pytest

from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.robot.camera_arm import CameraArm
from endocam.robot.carriers import arm_mount
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode
from endocam.sim.arm_scene import ARM_PREFIX, CAMERA_BODY_GEOM, camera_arm_links
from endocam.sim.render import WireChaserScene, log_arm
from endocam.sim.scene import GROUP_LINK, build_spec
from endocam.task.trajectory import TrajectoryKind
from endocam.view import look_at_pose

ATOL_M = 1e-9  # m: mocap body pose vs the arm's link frame (float32-free: mocap is float64)
ATOL_R = 1e-9  # 1: rotation-matrix entries
DURATION_S = 1.0  # s: a short episode keeps the file fast
VIEW_DISTANCE_M = 0.15  # m, overview viewpoint distance from the point it looks at
SHAFT_FRACTION = 0.5  # unitless, point along the drawn PSM shaft the view looks at
PSM_SHAFT_LENGTH_M = 0.467  # m, frame 3 to the wrist-pitch axis (DH table)


def _episode(arm: str, policy: str = "orientation") -> EpisodeResult:
    cfg = ExperimentConfig.model_validate(
        {"task": {"trajectory": {"duration": DURATION_S}}, "episode": {"arm": arm}}
    )
    return run_episode(cfg, EpisodeSpec(policy, TrajectoryKind.IDEAL, 71, 0))


@pytest.fixture(scope="module")
def psm_episode() -> EpisodeResult:
    return _episode("psm")


@pytest.fixture(scope="module")
def psm_scene(psm_episode: EpisodeResult) -> Iterator[WireChaserScene]:
    r = psm_episode
    s = WireChaserScene(r.config.task, r.camera, arm=log_arm(r.log))
    yield s
    s.close()


def _camera_arm(result: EpisodeResult) -> CameraArm:
    cfg = result.config
    kind = ArmKind(result.log.arm)
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    return CameraArm(kind, T_rcm, T_tip_cam, 0.01)


def _show_step(scene: WireChaserScene, result: EpisodeResult, k: int) -> None:
    scene.set_ring_pose(result.log.T_world_ring[k])
    scene.set_camera_pose(result.log.T_world_cam[k])
    scene.set_arm_from_log(result.log, k)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_arm_links_named_mocap_kinematic_and_in_link_group(kind: ArmKind):
    cfg = ExperimentConfig()
    camera = cfg.camera.stereo()
    with WireChaserScene(cfg.task, camera, arm=kind) as scene:
        m = scene.model
        for what, count in (("body", m.nbody), ("geom", m.ngeom)):
            names = [getattr(m, what)(i).name for i in range(1 if what == "body" else 0, count)]
            assert all(names) and len(set(names)) == len(names), f"unnamed/duplicate {what}"
        assert m.nv == 0 and np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
        links = camera_arm_links(kind, cfg.task.instruments)
        for link in links:
            body = m.body(link.body)
            assert body.name.startswith(ARM_PREFIX) and body.mocapid[0] >= 0
            for g in link.geoms:
                assert m.geom(g.name).group[0] == GROUP_LINK
                assert m.geom(g.name).bodyid[0] == body.id
        has_camera_body = CAMERA_BODY_GEOM in {m.geom(i).name for i in range(m.ngeom)}
        assert has_camera_body == (kind is ArmKind.PSM)
        m_plain = build_spec(cfg.task, camera).compile()
        n_link_geoms = sum(len(link.geoms) for link in links) + int(has_camera_body)
        assert m.ngeom == m_plain.ngeom + n_link_geoms
        assert m.nmocap == m_plain.nmocap + len(links)


def test_links_posed_at_the_arm_frames_and_jaws_hold_the_camera(
    psm_episode: EpisodeResult, psm_scene: WireChaserScene
):
    log = psm_episode.log
    assert log.joints is not None
    arm = _camera_arm(psm_episode)
    k = len(log.t) - 1
    _show_step(psm_scene, psm_episode, k)
    frames = arm.link_frames(log.joints[k])
    for link in camera_arm_links(ArmKind.PSM, psm_episode.config.task.instruments):
        b = psm_scene.model.body(link.body).id
        np.testing.assert_allclose(psm_scene.data.xpos[b], frames[link.frame][:3, 3], atol=ATOL_M)
        R = psm_scene.data.xmat[b].reshape(3, 3)
        np.testing.assert_allclose(R, frames[link.frame][:3, :3], atol=ATOL_R)
    # the jaws (tool tip) carry the camera through the mount: T_world_cam = T_world_tip T_tip_cam
    T_world_tip = frames[-1]
    np.testing.assert_allclose(
        T_world_tip @ arm.T_tip_cam, psm_scene.T_world_cam, atol=ATOL_M + ATOL_R
    )


def test_overview_frame_shows_the_camera_arm(
    psm_episode: EpisodeResult, psm_scene: WireChaserScene
):
    log = psm_episode.log
    assert log.joints is not None
    k = len(log.t) // 2
    _show_step(psm_scene, psm_episode, k)
    frames = _camera_arm(psm_episode).link_frames(log.joints[k])
    T3 = frames[2]  # insertion frame: the shaft runs along its z axis
    p_shaft = T3[:3, 3] + SHAFT_FRACTION * PSM_SHAFT_LENGTH_M * T3[:3, 2]
    side = np.cross(T3[:3, 2], [0.0, 0.0, 1.0])
    p_view = p_shaft + VIEW_DISTANCE_M * (side / np.linalg.norm(side) + np.array([0, 0, 0.5]))
    T_view = look_at_pose(p_view, p_shaft)  # the shaft point projects to the image centre
    shown = psm_scene.render_view(T_view)
    psm_scene.set_arm_joints(None)
    hidden = psm_scene.render_view(T_view)
    k_img = psm_episode.camera.intrinsics
    v, u = round(k_img.cy), round(k_img.cx)
    assert not np.array_equal(shown[v, u], hidden[v, u])  # the shaft is drawn there
    assert np.array_equal(hidden[v, u], np.zeros(3, dtype=np.uint8))  # background behind it
    shaft_rgb = np.array(psm_episode.config.task.instruments.rgba[:3])
    assert np.all(shown[v, u] > 0.25 * 255 * shaft_rgb)  # lit metal, not background


@pytest.mark.parametrize("arm", ["psm", "ecm"])
def test_camera_never_sees_its_own_arm(arm: str, psm_episode: EpisodeResult):
    result = psm_episode if arm == "psm" else _episode("free", "orientation-ecm")
    assert log_arm(result.log) is ArmKind(arm)
    with WireChaserScene(result.config.task, result.camera, arm=ArmKind(arm)) as scene:
        for k in (0, len(result.log.t) // 2, len(result.log.t) - 1):
            _show_step(scene, result, k)
            for eye in ("left", "right"):
                with_arm = scene.render(eye)
                scene.set_arm_joints(None)
                without = scene.render(eye)
                scene.set_arm_from_log(result.log, k)
                np.testing.assert_array_equal(with_arm, without)


def test_free_camera_logs_draw_no_arm():
    result = _episode("free", "fixed")
    assert log_arm(result.log) is None
    with WireChaserScene(result.config.task, result.camera, arm=log_arm(result.log)) as scene:
        assert scene.arm is None
        names = {scene.model.body(i).name for i in range(scene.model.nbody)}
        assert not any(n.startswith(ARM_PREFIX) for n in names)
        scene.set_arm_from_log(result.log, 0)  # a no-op without an arm
        with pytest.raises(ValueError, match="q"):
            scene.set_arm_joints(np.zeros(6))


def test_bad_input_rejected(psm_scene: WireChaserScene):
    with pytest.raises(ValueError, match="q"):
        psm_scene.set_arm_joints(np.zeros(4))
    with pytest.raises(ValueError, match="q"):
        psm_scene.set_arm_joints([0.0, 0.0, 0.1, 0.0, 0.0, float("nan")])
    with pytest.raises(ValueError, match="T_world_view"):
        psm_scene.render_view(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="kind"):
        camera_arm_links(ArmKind.FREE, ExperimentConfig().task.instruments)


def test_renderer_flags_unchanged_by_the_arm(psm_scene: WireChaserScene):
    assert psm_scene._renderer is not None
    assert psm_scene._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] == 0
    assert not np.any(psm_scene.model.light_castshadow)


def test_videos_of_arm_episodes_render(psm_episode: EpisodeResult, tmp_path: Path):
    from endocam.runner.experiments import render_side_by_side
    from endocam.runner.outputs import frame_indices, render_video
    from endocam.study.make import render_conditions

    free = _episode("free", "fixed")  # same trajectory, no arm: the arm is hidden for it
    n = render_video(psm_episode, tmp_path / "psm.mp4")
    assert n == len(frame_indices(psm_episode))
    paths = [tmp_path / "a.mp4", tmp_path / "b.mp4"]
    render_conditions([psm_episode, free], paths)
    render_side_by_side(
        [psm_episode, free], [tmp_path / "c.mp4", tmp_path / "d.mp4"], tmp_path / "g.mp4"
    )
    for p in [tmp_path / "psm.mp4", *paths, tmp_path / "g.mp4"]:
        assert p.stat().st_size > 0
