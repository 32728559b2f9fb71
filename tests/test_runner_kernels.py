"""The episode loop's look distance (endocam.view) against the numpy formula (a tolerance)."""

from __future__ import annotations

import math

import numpy as np

from endocam.view import MIN_LOOK_M, look_distance

N_OPERANDS = 20_000  # count: random pose pairs, over six decades of scale
RTOL = 1e-12  # unitless: a 3-term dot product's round-off relative to its terms' magnitude


def _numpy_look_distance(T_cmd: np.ndarray, T_ring: np.ndarray, d_f: float) -> float:
    with np.errstate(invalid="ignore", over="ignore"):  # inf − inf, 0 · inf: NaN
        depth = float((T_ring[:3, 3] - T_cmd[:3, 3]) @ T_cmd[:3, 2])
    return depth if depth > MIN_LOOK_M and math.isfinite(depth) else d_f


def test_look_distance_is_the_numpy_depth_within_round_off() -> None:
    """Random poses, signed zeros, infinities and NaN: the depth, or ``d_f`` where numpy's is."""
    rng = np.random.default_rng(3)
    specials = [0.0, -0.0, math.inf, -math.inf, math.nan]
    kinds = set()
    for _ in range(N_OPERANDS):
        T_cmd = rng.normal(size=(4, 4)) * 10.0 ** float(rng.integers(-3, 3))
        T_ring = rng.normal(size=(4, 4)) * 10.0 ** float(rng.integers(-3, 3))
        if rng.random() < 0.02:
            T_cmd[int(rng.integers(0, 3)), int(rng.choice([2, 3]))] = rng.choice(specials)
        if rng.random() < 0.02:
            T_ring[int(rng.integers(0, 3)), 3] = rng.choice(specials)
        d_f = float(rng.uniform(0.03, 0.1))
        got, want = look_distance(T_cmd, T_ring, d_f), _numpy_look_distance(T_cmd, T_ring, d_f)
        with np.errstate(invalid="ignore", over="ignore"):
            terms = float(np.abs(T_ring[:3, 3] - T_cmd[:3, 3]) @ np.abs(T_cmd[:3, 2]))
        if math.isfinite(terms) and abs(want - MIN_LOOK_M) <= RTOL * terms:
            continue  # at the threshold either answer is right
        assert math.isclose(got, want, rel_tol=0.0, abs_tol=RTOL * max(terms, d_f)), (got, want)
        kinds.add(got == d_f)
    assert kinds == {True, False}  # both branches taken


def test_a_ring_behind_or_at_the_camera_gives_the_working_distance() -> None:
    T = np.eye(4)
    ring = np.eye(4)
    ring[:3, 3] = (0.0, 0.0, 0.05)
    assert look_distance(T, ring, 0.07) == 0.05  # 5 cm ahead on z: its depth
    ring[:3, 3] = (0.01, 0.0, -0.05)
    assert look_distance(T, ring, 0.07) == 0.07  # behind: d_f
    ring[:3, 3] = (0.0, 0.0, 0.5 * MIN_LOOK_M)
    assert look_distance(T, ring, 0.07) == 0.07  # too close to pivot about
