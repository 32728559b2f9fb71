"""The wire's centre line as first interpolated: a chord-length cubic spline and its arc length.

:class:`endocam.task.wire.Wire` re-fits this curve against its arc length; the config's
validation (:class:`endocam.task.config.TaskConfig`: the end margins must leave some wire) reads
the same length, so the two never disagree.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
from scipy.integrate import cumulative_simpson
from scipy.interpolate import BSpline, make_interp_spline

from endocam.geometry import FloatArray

PARAM_SAMPLES = 20001  # count, dense samples of the chord-length spline for the arc-length map


def chord_spline(knots: Sequence[Sequence[float]]) -> tuple[BSpline, FloatArray, FloatArray]:
    """The natural cubic spline through ``knots`` by chord length, sampled with its arc length.

    knots : (K, 3) points in world, m, K ≥ 4, no two consecutive ones equal.
    Returns ``(param, u, s)``: the spline ``param(u)`` (world, m) of the chord parameter u (m),
    ``u`` (PARAM_SAMPLES,) evenly from 0 to the chord length, m, and ``s`` (PARAM_SAMPLES,) the
    arc length from the first knot at each ``u``, m (composite Simpson on ``|param'(u)|``).
    """
    k = np.asarray(knots, dtype=float)
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(k, axis=0), axis=1))])
    param = make_interp_spline(chord, k, k=3, bc_type="natural")
    u = np.linspace(0.0, chord[-1], PARAM_SAMPLES)
    speed = np.linalg.norm(param.derivative()(u), axis=1)
    s = np.concatenate([[0.0], cumulative_simpson(speed, x=u)])
    return param, u, s


@functools.lru_cache(maxsize=16)
def centre_line_length(knots: tuple[tuple[float, float, float], ...]) -> float:
    """Arc length of the wire's centre line through ``knots`` (world, m), m (cached by knots)."""
    return float(chord_spline(knots)[2][-1])
