"""The control loop on perception: the capture schedule, the stereo source, its logs.

The stereo source runs on a hand-made world (a still ring, a still camera at 320x240: a few
frames); the truth source's log is checked to keep its columns. The loop end to end:
test_perception_loop_episode.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam.config import ExperimentConfig
from endocam.perception.estimator import NormalChoice, settle_choice
from endocam.perception.loop import (
    capture_steps,
    estimate_errors,
    prior_normal,
    resampled,
)
from endocam.perception.track import (
    NormalAdaptation,
    StepLimit,
    TrackFilter,
    depth_scaled_gains,
    kalata_beta,
)
from endocam.robot.actuator import ArmKind
from endocam.runner.log_schema import (
    ESTIMATE_COLUMNS,
    LogHeader,
    MalformedLogError,
    episode_column_names,
    log_section,
)
from endocam.runner.step import EpisodeWorld
from endocam.view import look_at_pose

DT_S = 0.01  # s, the default control period
TIME_TOL_S = 1e-9  # s, times on the control grid
CENTRE_TOL_M = 1.0e-3  # m, a clear oblique view: issue 26's median target
NORMAL_TOL = math.radians(4.0)  # rad, likewise
DISTANCE_M = 0.055  # m, about the tracker's working distance
P_WORLD_RING = np.array([-0.06, -0.045, 0.05])  # m, in front of the wire (test_perception's)
R_WORLD_RING = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # normal −y
P_WORLD_PSM2 = np.array([0.1, 0.1, 0.1])  # m, PSM2's tip out of the way
STEADY_TOL_M = 1e-6  # m, a steady motion followed after 2 s (the filter's transient decayed)
NOISE_RAD = math.radians(1.5)  # rad, per-axis tilt noise of a simulated estimate

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)


def stereo_config(**perception: object) -> ExperimentConfig:
    return ExperimentConfig.model_validate(
        {
            "camera": {"width": 320, "height": 240},
            "perception": {"source": "stereo", **perception},
        }
    )


def still_world(n: int, T_ring: np.ndarray) -> EpisodeWorld:
    t = np.arange(n) * DT_S
    T = np.repeat(T_ring[None], n, axis=0)
    tips = np.repeat(np.stack([T_ring[:3, 3], P_WORLD_PSM2])[None], n, axis=0)
    return EpisodeWorld(t=t, T_world_ring=T, t_ring=t, T_world_ring_sensed=T, p_world_tips=tips)


def test_frames_are_captured_at_the_frame_rate_on_the_control_grid() -> None:
    steps = capture_steps(101, DT_S, 30.0)  # 1 s
    assert steps[:5].tolist() == [0, 4, 7, 10, 14]  # 0, 1/30 → 0.04, 2/30 → 0.07, 0.1, 4/30
    assert len(steps) == 31  # frames 0..30 at j / 30 s ≤ 1 s
    assert np.all(steps * DT_S + TIME_TOL_S >= np.arange(31) / 30.0)
    assert capture_steps(11, DT_S, 100.0).tolist() == list(range(11))  # every step


def test_a_prior_settles_an_ambiguous_normal() -> None:
    n, other = np.array([0.0, 0.0, -1.0]), np.array([0.0, math.sin(0.6), -math.cos(0.6)])
    choice = NormalChoice(n, 0.01, 0.005, 0.6, other)
    tol = 0.25 * choice.separation
    assert settle_choice(choice, None, tol) is None
    assert settle_choice(choice, n, tol) is choice
    swapped = settle_choice(choice, other, tol)
    assert swapped is not None and np.array_equal(swapped.n, other)
    assert swapped.disagreement == pytest.approx(0.015)  # the other pair's: best + margin
    between = (n + other) / np.linalg.norm(n + other)  # 0.3 rad from each: settles nothing
    assert settle_choice(choice, between, tol) is None


def test_the_stereo_source_delivers_estimates_late_and_stamped() -> None:
    from endocam.runner.ring_source import StereoSource

    cfg = stereo_config()
    T_ring = np.eye(4)
    T_ring[:3, :3], T_ring[:3, 3] = R_WORLD_RING, P_WORLD_RING
    a = math.radians(30.0)  # an oblique view: the second eye decides the normal
    sight = np.array([-math.sin(a), -math.cos(a), 0.0])  # from the ring towards the camera
    T_cam = look_at_pose(P_WORLD_RING + DISTANCE_M * sight, P_WORLD_RING)
    n = 20
    source = StereoSource(cfg, still_world(n, T_ring), ArmKind.FREE, 0, T_ring)
    try:
        seen = [source.sense(k, T_cam, np.zeros(0)) for k in range(n)]
        assert source.sense(n - 1, T_cam, np.zeros(0)) is seen[-1]  # asked again: the same
    finally:
        source.close()
    log = source.log()
    delay = cfg.episode.sensing_latency + cfg.perception.processing_delay
    assert log.frame_steps.tolist() == [0, 4, 7, 10, 14, 17]
    assert log.frame_ok.all(), log.frame_status
    delivered = np.flatnonzero(log.ok)
    assert delivered.tolist() == [6, 10, 13, 16]  # capture + 0.06 s, frames 0, 4, 7, 10
    age = np.arange(n)[delivered] * DT_S - log.t_capture[delivered]
    assert np.all(age >= delay - TIME_TOL_S)
    for k in range(6):  # nothing yet: a missing pose, stamped now
        assert np.isnan(seen[k][0]).all() and seen[k][1] == pytest.approx(k * DT_S)
    for k in range(6, n):  # every step after the first: the track's pose for now, stamped now
        assert seen[k][1] == pytest.approx(k * DT_S)
        assert np.array_equal(seen[k][0], log.T_world_ring_seen[k])
        assert np.linalg.norm(seen[k][0][:3, 3] - P_WORLD_RING) <= CENTRE_TOL_M
    centre, normal = estimate_errors(log, lambda t: np.repeat(T_ring[None], len(t), axis=0))
    assert len(centre) == 4
    assert centre.max() <= CENTRE_TOL_M and normal.max() <= NORMAL_TOL


def test_a_truth_log_keeps_its_columns_and_header() -> None:
    for carrier in ArmKind:
        assert not set(ESTIMATE_COLUMNS) & set(episode_column_names(carrier))
        stereo = episode_column_names(carrier, estimates=True)
        assert stereo[-1] == "reason" and set(ESTIMATE_COLUMNS) <= set(stereo)
    section = log_section(ArmKind.FREE, 60.0, DT_S)
    assert "estimates" not in section  # a truth run's scene.json is as before
    assert not LogHeader.from_scene({"log": section}, "scene.json").estimates
    on = log_section(ArmKind.FREE, 60.0, DT_S, estimates=True)
    assert LogHeader.from_scene({"log": on}, "scene.json").estimates
    with pytest.raises(MalformedLogError, match="estimates"):
        LogHeader.from_scene({"log": {**on, "estimates": "yes"}}, "scene.json")


def test_perception_config_is_checked() -> None:
    with pytest.raises(ValueError, match=r"perception\.source"):
        ExperimentConfig.model_validate({"perception": {"source": "sonar"}})
    with pytest.raises(ValueError, match="frame_rate"):
        stereo_config(frame_rate=200.0)  # above the 100 Hz control rate
    with pytest.raises(ValueError, match="ring_max_age"):
        stereo_config(processing_delay=0.5)


def test_the_track_filter_follows_a_steady_motion_and_damps_noise() -> None:
    frame_s = 1.0 / 30.0  # s
    speed = np.array([0.02, -0.01, 0.0])  # m/s
    n0 = np.array([0.0, 0.0, 1.0])
    steady = TrackFilter(0.35, 0.06)
    for j in range(60):
        x = steady.update(j * frame_s, speed * j * frame_s, n0)
    assert np.linalg.norm(x[:3] - speed * 59 * frame_s) <= STEADY_TOL_M  # no lag when steady
    rng = np.random.default_rng(0)
    noisy = TrackFilter(0.35, 0.06)
    raw, out = [], []
    for j in range(300):
        tilt = rng.normal(0.0, NOISE_RAD, 2)
        n = np.array([tilt[0], tilt[1], 1.0])
        raw.append(math.acos(1.0 / np.linalg.norm(n)))
        out.append(math.acos(min(1.0, noisy.update(j * frame_s, np.zeros(3), n)[5])))
    assert np.median(out[30:]) <= 0.6 * np.median(raw[30:])  # a still ring: noise damped
    x = noisy.update(300 * frame_s + 1.0, np.ones(3), np.array([1.0, 0.0, 0.0]))  # after a gap
    assert np.array_equal(x, np.array([1.0, 1.0, 1.0, 1.0, 0.0, 0.0]))  # restarted


def test_the_track_filter_clips_a_wild_estimate_and_still_follows_a_real_change() -> None:
    """An estimate far beyond the filter's gates moves its pose by at most alpha times the gate
    (no jump for the controller's gate to refuse); a real, lasting change is followed."""
    frame_s = 1.0 / 30.0  # s
    alpha, gate_m, gate_rad = 0.2, 2.0e-3, math.radians(6.0)  # -, m, rad
    f = TrackFilter(alpha, 0.02, gate_m, gate_rad)
    n0 = np.array([0.0, 0.0, 1.0])
    for j in range(10):
        x = f.update(j * frame_s, np.zeros(3), n0)
    turned = np.array([0.0, math.sin(8 * gate_rad), math.cos(8 * gate_rad)])  # 48° off
    y = f.update(10 * frame_s, np.array([10 * gate_m, 0.0, 0.0]), turned)
    assert np.linalg.norm(y[:3] - x[:3]) <= alpha * gate_m * (1 + 1e-9)
    assert math.acos(min(1.0, float(y[3:] @ x[3:]))) <= alpha * gate_rad * (1 + 1e-9)
    assert f.clipped == 1
    moved = np.array([0.01, 0.0, 0.0])  # m: the ring is now 1 cm away, for good
    for j in range(11, 11 + 10 * 30):  # 10 s
        y = f.update(j * frame_s, moved, n0)
    assert np.linalg.norm(y[:3] - moved) <= STEADY_TOL_M  # followed


def test_the_track_filter_gives_the_normal_its_own_gains() -> None:
    """One estimate's innovation, within the gates: the centre takes its alpha of it and the
    normal the normal's; without ``alpha_normal`` both take the centre's."""
    frame_s = 1.0 / 30.0  # s
    alpha, alpha_n = 0.2, 0.6  # -
    n0, p1 = np.array([0.0, 0.0, 1.0]), np.array([1.0e-3, 0.0, 0.0])  # -, m
    tilt = math.radians(3.0)  # rad, under the default gate
    n1 = np.array([0.0, math.sin(tilt), math.cos(tilt)])
    for gain, expected in ((alpha_n, alpha_n), (None, alpha)):
        f = TrackFilter(alpha, 0.0, alpha_normal=gain)
        f.update(0.0, np.zeros(3), n0)
        y = f.update(frame_s, p1, n1)
        np.testing.assert_allclose(y[:3], alpha * p1, atol=1e-15)  # m
        turned = math.atan2(y[4], y[5])  # rad, about x
        blended = math.atan2(expected * math.sin(tilt), 1.0 - expected + expected * math.cos(tilt))
        assert turned == pytest.approx(blended, abs=1e-12)  # rad


GAIN_TOL = 1e-12  # -, gains of order one from a few square roots


@pytest.mark.parametrize("alpha", [0.1, 0.35, 0.7, 0.9])
@pytest.mark.parametrize("scale", [0.25, 1.0, 4.0, 16.0])
def test_depth_scaled_gains_are_kalatas_for_the_scaled_tracking_index(
    alpha: float, scale: float
) -> None:
    """Kalata's pairs satisfy Λ² = β² / (1 − α) (the tracking index, process over measurement
    noise): starting from one (α, Kalata's β), a noise ``scale`` times larger gives the pair
    whose index is the reference's over ``scale``, and larger noise lower gains."""
    beta = 2.0 * (2.0 - alpha) - 4.0 * math.sqrt(1.0 - alpha)  # Kalata's β for alpha
    a, b = depth_scaled_gains(alpha, beta, scale)
    index_ref = beta / math.sqrt(1.0 - alpha)
    assert b / math.sqrt(1.0 - a) == pytest.approx(index_ref / scale, abs=GAIN_TOL)
    assert b == pytest.approx(2.0 * (2.0 - a) - 4.0 * math.sqrt(1.0 - a), abs=GAIN_TOL)
    if scale > 1.0:
        assert a < alpha and b < beta
    if scale == 1.0:
        assert (a, b) == (alpha, beta)


def test_the_track_filter_takes_a_far_estimate_with_less_gain() -> None:
    """With a reference depth, the same innovation moves the centre by the reference gain at
    that depth, less four times farther, more nearer; the normal's gain does not change."""
    frame_s, alpha, beta, depth_ref = 1.0 / 30.0, 0.7, 0.4, 0.05  # s, -, -, m
    p1 = np.array([1.0e-3, 0.0, 0.0])  # m, under the default gate
    n0 = np.array([0.0, 0.0, 1.0])
    moved = {}
    for depth in (0.025, depth_ref, 0.2):  # m
        f = TrackFilter(alpha, beta, alpha_normal=0.2, beta_normal=0.02, reference_depth=depth_ref)
        f.update(0.0, np.zeros(3), n0, depth)
        moved[depth] = f.update(frame_s, p1, n0, depth)[0] / p1[0]
    assert moved[depth_ref] == pytest.approx(alpha, abs=GAIN_TOL)
    assert moved[0.2] == pytest.approx(depth_scaled_gains(alpha, beta, 16.0)[0], abs=GAIN_TOL)
    assert moved[0.2] < alpha < moved[0.025]


def test_the_normal_gain_follows_the_paths_motion_not_the_estimators_noise() -> None:
    """A still ring seen with the estimator's noise keeps the configured normal gain; a ring
    whose normal jitters by several times that noise raises it to the cap, with Kalata's β;
    the gain rule between: α = 1 − noise² / m²."""
    frame_s, noise = 1.0 / 30.0, math.radians(0.9)  # s, rad
    adapt = NormalAdaptation(noise, alpha_max=0.4, frames=90)
    alpha_n, beta_n = 0.2, 0.02  # the configured (least) gains
    assert adapt.gains(noise, alpha_n, beta_n) == (alpha_n, beta_n)
    typical = noise / math.sqrt(1.0 - 0.3)  # the innovation at which α is 0.3
    a, b = adapt.gains(typical, alpha_n, beta_n)
    assert a == pytest.approx(0.3, abs=GAIN_TOL)
    assert b == pytest.approx(beta_n * kalata_beta(0.3) / kalata_beta(alpha_n), abs=GAIN_TOL)
    rng = np.random.default_rng(3)
    still = TrackFilter(0.7, 0.4, alpha_normal=alpha_n, beta_normal=beta_n, adapt=adapt)
    for j in range(300):
        tilt = rng.normal(0.0, noise / math.sqrt(2.0), 2)  # rad, per axis: |tilt| ~ noise
        still.update(j * frame_s, np.zeros(3), np.array([tilt[0], tilt[1], 1.0]))
    assert still.gains[2:] == (alpha_n, beta_n)
    jitter = TrackFilter(0.7, 0.4, alpha_normal=alpha_n, beta_normal=beta_n, adapt=adapt)
    for j in range(300):
        swing = 5.0 * noise * math.sin(2.0 * math.pi * 3.0 * j * frame_s)  # rad, 3 Hz
        jitter.update(j * frame_s, np.zeros(3), np.array([math.sin(swing), 0.0, math.cos(swing)]))
    assert jitter.gains[2:] == pytest.approx(
        (0.4, beta_n * kalata_beta(0.4) / kalata_beta(alpha_n))
    )
    assert jitter.gains[:2] == still.gains[:2] == (0.7, 0.4)  # the centre's are its own


def test_no_estimate_moves_the_given_pose_past_the_gates_floors() -> None:
    """A fast filter's step (its pose predicted across the delay and lead, before and after
    one estimate) stays within the observation gate's floors with a step limit, and not
    without: the limit, not the gains, keeps the gate from refusing the filter's own poses."""
    frame_s, horizon = 1.0 / 30.0, 0.1  # s: a frame; the capture's delay plus the lead
    floor_m, floor_rad = 1.0e-3, math.radians(3.0)  # m, rad: the stereo floors
    limit = StepLimit(floor_m, floor_rad, horizon)
    n0 = np.array([0.0, 0.0, 1.0])
    turn = math.radians(5.0)  # rad, inside the filter's own 6° gate
    p1, n1 = np.array([1.8e-3, 0.0, 0.0]), np.array([0.0, math.sin(turn), math.cos(turn)])
    steps = {}
    for name, lim in (("limited", limit), ("free", None)):
        f = TrackFilter(0.7, 0.4, alpha_normal=0.4, beta_normal=0.09, step_limit=lim)
        for j in range(5):
            f.update(j * frame_s, np.zeros(3), n0)
        before = f.x + f.v * (frame_s + horizon)  # the given pose at the next frame, predicted
        after = f.update(5 * frame_s, p1, n1)
        after = after + f.v * horizon
        n_a, n_b = after[3:] / np.linalg.norm(after[3:]), before[3:] / np.linalg.norm(before[3:])
        steps[name] = (
            float(np.linalg.norm(after[:3] - before[:3])),
            math.acos(min(1.0, float(n_a @ n_b))),
        )
    assert steps["limited"][0] <= floor_m * (1 + 1e-9) < steps["free"][0]
    assert steps["limited"][1] <= floor_rad * (1 + 1e-6) < steps["free"][1]


def test_an_adaptation_capped_below_the_fixed_gain_is_refused() -> None:
    with pytest.raises(ValueError, match="filter_alpha_normal_max"):
        stereo_config(
            filter_normal_noise=0.01, filter_alpha_normal=0.5, filter_alpha_normal_max=0.4
        )


def test_the_controller_is_given_the_track_predicted_to_now_until_it_is_too_old() -> None:
    """The track (centre, normal and rates) predicted across its age and the lead, stamped
    with the control time; past max_age: the pose at its capture with its capture stamp (so
    the controller's stale rule holds the camera)."""
    v = np.array([0.01, -0.02, 0.0])  # m/s
    track = np.concatenate([P_WORLD_RING, [0.0, 0.0, 1.0], v, [0.0, 0.0, 0.0]])
    t_capture, lead, max_age = 1.0, 0.04, 0.25  # s
    T, stamp = resampled(track, t_capture, t_capture + 0.1, lead, max_age)
    assert stamp == t_capture + 0.1
    np.testing.assert_allclose(T[:3, 3], P_WORLD_RING + v * (0.1 + lead), atol=TIME_TOL_S)
    T, stamp = resampled(track, t_capture, t_capture + max_age + DT_S, lead, max_age)
    assert stamp == t_capture
    np.testing.assert_allclose(T[:3, 3], P_WORLD_RING, atol=TIME_TOL_S)


def test_the_registration_is_the_prior_until_the_first_estimate() -> None:
    """Before any estimate the setup's normal settles ambiguous pairs however long it takes
    (the PSM's far start); after one, its normal does for ``max_age`` only."""
    T_cam = look_at_pose(P_WORLD_RING + np.array([0.0, -DISTANCE_M, 0.0]), P_WORLD_RING)
    n = R_WORLD_RING[:, 2]
    max_age = 1.0  # s
    before = prior_normal(30.0, math.inf, n, T_cam, max_age)
    assert before is not None
    np.testing.assert_allclose(before, T_cam[:3, :3].T @ n, atol=TIME_TOL_S)
    assert prior_normal(30.0, 29.5, n, T_cam, max_age) is not None
    assert prior_normal(30.0, 28.5, n, T_cam, max_age) is None
