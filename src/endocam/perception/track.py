"""The track filter between the stereo estimator and the controller.

Each estimate (the ring's centre and unit face normal, world) updates an alpha-beta filter
(:class:`TrackFilter`): a constant-velocity prediction, each innovation clipped to a gate (a
Huber filter) and taken in with a gain. The gains follow what the estimate is worth:

* **the centre's, its depth** (:func:`depth_scaled_gains`): a stereo centre's error grows as
  the square of its depth, so the far estimates of the approach weigh little and the near ones
  of the working band a lot;
* **the normal's, the path's own motion** (:class:`NormalAdaptation`): the estimator's normal
  error is about the same on every path, while the ring's normal jitters on the noisy paths
  and not on the ideal ones; the typical innovation over the last seconds against the
  estimator's own noise sets the gain.

Pure Python on small numpy arrays; world frame, m, unit normals.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from endocam.geometry import FloatArray

FILTER_GATE_M = 2.0e-3
"""m: the track filter's centre gate: the raw estimator's centre error was 0.23 mm at the p95
and 2.1 mm at the max over 300 pairs (bench/perception_estimator.py, image model on)."""
FILTER_GATE_RAD = math.radians(6.0)
"""rad: the filter's normal gate: the raw normal error was 3.9° at the p95, 16.5° at the max;
an estimate 6° or more off moves the filter's pose by at most alpha × 6° (1.2° at the default
alpha), under the controller gate's stereo floor (3°)."""
FILTER_RESET_S = 0.25  # s, a gap between estimates longer than this restarts the track filter


def depth_scaled_gains(alpha: float, beta: float, scale: float) -> tuple[float, float]:
    """An alpha-beta filter's gains for a measurement noise ``scale`` times the reference's.

    ``alpha``, ``beta``: the gains at the reference noise. Kalata's optimal steady-state
    alpha-beta filter (the constant-velocity Kalman filter's gains, Kalata 1984, "The
    tracking index") has one parameter, the tracking index ``Λ = σ_a T² / σ_v`` (process
    noise over measurement noise), with ``α = 1 − r²``, ``β = 2 (2 − α) − 4 r`` and
    ``r = (4 + Λ − √(Λ² + 8 Λ)) / 4``. Here ``Λ`` is the one whose ``α`` is ``alpha``,
    divided by ``scale``; each gain is returned as the given one times the ratio of Kalata's
    gain at that index to his at the reference (so ``scale = 1`` returns ``alpha, beta``).
    """
    if not 0.0 < alpha < 1.0 or scale == 1.0:
        return alpha, beta
    r_ref = math.sqrt(1.0 - alpha)
    index = 2.0 * (1.0 - r_ref) ** 2 / r_ref / scale  # Kalata's Λ for alpha, over the scale
    r = (4.0 + index - math.sqrt(index * index + 8.0 * index)) / 4.0
    a = 1.0 - r * r
    return a, kalata_scaled_beta(beta, alpha, a)


def kalata_beta(alpha: float) -> float:
    """Kalata's optimal ``β`` for an alpha-beta filter's ``α`` in [0, 1).

    ``β = 2 (2 − α) − 4 √(1 − α)``.
    """
    return 2.0 * (2.0 - alpha) - 4.0 * math.sqrt(1.0 - alpha)


def kalata_scaled_beta(beta: float, alpha_ref: float, alpha: float) -> float:
    """A configured ``beta`` (given at ``alpha_ref``) moved along Kalata's curve to ``alpha``.

    ``beta`` times the ratio of Kalata's ``β`` at ``alpha`` to his at ``alpha_ref``.
    """
    b_ref = kalata_beta(alpha_ref)
    return beta * kalata_beta(alpha) / b_ref if b_ref > 0.0 else beta


def chord(angle: float) -> float:
    """The chord between two unit vectors ``angle`` rad apart (capped at π)."""
    return 2.0 * math.sin(0.5 * min(angle, math.pi))


