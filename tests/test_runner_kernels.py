"""The episode runner's compiled pieces are the numpy code they replaced, bit for bit."""

from __future__ import annotations

import math

import numpy as np

from endocam.runner.episode import _MIN_LOOK_M, _look_distance

N_OPERANDS = 100_000  # random pose pairs (numpy's strided ddot against blasfloat.dot3)


def _numpy_look_distance(T_cmd: np.ndarray, T_ring: np.ndarray, d_f: float) -> float:
    """``episode._look_distance`` as it was (numpy, interpreted)."""
    with np.errstate(invalid="ignore", over="ignore"):  # inf − inf, 0 · inf: NaN
        depth = float((T_ring[:3, 3] - T_cmd[:3, 3]) @ T_cmd[:3, 2])
    return depth if depth > _MIN_LOOK_M and math.isfinite(depth) else d_f


def test_look_distance_is_numpys() -> None:
    """Random poses over six decades, with signed zeros, infinities and NaN: the same float."""
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
        got, want = _look_distance(T_cmd, T_ring, d_f), _numpy_look_distance(T_cmd, T_ring, d_f)
        assert repr(got) == repr(want)
        kinds.add(got == d_f)
    assert kinds == {True, False}
