"""Episode runner contracts: determinism, latency, motion limits, ground truth and outputs."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from endocam.config import ExperimentConfig
from endocam.robot.cartesian import CartesianLimiter
from endocam.runner import outputs
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.task.touches import clearances
from endocam.task.trajectory import TrajectoryKind

DURATION = 4.0  # s, short episodes keep the suite fast
LIMIT_RTOL = 1e-6  # relative slack on a speed limit (round-off of ruckig's profiles)
ATOL_M = 1e-12  # m


def _config(**episode: object) -> ExperimentConfig:
    """Short episodes of the free camera (its Cartesian limiter); tests/test_sim_arm.py: arms."""
    data: dict = {"task": {"trajectory": {"duration": DURATION}}, "episode": {"arm": "free"}}
    data["episode"].update(episode)
    return ExperimentConfig.model_validate(data)


@pytest.fixture(scope="module")
def noisy_orientation():
    return run_episode(_config(), EpisodeSpec("orientation", TrajectoryKind.NOISY, 71, 3))


def test_same_config_and_seed_give_identical_logs(noisy_orientation) -> None:
    again = run_episode(_config(), EpisodeSpec("orientation", TrajectoryKind.NOISY, 71, 3))
    a, b = noisy_orientation.log, again.log
    for name in ("t", "T_world_ring", "T_world_cam", "T_world_cmd", "d_f", "clearance"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(a.state, b.state)
    assert a.reason == b.reason
    other_seed = run_episode(_config(), EpisodeSpec("orientation", TrajectoryKind.NOISY, 71, 4))
    assert not np.array_equal(other_seed.log.T_world_ring, a.T_world_ring)


def test_controller_sees_the_ring_late(noisy_orientation) -> None:
    r = noisy_orientation
    latency = r.config.episode.sensing_latency
    k = len(r.log.t) // 2
    expected = r.trajectory.pose(r.log.t[k] - latency)
    np.testing.assert_allclose(r.log.T_world_ring_sensed[k], expected, atol=ATOL_M)
    assert not np.allclose(r.log.T_world_ring_sensed[k], r.log.T_world_ring[k])


def test_camera_respects_speed_limits(noisy_orientation) -> None:
    r = noisy_orientation
    lim = r.config.episode.limits
    dt = 1.0 / r.config.episode.control_rate
    p = r.log.T_world_cam[:, :3, 3]
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / dt
    assert speed.max() <= lim.max_linear_speed * (1 + LIMIT_RTOL)
    R = r.log.T_world_cam[:, :3, :3]
    rel = np.einsum("nji,njk->nik", R[:-1], R[1:])  # R_k^T R_{k+1}
    angle = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert (angle / dt).max() <= lim.max_angular_speed * (1 + LIMIT_RTOL)
    assert speed.max() > 0.1 * lim.max_linear_speed  # it did move


def test_limiter_never_teleports_to_a_far_target() -> None:
    cfg = _config()
    dt = 0.01
    lim = CartesianLimiter(cfg.episode.limits, dt)
    lim.reset(np.eye(4))
    far = np.eye(4)
    far[:3, 3] = [1.0, 0.0, 0.0]
    T = lim.step(far)
    assert np.linalg.norm(T[:3, 3]) <= cfg.episode.limits.max_linear_speed * dt
    nan_target = np.full((4, 4), np.nan)
    T2 = lim.step(nan_target)  # rejected: keeps heading for the last valid target
    assert np.all(np.isfinite(T2))
    assert lim.status.value == "rejected"
    assert T2[0, 3] >= T[0, 3]


# Noisy 71-point trajectory, seed 3, squeezed into DURATION: the ring-wire clearance, sampled
# every DENSE_DT_S on its own (task.touches.clearances), dips below zero in this many separate
# runs. Counted once from the dense clearance and written here; the runner's touches must agree.
EXPECTED_TOUCHES = 3  # count
DENSE_DT_S = 2e-4  # s: far finer than the shortest touch of this path (~35 ms)


def test_touches_add_up(noisy_orientation) -> None:
    r = noisy_orientation
    t = np.arange(0.0, DURATION + 1e-9, DENSE_DT_S)
    c, _ = clearances(r.trajectory.poses(t), r.wire, r.config.task.ring)
    touching = c < 0.0
    runs = int(np.count_nonzero(np.diff(touching.astype(int)) == 1) + touching[0])
    assert runs == EXPECTED_TOUCHES
    m = outputs.metrics_dict(r)
    assert m["touches"] == len(m["touch_events"]) == EXPECTED_TOUCHES
    # the logged contact column is the dense clearance's sign at each control step
    k = np.round(r.log.t / DENSE_DT_S).astype(int)
    np.testing.assert_array_equal(r.log.contact, touching[k])
    # the time in contact reported equals the events' total duration over the trajectory's
    spent = sum(e.t_end - e.t_start for e in r.touches.events)
    assert m["contact_fraction"] == pytest.approx(spent / (r.touches.t[-1] - r.touches.t[0]))


def test_touches_do_not_depend_on_the_policy(noisy_orientation) -> None:
    fixed = run_episode(_config(), EpisodeSpec("fixed", TrajectoryKind.NOISY, 71, 3))
    assert [e.t_start for e in fixed.touches.events] == [
        e.t_start for e in noisy_orientation.touches.events
    ]
    np.testing.assert_array_equal(fixed.log.contact, noisy_orientation.log.contact)
    np.testing.assert_array_equal(fixed.log.T_world_cam[0], fixed.log.T_world_cam[-1])


def test_ideal_trajectory_has_no_contact() -> None:
    r = run_episode(_config(), EpisodeSpec("centering", TrajectoryKind.IDEAL, 36))
    assert r.touches.count == 0
    assert not r.log.contact.any()
    assert r.log.clearance.min() > 0


def test_unknown_policy_fails_before_work() -> None:
    with pytest.raises(ValueError, match="unknown policy"):
        run_episode(_config(), EpisodeSpec("zoom", TrajectoryKind.IDEAL, 36))
    with pytest.raises(ValueError, match="control_points"):
        EpisodeSpec("fixed", TrajectoryKind.IDEAL, 1)


REQUIRED_COLUMNS = (
    "t ring_x ring_y ring_z ring_qw ring_qx ring_qy ring_qz cam_x cam_y cam_z "
    "cam_qw cam_qx cam_qy cam_qz contact"
).split()


def test_outputs_are_complete_and_consistent(noisy_orientation, tmp_path: Path) -> None:
    r = noisy_orientation
    out = outputs.write_run(r, tmp_path / "run", video=False)
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        outputs.OUTPUT_MARKER,
        "check.json",
        "episode.csv",
        "metrics.json",
        "report.html",
        "scene.json",
        "tracking.png",
    ]
    with open(out / "episode.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(r.log.t)
    for col in REQUIRED_COLUMNS:
        assert col in rows[0]
    k = 17
    assert float(rows[k]["cam_x"]) == r.log.T_world_cam[k, 0, 3]
    q = [float(rows[k][f"ring_q{a}"]) for a in "wxyz"]
    assert math.isclose(sum(v * v for v in q), 1.0, rel_tol=1e-12)
    assert sum(int(row["contact"]) for row in rows) == int(r.log.contact.sum())
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("image_error_px", "center_error_mm", "orientation_error_deg"):
        assert set(metrics[key]) >= {"mean", "p95", "max"}
    assert metrics["center_error_mm"]["mean"] == pytest.approx(1e3 * r.center_error.mean())
    assert metrics["config"] == r.config.model_dump(mode="json")
    assert "endocam_version" in metrics
    scene = json.loads((out / "scene.json").read_text())
    assert np.asarray(scene["wire"]["points"]).shape[1] == 3
    np.testing.assert_allclose(scene["camera"]["K_left"], r.camera.intrinsics.K)
    np.testing.assert_allclose(scene["camera"]["T_cam_left"], r.camera.T_cam_left)
    assert scene["ring"]["major_radius"] == r.config.task.ring.major_radius
    assert scene["wire"]["wire_radius"] == r.config.task.wire.radius


def test_failed_write_leaves_nothing(noisy_orientation, tmp_path: Path, monkeypatch) -> None:
    def boom(*args: object, **kwargs: object) -> None:
        raise RuntimeError("disk full")

    monkeypatch.setattr(outputs, "plot_tracking", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        outputs.write_run(noisy_orientation, tmp_path / "run", video=False)
    assert list(tmp_path.iterdir()) == []


def test_video_has_one_frame_per_sample(tmp_path: Path) -> None:
    cfg = ExperimentConfig.model_validate(
        {
            "task": {"trajectory": {"duration": 1.0}},
            "camera": {"width": 160, "height": 120},
            "episode": {"video_fps": 10.0},
        }
    )
    r = run_episode(cfg, EpisodeSpec("orientation", TrajectoryKind.IDEAL, 36))
    out = outputs.write_run(r, tmp_path / "run", video=True)
    reader = imageio_ffmpeg.read_frames(str(out / "video.mp4"))
    meta = next(reader)
    assert tuple(meta["size"]) == (160, 120)
    frames = list(reader)
    assert len(frames) == len(outputs.frame_indices(r)) == 11
    first = np.frombuffer(frames[0], np.uint8)
    assert first.std() > 5  # not a blank frame
    html = (out / "report.html").read_text()
    assert 'src="video.mp4"' in html


def test_side_by_side_caption_names_each_panel() -> None:
    from endocam.runner.experiments import LABEL_HEIGHT_PX, label_strip

    strip = label_strip(["fixed", "centering", "orientation"], 160)
    assert strip.shape == (LABEL_HEIGHT_PX, 480, 3)
    assert strip.dtype == np.uint8
    bright = strip.max(axis=2) > 200  # white text on a dark strip
    for j in range(3):  # text in every panel, centred on it
        cols = np.flatnonzero(bright[:, 160 * j : 160 * (j + 1)].any(axis=0))
        assert cols.size > 0
        assert abs(0.5 * (cols.min() + cols.max()) - 80) < 20
