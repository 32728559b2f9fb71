"""The control loop on perception: its settings, its frame schedule and what it logs.

With ``perception.source = "stereo"`` an episode's controller is fed what the stereo endoscope
sees (docs/perception.md, "The loop on perception")::

    capture (both eyes at the camera pose of the capture step, every 1/frame_rate s)
      → image model (seeded from the run's seed) → estimator (camera frame)
      → world frame through the camera pose at capture → delay (sensing_latency +
        processing_delay) → the observation, stamped with the capture time
      → the controller's checks (stale pose, the observation gate) → the controller

This module holds the parts that need no renderer: :class:`PerceptionConfig`, the capture
steps (:func:`capture_steps`), the estimate in world (:func:`estimate_in_world`), the
per-step log (:class:`EstimateLog`) and its error summary (:func:`estimation_summary`). The
source that renders, runs the estimator and delivers is ``endocam.runner.ring_source``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from endocam.geometry import FloatArray, frame_with_z
from endocam.perception.track import FILTER_GATE_M, FILTER_GATE_RAD, NormalAdaptation

if TYPE_CHECKING:
    from endocam.perception.estimator import RingEstimate

CAPTURE_TOL_S = 1e-9  # s, a frame due within this of a control step is captured at that step
MEASURED_PROCESSING_S = 0.010
"""s: the estimator's time per pair, bench/perception_estimator.py's median wall time on a
shared 2-core machine (7.7–9.7 ms over round 11's runs), rounded up: the default delay."""


STEREO_FLOOR_M = 1.0e-3
"""m: the gate's centre noise floor on stereo. The innovation the gate sees on the filtered
estimates (their constant-velocity prediction's miss, frame to frame) was 0.15-0.23 mm at the
p95 and 0.27-0.41 mm at the p99 over round 12's six free-camera episodes (docs/perception.md);
the raw estimator's centre error p95 0.23 mm (bench/perception_estimator.py): ~4× the p95."""
STEREO_FLOOR_RAD = math.radians(3.0)
"""rad: the gate's normal noise floor on stereo: the same innovation's p95 was 2.3-3.1° (p99
4.8-6.4°); the raw estimator's normal error p95 3.9°. Below 6°, so a 6° jump is refused."""


class PerceptionSource(enum.Enum):
    """Where the controller's ring pose comes from."""

    TRUTH = "truth"  # the simulator's true pose, ``episode.sensing_latency`` late
    STEREO = "stereo"  # the stereo estimator on the rendered, degraded endoscope images


class PerceptionConfig(BaseModel):
    """How the controller perceives the ring (frozen; ``truth``: as every run before).

    Attributes
    ----------
    source : PerceptionSource
    filter_alpha, filter_beta : float
        The alpha-beta track filter between the estimator and the controller
        (:class:`TrackFilter`).
    frame_rate : float
        The endoscope's frame rate, frames/s (≤ ``episode.control_rate``).
    processing_delay : float
        The estimator's processing time added to ``episode.sensing_latency``, s: stated, not
        the wall clock, so a run repeats (the measured wall time is logged apart).
    image_model : bool
        Degrade the rendered images (``ImageModelConfig()`` defaults) before the estimator.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    source: PerceptionSource = Field(
        PerceptionSource.TRUTH,
        description="Ring pose source: 'truth' (the simulator's pose, sensing_latency late) or "
        "'stereo' (the estimator on the rendered stereo images).",
    )
    frame_rate: float = Field(
        30.0, gt=0.0, le=240.0, description="Endoscope frame rate (stereo), frames/s."
    )
    processing_delay: float = Field(
        MEASURED_PROCESSING_S,
        ge=0.0,
        le=1.0,
        description="Estimator processing time added to the sensing latency (stereo), s "
        "(default: the bench's median, 7.7-9.7 ms, rounded up).",
    )
    image_model: bool = Field(
        True, description="Apply the image model (noise, blur, highlights, gain) (stereo)."
    )
    filter_alpha: float = Field(
        0.7,
        gt=0.0,
        le=1.0,
        description="Alpha-beta track filter on the estimates (stereo): the share of an "
        "estimate's centre innovation taken into the pose at filter_reference_depth (1 with "
        "beta 0: raw estimates). 0.7 / 0.4 (Kalata's pair): the centre's error, 0.02-0.05 mm "
        "at the working distance, is far below the noisy paths' jitter (docs/perception.md, "
        "'Round 16').",
    )
    filter_beta: float = Field(
        0.4,
        ge=0.0,
        lt=1.0,
        description="Alpha-beta track filter (stereo): the share of the centre's innovation "
        "per frame period taken into its rate, at filter_reference_depth.",
    )

    filter_alpha_normal: float | None = Field(
        0.2,
        gt=0.0,
        le=1.0,
        description="The track filter's alpha for the face normal (stereo; None: "
        "filter_alpha). 0.2: the normal's error (0.55 deg median) is not far below the "
        "paths' jitter, and faster gains cost the ideal paths (docs/perception.md).",
    )
    filter_beta_normal: float | None = Field(
        0.02,
        ge=0.0,
        lt=1.0,
        description="The track filter's beta for the face normal (stereo; None: filter_beta).",
    )

    filter_reference_depth: float | None = Field(
        0.05,
        gt=0.0,
        le=0.3,
        description="The depth at which the track filter's centre gains are filter_alpha / "
        "filter_beta, m (the working distance); at depth d they are Kalata's for a noise "
        "(d / this)² times as large (perception.track.depth_scaled_gains; stereo): the "
        "approach's far estimates weigh little. None: fixed gains.",
    )

    filter_normal_noise: float | None = Field(
        None,
        gt=0.0,
        le=math.radians(10.0),
        description="The estimator's typical normal error, rad: with it the track filter's "
        "normal gain follows the path's own motion (perception.track.NormalAdaptation), from "
        "filter_alpha_normal up to filter_alpha_normal_max (stereo). None: fixed gains.",
    )
    filter_alpha_normal_max: float = Field(
        0.4,
        gt=0.0,
        lt=1.0,
        description="The largest normal gain the adaptation gives (stereo; with "
        "filter_normal_noise).",
    )

    filter_gate_position: float = Field(
        FILTER_GATE_M,
        gt=0.0,
        description="The track filter clips an estimate's centre innovation to this length, "
        "m (stereo).",
    )
    filter_gate_angle: float = Field(
        FILTER_GATE_RAD,
        gt=0.0,
        le=math.pi,
        description="The track filter clips an estimate's normal innovation to this angle, "
        "rad (stereo).",
    )
    resample: bool = Field(
        True,
        description="Give the controller the track filter's pose at every control step, "
        "predicted across the capture's age and the carrier's lead and stamped with the "
        "step's time, up to controller.ring_max_age after the last capture (the controller's "
        "own prediction off); off: the last estimate held, stamped with its capture time, and "
        "the controller predicting from it.",
    )
    gate_floor_position: float = Field(
        STEREO_FLOOR_M,
        gt=0.0,
        le=0.01,
        description="The observation gate's centre noise floor on stereo, m (replaces "
        "controller.ring_gate_floor_position; docs/perception.md, 'The gate's floor').",
    )
    gate_floor_angle: float = Field(
        STEREO_FLOOR_RAD,
        gt=0.0,
        le=math.radians(20.0),
        description="The observation gate's normal noise floor on stereo, rad (replaces "
        "controller.ring_gate_floor_angle).",
    )

    @property
    def stereo(self) -> bool:
        """Whether the controller is fed the stereo estimator's poses."""
        return self.source is PerceptionSource.STEREO

    def normal_adaptation(self) -> NormalAdaptation | None:
        """The track filter's normal adaptation, or None (fixed gains)."""
        if self.filter_normal_noise is None:
            return None
        return NormalAdaptation(self.filter_normal_noise, self.filter_alpha_normal_max)

    @model_validator(mode="after")
    def _adaptation_above_the_fixed_gain(self) -> PerceptionConfig:
        alpha_n = (
            self.filter_alpha if self.filter_alpha_normal is None else self.filter_alpha_normal
        )
        if self.filter_normal_noise is not None and self.filter_alpha_normal_max < alpha_n:
            raise ValueError(
                f"perception.filter_alpha_normal_max ({self.filter_alpha_normal_max}) is below "
                f"the normal's fixed gain ({alpha_n})"
            )
        return self


def capture_steps(n: int, dt: float, frame_rate: float) -> np.ndarray:
    """(F,) int: the control steps at which the endoscope captures a frame.

    Frame ``j`` is due at ``j / frame_rate`` s and is captured at the first control step at or
    after it (within :data:`CAPTURE_TOL_S`); ``n`` steps of ``dt`` s. With ``frame_rate`` up to
    ``1 / dt`` every frame has its own step.
    """
    if n <= 0:
        return np.zeros(0, dtype=int)
    duration = (n - 1) * dt
    due = np.arange(0.0, duration + CAPTURE_TOL_S, 1.0 / frame_rate)
    steps = np.ceil(due / dt - CAPTURE_TOL_S / dt).astype(int)
    return np.unique(steps[steps < n])


def estimate_in_world(
    est: RingEstimate, T_world_cam: FloatArray, n_world_prior: FloatArray | None = None
) -> FloatArray:
    """(4, 4) the ring pose an estimate gives, world, m; its z the estimated face normal.

    ``T_world_cam`` (4, 4): the camera (rig centre, optical frame) at the capture, m. A ring
    has no front: the normal takes the sign of ``n_world_prior`` (3,) (the track's last
    normal, world), so the observations' normals do not flip when the camera changes side;
    without a prior, the estimator's (towards the camera). The ring's rotation about the
    normal is not observable (a torus): a rotation taking a world axis to it.
    """
    R_wc = T_world_cam[:3, :3]
    n = R_wc @ est.n_cam
    if n_world_prior is not None and float(n @ n_world_prior) < 0.0:
        n = -n
    return ring_pose(R_wc @ est.p_cam_ring + T_world_cam[:3, 3], n)


def ring_pose(p_world: FloatArray, n_world: FloatArray) -> FloatArray:
    """(4, 4) a ring pose with centre ``p_world`` (3,), m, and face normal ``n_world`` (3,).

    The normal is normalised; the rotation about it (not observable on a torus) takes a
    world axis to the normal.
    """
    n = n_world / np.linalg.norm(n_world)
    T = np.eye(4)
    T[:3, :3] = frame_with_z(n)
    T[:3, 3] = p_world
    return T


def resampled(
    track: FloatArray, t_capture: float, t: float, lead: float, max_age: float
) -> tuple[FloatArray, float]:
    """The ring pose the controller is given at control time ``t`` (s), and its stamp.

    ``track`` (12,): the track filter's centre (m), unit normal and their rates (m/s, 1/s),
    world, after the estimate captured at ``t_capture`` (s), the last one delivered. While
    ``t − t_capture ≤ max_age`` (s): the track predicted at constant velocity to ``t + lead``
    (across the capture's whole age and the carrier's lead, s), stamped ``t``: the filter,
    whose rates come from many frames, is the loop's one predictor (the controller's own,
    which differences 30 ms apart samples, amplified the estimates' noise ~10×; it is off on
    stereo, ``ExperimentConfig.controller_on_source``). Past ``max_age``: the filter's pose at
    the capture, stamped with it (stale: the controller holds). Returns (4, 4), m, and s.
    """
    if not t - t_capture <= max_age:
        return ring_pose(track[:3], track[3:6]), t_capture
    x = track[:6] + track[6:] * (t + lead - t_capture)
    return ring_pose(x[:3], x[3:6]), t


def prior_normal(
    t: float, t_last: float, n_world_last: FloatArray, T_world_cam: FloatArray, max_age: float
) -> FloatArray | None:
    """The estimator's prior at ``t`` (s): the last normal in this camera's frame, or None.

    ``n_world_last`` (3,): the last estimate's unit normal, world, captured at ``t_last`` (s;
    ``inf`` before the first estimate: then the setup's registration normal, which does not
    lapse); ``T_world_cam`` (4, 4) the camera now. None once the estimate is more than
    ``max_age`` (s) old.
    """
    if t - t_last > max_age:
        return None
    return np.asarray(T_world_cam[:3, :3].T @ n_world_last)


@dataclass(frozen=True)
class EstimateLog:
    """What the stereo source did over an episode (N control steps, F frames), SI, world.

    Attributes
    ----------
    p_world : (N, 3)
        The estimated ring centre delivered at each step, m; NaN where none was delivered.
    n_world : (N, 3)
        Its unit face normal (towards the camera at capture); NaN where none.
    t_capture : (N,)
        The capture time of the estimate delivered at each step, s; NaN where none.
    T_world_ring_seen : (N, 4, 4)
        The ring pose the controller was given at each step (the last delivered estimate;
        all NaN before the first), m.
    t_ring_seen : (N,)
        Its capture stamp, s (the step's time before the first estimate).
    frame_steps : (F,) int
        The control steps at which a frame was captured.
    frame_ok : (F,) bool
        Whether the frame gave an estimate.
    frame_status : (F,) str
        The estimator's status per frame (``EstimateStatus`` values).
    frame_wall_s : (F,)
        Measured wall time of the estimator per frame, s (not used by the loop).
    frame_cpu_s : (F,)
        Its thread CPU time per frame, s.
    lost : (K,) bool
        The steps asked so far on which the ring was lost: no estimate delivered yet, or the
        last one captured more than ``controller.ring_max_age`` before (the controller holds).
    dt_s : float
        The control period, s.
    filter_clipped : int
        Estimates whose innovation the track filter clipped to its gates.
    """

    p_world: FloatArray
    n_world: FloatArray
    t_capture: FloatArray
    T_world_ring_seen: FloatArray
    t_ring_seen: FloatArray
    frame_steps: np.ndarray
    frame_ok: np.ndarray
    frame_status: np.ndarray
    frame_wall_s: FloatArray
    frame_cpu_s: FloatArray
    lost: np.ndarray
    dt_s: float
    filter_clipped: int = 0

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: an estimate was delivered at the step."""
        return np.isfinite(self.t_capture)


def estimate_errors(log: EstimateLog, T_world_ring_at: Any) -> tuple[FloatArray, FloatArray]:
    """The delivered estimates' errors against the true ring pose at their capture.

    ``T_world_ring_at(t)``: the true ring poses (M, 4, 4) at times ``t`` (M,), s (a
    trajectory's ``poses``). Returns the centre errors (D,), m, and the normal errors up to
    sign (D,), rad, of the D delivered estimates.
    """
    ok = log.ok
    if not ok.any():
        return np.zeros(0), np.zeros(0)
    T_true = T_world_ring_at(log.t_capture[ok])
    centre = np.linalg.norm(log.p_world[ok] - T_true[:, :3, 3], axis=1)
    cos = np.abs(np.einsum("ij,ij->i", log.n_world[ok], T_true[:, :3, 2]))
    return centre, np.arccos(np.clip(cos, 0.0, 1.0))


def _stats(values: FloatArray, scale: float) -> dict[str, float | None]:
    if len(values) == 0:
        return {"median": None, "p95": None, "max": None}
    v = np.asarray(values) * scale
    return {
        "median": float(np.median(v)),
        "p95": float(np.percentile(v, 95.0)),
        "max": float(np.max(v)),
    }


def lost_summary(log: EstimateLog) -> dict[str, Any]:
    """Why the controller held for want of an estimate: the lost stretches and their frames.

    ``share`` of the steps lost, ``stretches`` (runs of lost steps), ``longest_s`` (s), and
    ``frame_status``: the estimator's status counts over the frames captured while lost
    (``no_ring``: the ring out of view or too small; ``ambiguous``, ``low_coverage``, ...).
    """
    lost = np.asarray(log.lost, dtype=bool)
    edges = np.diff(np.concatenate([[0], lost.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    steps = log.frame_steps
    during = log.frame_status[lost[steps[steps < len(lost)]]] if len(steps) else log.frame_status
    statuses, counts = np.unique(during, return_counts=True)
    return {
        "share": float(lost.mean()) if len(lost) else 0.0,
        "stretches": len(starts),
        "longest_s": float((ends - starts).max() * log.dt_s) if len(starts) else 0.0,
        "frame_status": {str(s): int(c) for s, c in zip(statuses, counts, strict=True)},
    }


def estimation_summary(log: EstimateLog, T_world_ring_at: Any) -> dict[str, Any]:
    """``metrics.json``'s ``perception`` section: errors (mm, deg), estimate share, time (ms)."""
    centre, normal = estimate_errors(log, T_world_ring_at)
    frames = len(log.frame_steps)
    statuses, counts = np.unique(log.frame_status, return_counts=True)
    return {
        "lost": lost_summary(log),
        "frames": frames,
        "estimate_share": float(np.mean(log.frame_ok)) if frames else 0.0,
        "frame_status": {str(s): int(c) for s, c in zip(statuses, counts, strict=True)},
        "filter_clipped": log.filter_clipped,
        "delivered": int(np.count_nonzero(log.ok)),
        "center_error_mm": _stats(centre, 1e3),
        "normal_error_deg": _stats(normal, math.degrees(1.0)),
        "estimator_time_ms": {
            "median_wall": float(np.median(log.frame_wall_s) * 1e3) if frames else None,
            "median_cpu": float(np.median(log.frame_cpu_s) * 1e3) if frames else None,
        },
    }
