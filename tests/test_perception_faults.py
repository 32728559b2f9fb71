"""Faults on the stereo path: the ring faults applied to what the perception source delivers.

A delivered sequence of poses (a ring moving along x, stamped with the step time) stands in for
the stereo source's output: no rendering, no kernel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam.config import ExperimentConfig
from endocam.faults import DeliveredFaults, FaultsConfig, fault_schedule

pytestmark = pytest.mark.no_kernels

DT_S = 0.01  # s, control period
N = 400  # control steps
SPEED_M_S = 0.05  # m/s, the delivered ring's speed along world x
ATOL_M = 1e-12  # m, round-off on centimetre offsets
ATOL_RAD = 1e-9  # rad, arccos of a unit dot product near 5°


def _delivered() -> tuple[np.ndarray, np.ndarray]:
    """(N, 4, 4) poses, world, m, and (N,) stamps, s: what a source gave without faults."""
    t = np.arange(N) * DT_S
    T = np.tile(np.eye(4), (N, 1, 1))
    T[:, 0, 3] = SPEED_M_S * t
    return T, t


def _given(faults: FaultsConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the controller is given at each step under ``faults``, and the schedule's labels."""
    schedule = fault_schedule(faults, N, DT_S, arm=False)
    applied = DeliveredFaults(schedule, DT_S)
    T, t = _delivered()
    out = [applied.apply(k, T, t) for k in range(N)]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out]), schedule.labels()


def test_the_validator_accepts_faults_with_stereo_perception() -> None:
    cfg = ExperimentConfig.model_validate(
        {"perception": {"source": "stereo"}, "faults": {"ring_outlier": {"rate": 1.0}}}
    )
    assert cfg.faults.any and cfg.perception.stereo


def test_a_small_outlier_moves_the_delivered_pose_by_its_size_on_the_faulty_steps_only() -> None:
    distance, angle = 0.02, math.radians(5.0)  # m, rad: the small fault of docs/safety.md
    faults = FaultsConfig(
        ring_outlier={"rate": 1.0, "burst": 0.2, "distance": distance, "angle": angle}
    )
    T_given, _, labels = _given(faults)
    T, _ = _delivered()
    faulty = labels == "ring_outlier"
    assert faulty.any() and not faulty.all()
    shift = np.linalg.norm(T_given[:, :3, 3] - T[:, :3, 3], axis=1)
    turn = np.arccos(np.clip(np.einsum("ni,ni->n", T_given[:, :3, 2], T[:, :3, 2]), -1.0, 1.0))
    np.testing.assert_allclose(shift[faulty], distance, atol=ATOL_M)
    np.testing.assert_allclose(turn[faulty], angle, atol=ATOL_RAD)
    assert np.all(shift[~faulty] == 0.0) and np.all(turn[~faulty] == 0.0)


def test_a_nan_fault_gives_a_non_finite_pose_on_its_steps() -> None:
    T_given, _, labels = _given(FaultsConfig(ring_nan={"rate": 1.0, "burst": 0.1}))
    faulty = labels == "ring_nan"
    assert faulty.any()
    finite = np.isfinite(T_given).all(axis=(1, 2))
    assert not finite[faulty].any() and finite[~faulty].all()


def test_a_dropout_gives_no_pose_and_a_frozen_tracker_an_ageing_one() -> None:
    max_age = ExperimentConfig().controller.ring_max_age  # s
    burst = 2.0 * max_age  # s
    faults = FaultsConfig(
        ring_dropout={"rate": 0.5, "burst": burst}, tracker_frozen={"rate": 1.0, "burst": burst}
    )
    T_given, t_given, labels = _given(faults)
    T, t = _delivered()
    dropout = np.array(["ring_dropout" in s for s in labels])
    frozen = (labels == "tracker_frozen") & ~dropout
    assert dropout.any() and frozen.any()
    assert np.isnan(T_given[dropout]).all()
    first = int(np.argmax(frozen))
    np.testing.assert_array_equal(
        T_given[frozen], np.broadcast_to(T[first - 1], T_given[frozen].shape)
    )
    assert (t[frozen] - t_given[frozen]).max() > max_age  # the controller's stale rule holds it
    clean = ~dropout & ~frozen
    assert np.array_equal(t_given[clean], t[clean]) and np.array_equal(T_given[clean], T[clean])