@dataclass(frozen=True)
class NormalAdaptation:
    """The normal's gain set by the path's own motion (see :meth:`TrackFilter.update`).

    The typical (median) normal innovation ``m`` over the last ``frames`` estimates (the
    chord between the estimate and the prediction, ≈ rad) is set against the estimator's own
    noise ``noise``: a Kalman filter's steady state has an innovation variance ``S = R / (1 −
    α)``, so ``α = 1 − noise² / m²``, kept within [the configured ``alpha_normal``,
    ``alpha_max``]; ``β`` is the configured ``beta_normal`` times the ratio of Kalata's ``β``
    at that ``α`` to his at the configured one. A median over seconds, not a running mean:
    the estimator's errors come in bursts (an ambiguous choice near the axis, a partly hidden
    rim) that a mean would take for motion, and raise the gain exactly when the estimates
    are worst.

    Attributes
    ----------
    noise : float
        rad: the estimator's typical normal error on a still ring.
    alpha_max : float
        The largest normal gain, in (0, 1).
    frames : int
        Estimates in the median (at 30 frames/s, 90 is 3 s).
    """

    noise: float
    alpha_max: float
    frames: int = 90

    def __post_init__(self) -> None:
        if not (math.isfinite(self.noise) and self.noise > 0.0):
            raise ValueError(f"noise must be finite and > 0 rad, got {self.noise}")
        if not 0.0 < self.alpha_max < 1.0:
            raise ValueError(f"alpha_max must be in (0, 1), got {self.alpha_max}")
        if self.frames < 1:
            raise ValueError(f"frames must be ≥ 1, got {self.frames}")

    def gains(self, typical: float, alpha: float, beta: float) -> tuple[float, float]:
        """(α, β) of the normal for a typical innovation ``typical`` (≈ rad).

        ``alpha``, ``beta``: the configured (least) gains.
        """
        a = 1.0 - (self.noise / typical) ** 2 if typical > 0.0 else 0.0
        a = min(self.alpha_max, max(alpha, a))
        return a, kalata_scaled_beta(beta, alpha, a)


@dataclass(frozen=True)
class StepLimit:
    """How far one estimate may move the pose the controller is given.

    On delivery the given pose (the track predicted ``horizon`` s past its capture: the
    delay and the carrier's lead, ``perception.loop.resampled``) moves by ``(α + β ·
    horizon / Δt)`` times the estimate's innovation. The filter clips each innovation so that
    this step stays within the observation gate's stereo floors (``position``, m; ``angle``,
    rad): a faster filter then never hands the gate a step it refuses, and the gate still
    refuses what a fault adds after the filter. At round 15's gains (0.2 / 0.02) the limits
    lay beyond the filter's own gates (2 mm, 6°); at the centre's 0.7 / 0.4 (50 mm, 30
    frames/s, 0.1 s horizon) its clip is 1 mm / 1.9 ≈ 0.5 mm; the normal's (0.2 / 0.02) stays
    the filter's own 6°.
    """

    position: float
    angle: float
    horizon: float


