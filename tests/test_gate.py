"""The observation gate after a gap: the true ring taken back within ``ring_confirm`` by the
bridge across the gap, an outlier burst that begins as the gap ends refused, and the safety
check's matching (weaker) promise for such bursts. Pure functions on short pose sequences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam.control.config import ControllerConfig
from endocam.control.gate import RingGate, outlier_detected
from endocam.faults import fault_names
from endocam.runner.check import outlier_after_gap

DT = 0.01  # s: the default control period
TRACK_S = 0.1  # s: the ring observed before the gap
AFTER_S = 1.0  # s: observed after it (longer than a burst and ring_reacquire)
ACCEL = 0.2  # m/s²: the ring's centre accelerates during the gap (4× the default task's)
ANGULAR_ACCEL = 3.0  # rad/s²: the normal's turn accelerates (the fault matrix's pace)
SPEED = 0.01  # m/s: the centre's speed when the gap begins
RATE = 0.5  # rad/s: the normal's rate when the gap begins
GAPS_S = (0.25, 0.3, 0.4)  # s: gaps long enough that the cap alone refuses the ring after them
OUTLIERS = [(0.02, 0.0), (0.0, 15.0)]  # m, deg: the smallest offsets promised after a gap
BURST_S = 0.3  # s: an outlier burst (the fault matrix's)


def ring(t: np.ndarray, t_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Centres (N, 3), m, and unit normals (N, 3) of a ring that accelerates from ``t_gap`` s.

    Before ``t_gap``: constant velocity (centre along x, the normal turning about x at
    ``RATE``); after: the centre accelerates at ``ACCEL`` along y, the turn at
    ``ANGULAR_ACCEL``. Its constant-velocity prediction across a gap drifts off by
    ``½ a Δt²``; the trapezoid bridge between the two tracks' velocities does not.
    """
    late = np.clip(t - t_gap, 0.0, None)
    p = np.zeros((len(t), 3))
    p[:, 0] = SPEED * t
    p[:, 1] = 0.5 * ACCEL * late**2
    p[:, 2] = 0.05
    angle = RATE * t + 0.5 * ANGULAR_ACCEL * late**2
    n = np.stack([np.zeros_like(t), -np.sin(angle), np.cos(angle)], axis=1)
    return p, n


def gap_run(
    gate: RingGate, gap: float, offset: tuple[float, float] = (0.0, 0.0), seed: int = 0
) -> np.ndarray:
    """Feed ``gate`` the ring, a gap of ``gap`` s, then the ring again; returns the answers
    (bool, one per pose after the gap). ``offset`` (m, deg): an outlier burst of ``BURST_S``
    s beginning with the first pose after the gap (centre moved in a random direction, the
    normal turned about a random axis in the ring's face)."""
    rng = np.random.default_rng(seed)
    before = np.arange(round(TRACK_S / DT) + 1) * DT
    p, n = ring(before, TRACK_S)
    gate.reset()
    assert all(gate.accept(t, p[k], n[k]) for k, t in enumerate(before))
    after = TRACK_S + gap + np.arange(round(AFTER_S / DT)) * DT
    p, n = ring(after, TRACK_S)
    burst = after < TRACK_S + gap + BURST_S - DT / 2
    u = rng.normal(size=3)
    p[burst] += offset[0] * u / np.linalg.norm(u)
    face = np.cross(n[0], rng.normal(size=3))
    face /= np.linalg.norm(face)
    for k in np.flatnonzero(burst):  # Rodrigues: n turned about an axis in the face
        c, s = math.cos(math.radians(offset[1])), math.sin(math.radians(offset[1]))
        n[k] = c * n[k] + s * np.cross(face, n[k]) + (1 - c) * np.dot(face, n[k]) * face
    return np.array([gate.accept(t, p[k], n[k]) for k, t in enumerate(after)])