def test_a_latency_spike_gives_an_older_estimate() -> None:
    extra = 0.1  # s
    faults = FaultsConfig(latency_spike={"rate": 1.0, "burst": 0.2, "extra_delay": extra})
    T_given, t_given, labels = _given(faults)
    _, t = _delivered()
    faulty = labels == "latency_spike"
    assert faulty.any()
    np.testing.assert_allclose(t[faulty] - t_given[faulty], extra, atol=1e-9)
    np.testing.assert_allclose(T_given[faulty, 0, 3], SPEED_M_S * t_given[faulty], atol=ATOL_M)


class _NoScene:
    """Stands in for the renderer: the stereo source's wiring is tested, not its images."""

    arm = None

    def __init__(self, *args: object, **kwargs: object) -> None:
        pass

    def close(self) -> None:
        pass


def _stereo_given(
    monkeypatch: pytest.MonkeyPatch, faults: FaultsConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a stereo source (its estimate: the true pose) gives the controller at each step."""
    from endocam.runner import ring_source
    from endocam.runner.episode import episode_world
    from endocam.task.trajectory import TrajectoryKind, make_trajectory

    def capture(self, k: int, T_world_cam: np.ndarray, q: np.ndarray) -> None:  # type: ignore[no-untyped-def]
        t, T = float(self.world.t[k]), self.world.T_world_ring[k]
        track = np.concatenate([T[:3, 3], T[:3, 2], np.zeros(6)])
        self._pending.append(ring_source._Pending(t + self.delay, t, T, track))

    monkeypatch.setattr(ring_source, "WireChaserScene", _NoScene)
    monkeypatch.setattr(ring_source.RingModel, "from_task", staticmethod(lambda *a: None))
    monkeypatch.setattr(ring_source.StereoSource, "_capture", capture)
    cfg = ExperimentConfig.model_validate(
        {
            "task": {"trajectory": {"duration": 3.0}},
            "perception": {"source": "stereo"},
            "faults": faults.model_dump(),
        }
    )
    world = episode_world(cfg, make_trajectory(cfg.task, TrajectoryKind.IDEAL, seed=0))
    dt = 1.0 / cfg.episode.control_rate
    schedule = fault_schedule(cfg.faults, world.n, dt, arm=False)
    source = ring_source.StereoSource(
        cfg,
        world,
        ring_source.ArmKind.FREE,
        0,
        world.T_world_ring[0],
        DeliveredFaults(schedule, dt),
    )
    out = [source.sense(k, np.eye(4), np.zeros(0)) for k in range(world.n)]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out]), schedule.labels()


def test_the_stereo_source_gives_the_controller_the_faulted_estimate(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    max_age = ExperimentConfig().controller.ring_max_age  # s
    faults = FaultsConfig(  # seed 3: NaN bursts within and apart from two dropouts
        seed=3,
        ring_nan={"rate": 1.0, "burst": 0.1},
        ring_dropout={"rate": 0.5, "burst": 2.0 * max_age},
    )
    T_clean, t_clean, _ = _stereo_given(monkeypatch, FaultsConfig())
    T_given, t_given, labels = _stereo_given(monkeypatch, faults)
    nan = np.array(["ring_nan" in s for s in labels])
    dropout = np.array(["ring_dropout" in s for s in labels])
    assert nan.any() and dropout.any()
    assert not np.isfinite(T_given[nan | dropout]).all(axis=(1, 2)).any()  # refused: hold
    assert np.isnan(T_given[dropout]).all()  # no estimate at all
    clean = ~nan & ~dropout
    np.testing.assert_array_equal(T_given[clean], T_clean[clean])
    np.testing.assert_array_equal(t_given[clean], t_clean[clean])


def test_a_frozen_or_late_pose_carries_its_capture_time_not_the_prediction_stamp() -> None:
    """A source that predicts to the present stamps its pose now; repeated as old, the pose
    carries when its information was captured, so the stale rule counts that age."""
    delay_s = 0.06  # s, the capture's age behind each stamp
    faults = FaultsConfig(
        tracker_frozen={"rate": 1.0, "burst": 0.3}, latency_spike={"rate": 1.0, "burst": 0.3}
    )
    schedule = fault_schedule(faults, N, DT_S, arm=False)
    applied = DeliveredFaults(schedule, DT_S)
    T, t = _delivered()
    captured = t - delay_s
    old = schedule.mask("tracker_frozen") | schedule.mask("latency_spike")
    assert old.any()
    for k in np.flatnonzero(old):
        _, stamp = applied.apply(int(k), T, t, captured)
        _, stamp_now = applied.apply(int(k), T, t)
        assert stamp == pytest.approx(stamp_now - delay_s, abs=1e-12)  # s
