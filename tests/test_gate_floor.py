"""The observation gate's noise floor is the observation source's: 0.5 mm / 0.5° on truth (the
limits as before), the perception section's on stereo, with the caps raised by the floor's
rise; stereo-sized noise passes the stereo floor, and 3 mm / 6° jumps are still refused."""

from __future__ import annotations

import math
from dataclasses import astuple

import numpy as np
import pytest

from endocam.config import ExperimentConfig
from endocam.control.gate import FLOOR_M, FLOOR_RAD, RingGate, RingLimits, outlier_detected
from endocam.perception.loop import PerceptionConfig

DT = 0.01  # s: the default control period (the stereo source's resampled stream)
SPEED = 0.013  # m/s: the default task's fastest ring
RATE = 0.2  # rad/s: the normal's turn
NOISE_M = 0.1e-3  # m: per-step centre noise, about the filtered estimates' (docs/perception.md)
NOISE_RAD = math.radians(0.5)  # rad: per-step normal noise, per axis
WILD_M, WILD_RAD = 0.020, math.radians(45.0)  # issue 26: never passed to the controller
BURST_S = 0.3  # s: an outlier burst (the fault matrix's)
STEPS = 300  # control steps observed


def stereo_config() -> ExperimentConfig:
    return ExperimentConfig(perception=PerceptionConfig(source="stereo"))


def ring(n: int, seed: int, noise: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (n,), s; centres (n, 3), m; unit normals (n, 3): a ring moving and turning
    steadily, with seeded per-step noise when ``noise``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    p = np.stack([SPEED * t, np.zeros(n), np.full(n, 0.05)], axis=1)
    n_ = np.stack([np.zeros(n), -np.sin(RATE * t), np.cos(RATE * t)], axis=1)
    if noise:
        p += rng.normal(scale=NOISE_M, size=p.shape)
        n_ += rng.normal(scale=NOISE_RAD, size=n_.shape)
        n_ /= np.linalg.norm(n_, axis=1, keepdims=True)
    return t, p, n_


def accepted(limits: RingLimits, t: np.ndarray, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    gate = RingGate(limits)
    gate.reset()
    return np.array([gate.accept(t[k], p[k], n[k]) for k in range(len(t))])


def test_truth_keeps_its_floor_and_limits() -> None:
    """On truth the floor is the module's default and the limits are unchanged by it."""
    config = ExperimentConfig()
    assert config.controller_on_source is config.controller
    limits = config.controller.ring_limits
    assert (limits.floor_position, limits.floor_angle) == (FLOOR_M, FLOOR_RAD)
    assert astuple(limits.with_floor(FLOOR_M, FLOOR_RAD)) == astuple(limits)


def test_stereo_takes_the_perception_floor_and_raises_the_caps_by_its_rise() -> None:
    """The stereo floor replaces the truth floor; each cap rises by the floor's rise, and the
    gate's promise still refuses anything off by 20 mm or 45° (observed or after a gap)."""
    config = stereo_config()
    per, truth = config.perception, config.controller.ring_limits
    limits = config.controller_on_source.ring_limits
    assert (limits.floor_position, limits.floor_angle) == (
        per.gate_floor_position,
        per.gate_floor_angle,
    )
    rise_m, rise_rad = per.gate_floor_position - FLOOR_M, per.gate_floor_angle - FLOOR_RAD
    assert rise_m > 0 and rise_rad > 0
    assert limits.position_gate == pytest.approx(truth.position_gate + rise_m)
    assert limits.gap_position == pytest.approx(truth.gap_position + rise_m)
    assert limits.angle_gate == pytest.approx(truth.angle_gate + rise_rad)
    assert limits.gap_angle == pytest.approx(truth.gap_angle + rise_rad)
    for after_gap in (False, True):
        assert outlier_detected(WILD_M * 1.001, 0.0, limits, after_gap=after_gap)
        assert outlier_detected(0.0, WILD_RAD * 1.001, limits, after_gap=after_gap)


def test_stereo_noise_passes_the_stereo_floor_not_the_truth_floor() -> None:
    """Per-step noise the size of the filtered estimates' is refused often by the truth floor
    (each refusal holds the camera) and rarely by the stereo floor (fails without the field)."""
    t, p, n = ring(STEPS, 0, noise=True)
    truth = ExperimentConfig().controller.ring_limits
    stereo = stereo_config().controller_on_source.ring_limits
    share_truth = accepted(truth, t, p, n).mean()
    share_stereo = accepted(stereo, t, p, n).mean()
    assert share_stereo >= 0.95
    assert share_truth < share_stereo - 0.2


@pytest.mark.parametrize(("offset_m", "offset_deg"), [(0.003, 0.0), (0.0, 6.0), (0.025, 50.0)])
def test_stereo_refuses_jumps_beyond_its_floor_and_motion_bound(
    offset_m: float, offset_deg: float
) -> None:
    """A burst of 3 mm or 6° (beyond the stereo floor + ½ a Δt² at the control rate) or a wild
    one, from a tracked noisy ring: no pose of it is taken; the ring after it is, at the latest
    once its own run has agreed for ``reacquire`` (the gate's rates are differenced from noisy
    poses, so its prediction across the burst may miss the ring's return)."""
    limits = stereo_config().controller_on_source.ring_limits
    step_m = limits.floor_position + 0.5 * limits.max_acceleration * DT**2
    step_rad = limits.floor_angle + 0.5 * limits.max_angular_acceleration * DT**2
    assert offset_m > step_m or math.radians(offset_deg) > step_rad
    start, burst = STEPS // 3, round(BURST_S / DT)
    back = start + burst + 2 * round(limits.reacquire / DT)  # the return's own run, at most
    for seed in range(3):
        t, p, n = ring(STEPS, seed, noise=True)
        rng = np.random.default_rng(100 + seed)
        u = rng.normal(size=3)
        p[start : start + burst] += offset_m * u / np.linalg.norm(u)
        axis = np.cross(n[start], rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        c, s = math.cos(math.radians(offset_deg)), math.sin(math.radians(offset_deg))
        for k in range(start, start + burst):  # Rodrigues about an axis in the face
            n[k] = c * n[k] + s * np.cross(axis, n[k]) + (1 - c) * np.dot(axis, n[k]) * axis
        answers = accepted(limits, t, p, n)
        assert not answers[start : start + burst].any()
        assert answers[back:].mean() > 0.9