@pytest.mark.parametrize("gap", GAPS_S)
def test_a_ring_that_moved_during_a_gap_is_taken_back_within_confirm(gap: float) -> None:
    """The first pose after the gap lies beyond the capped innovation (refused as it comes),
    and the ring is taken back by the bridge once the run has agreed for ``ring_confirm``, not
    after ``ring_reacquire`` (fails without the gap rule)."""
    cfg = ControllerConfig()
    answers = gap_run(cfg.ring_gate(), gap)
    drift_m = 0.5 * ACCEL * gap**2  # the constant-velocity prediction's error
    drift_rad = 0.5 * ANGULAR_ACCEL * gap**2
    assert drift_m > cfg.ring_gate_position or drift_rad > cfg.ring_gate_angle
    assert not answers[0]
    first = int(np.argmax(answers))
    assert answers[first] and first * DT <= cfg.ring_confirm + DT / 2
    assert first * DT < cfg.ring_reacquire / 2
    assert answers[first:].all()  # and kept


@pytest.mark.parametrize(("distance", "angle_deg"), OUTLIERS)
@pytest.mark.parametrize("gap", GAPS_S)
def test_an_outlier_burst_that_begins_as_a_gap_ends_is_refused(
    distance: float, angle_deg: float, gap: float
) -> None:
    """2 cm and 15° bursts (promised: ``outlier_detected(after_gap=True)``) from the first pose
    after the gap: none of them is taken, whatever its direction; the true ring after the
    burst is taken back by ``ring_reacquire``."""
    cfg = ControllerConfig()
    limits = cfg.ring_limits
    assert outlier_detected(distance, math.radians(angle_deg), limits, after_gap=True)
    burst = round(BURST_S / DT)
    for seed in range(4):
        answers = gap_run(cfg.ring_gate(), gap, (distance, angle_deg), seed)
        assert not answers[:burst].any()
        assert answers[burst + round(cfg.ring_reacquire / DT) + 1 :].all()


def test_the_promise_after_a_gap_is_twice_the_gap_caps() -> None:
    """One definition: beyond the innovation caps while observed; beyond twice the gap caps
    (what the ring itself may do across a gap, plus that much again) right after a gap."""
    limits = ControllerConfig().ring_limits
    for after_gap, (d_m, a_rad) in (
        (False, (limits.position_gate, limits.angle_gate)),
        (True, (2 * limits.gap_position, 2 * limits.gap_angle)),
    ):
        assert not outlier_detected(d_m, 0.0, limits, after_gap=after_gap)
        assert not outlier_detected(0.0, a_rad, limits, after_gap=after_gap)
        assert outlier_detected(1.01 * d_m, 0.0, limits, after_gap=after_gap)
        assert outlier_detected(0.0, 1.01 * a_rad, limits, after_gap=after_gap)
    assert not outlier_detected(0.01, 0.0, limits, after_gap=True)  # 1 cm: not promised
    assert not outlier_detected(0.0, math.radians(5.0), limits, after_gap=True)  # 5°: not


def test_the_check_marks_outlier_bursts_that_follow_a_gap() -> None:
    """A burst right after (or overlapping) a dropout or stale pose is judged by the weaker
    promise, and so is the next one unless ``settle`` clean steps lie between (the gate may
    have taken the first and judge against it); one that begins among fresh poses is not."""
    column = [
        "",
        "ring_outlier",  # among fresh poses
        "",
        "ring_dropout",
        "ring_outlier",  # right after a gap
        "",
        "ring_outlier",  # 1 clean step after a weak burst: still weak
        "",
        "",
        "",
        "ring_outlier",  # 3 clean steps: the true ring is back
        "latency_spike",
        "",
        "ring_outlier",  # a burst that a dropout interrupts
        "ring_dropout+ring_outlier",  # the burst overlaps a gap
        "ring_outlier",
    ]
    marked = outlier_after_gap([fault_names(f) for f in column], settle=3)
    expected = [False, False, False, False, True, False, True, False, False, False, False]
    expected += [False, False, True, True, True]
    assert marked.tolist() == expected