class TrackFilter:
    """An alpha-beta filter on the estimated ring centre and normal (world), per estimate.

    The estimator's normal is noisy near the ring's axis (1–5°, docs/perception.md); the
    filter takes ``alpha`` of each innovation into the pose and ``beta / Δt`` of it into the
    rates (constant-velocity prediction: no lag on a steady motion). An innovation longer
    than ``gate_position`` (m, the centre) or ``gate_angle`` (rad, the normal) is clipped to
    that length first (a Huber filter): a bad fit or a wrong choice of normal moves the pose
    by at most ``alpha`` times the gate, and a real change the filter lags is still followed,
    at most that much per estimate, with no jump the controller's gate would refuse. A gap
    longer than :data:`FILTER_RESET_S` restarts it at the estimate. ``alpha = 1, beta = 0``
    and infinite gates: the raw estimates. ``alpha_normal``, ``beta_normal``: the normal's
    gains (``None``: the centre's).

    ``reference_depth`` (m, or None): the depth at which the centre's gains are ``alpha``,
    ``beta``. A stereo centre's error grows as the square of its depth (the disparity's
    error over ``f b / d²``), so an estimate at depth ``d`` is taken with the gains
    :func:`depth_scaled_gains` gives for a noise ``(d / reference_depth)²`` times the
    reference's: the far estimates of the approach (10–250 mm) weigh little, the near ones
    of the working band a lot. None: fixed gains.

    ``adapt``: the normal's gain set by the path's own motion (:class:`NormalAdaptation`);
    None: the normal's gains are fixed. ``step_limit``: the innovations are clipped further so
    that no estimate moves the given pose past the observation gate's floors
    (:class:`StepLimit`). A restart keeps the innovations seen (the path's
    character outlasts a gap).
    """

    def __init__(
        self,
        alpha: float,
        beta: float,
        gate_position: float = math.inf,
        gate_angle: float = math.pi,
        alpha_normal: float | None = None,
        beta_normal: float | None = None,
        reference_depth: float | None = None,
        adapt: NormalAdaptation | None = None,
        step_limit: StepLimit | None = None,
    ) -> None:
        a_n = alpha if alpha_normal is None else alpha_normal
        b_n = beta if beta_normal is None else beta_normal
        self._gains = (alpha, beta)  # the centre's at the reference depth
        self._gains_normal = (a_n, b_n)  # the normal's, the least adaptation gives
        self.reference_depth = reference_depth
        self.adapt = adapt
        self.step_limit = step_limit
        self._innovations: deque[float] = deque(maxlen=1 if adapt is None else adapt.frames)
        self._alpha = np.array([alpha] * 3 + [a_n] * 3)  # (6,): the centre's, the normal's
        self._beta = np.array([beta] * 3 + [b_n] * 3)
        self.gate_position = gate_position
        self.gate_normal = chord(gate_angle)  # unit normals: the gate as a chord
        self.t: float | None = None
        self.x = np.zeros(6)  # centre (m), unit normal
        self.v = np.zeros(6)  # their rates, m/s and 1/s
        self.clipped = 0  # estimates whose innovation was clipped, since the start

    def _gates(self, dt: float) -> tuple[float, float]:
        """The centre's (m) and the normal's (chord) innovation clips for a frame ``dt`` s."""
        lim = self.step_limit
        if lim is None:
            return self.gate_position, self.gate_normal
        k = lim.horizon / dt
        step_p = lim.position / float(self._alpha[0] + self._beta[0] * k)
        step_n = chord(lim.angle) / float(self._alpha[3] + self._beta[3] * k)
        return min(self.gate_position, step_p), min(self.gate_normal, step_n)

    @property
    def gains(self) -> tuple[float, float, float, float]:
        """The gains the last estimate was taken with: the centre's α, β, the normal's α, β."""
        return (
            float(self._alpha[0]),
            float(self._beta[0]),
            float(self._alpha[3]),
            float(self._beta[3]),
        )

    def update(
        self,
        t: float,
        p_world: FloatArray,
        n_world: FloatArray,
        depth: float | None = None,
        one_eye: bool = False,
    ) -> FloatArray:
        """The filtered (6,) centre (m) and unit normal after the estimate at ``t`` s.

        ``depth`` (m): the estimate's depth in the camera, for the centre's gains (ignored
        without a ``reference_depth``) and, with an adaptation, the normal's noise, taken to
        grow as the centre's (the disparity plane's tilt error grows as ``d²``): a typical
        innovation is set against the noise at that depth. ``one_eye``: a pose from one eye
        (status ``mono``), whose normal a prior chose: with an adaptation its normal is taken
        with the least gains and its innovation left out of the median.
        """
        scale = None
        if self.reference_depth is not None and depth is not None:
            scale = (depth / self.reference_depth) ** 2
            self._alpha[:3], self._beta[:3] = depth_scaled_gains(*self._gains, scale)
        z = np.concatenate([p_world, n_world])
        dt = math.inf if self.t is None else t - self.t
        if not 0.0 < dt <= FILTER_RESET_S:
            self.x, self.v = z, np.zeros(6)
        else:
            predicted = self.x + self.v * dt
            r = z - predicted
            if self.adapt is not None and one_eye:
                self._alpha[3:], self._beta[3:] = self._gains_normal
            elif self.adapt is not None:
                self._innovations.append(float(np.linalg.norm(r[3:])))
                typical = float(np.median(self._innovations))
                noise_scale = 1.0 if scale is None else scale  # the normal's noise grows too
                gains = self.adapt.gains(typical / noise_scale, *self._gains_normal)
                self._alpha[3:], self._beta[3:] = gains
            clipped = False
            for part, gate in zip((slice(0, 3), slice(3, 6)), self._gates(dt), strict=True):
                length = float(np.linalg.norm(r[part]))
                if length > gate:
                    r[part] *= gate / length
                    clipped = True
            self.clipped += clipped
            self.x = predicted + self._alpha * r
            self.v = self.v + (self._beta / dt) * r
            self.x[3:] /= np.linalg.norm(self.x[3:])
        self.t = t
        return self.x.copy()
