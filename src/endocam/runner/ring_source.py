"""The stereo ring source: the controller fed what the endoscope sees (``perception.source``).

:class:`StereoSource` is the :class:`endocam.runner.step.RingSource` the episode loop asks each
step when ``perception.source = "stereo"``. At every capture step
(:func:`endocam.perception.loop.capture_steps`, ``perception.frame_rate``) it renders both eyes
at the camera pose of that step (the ring, PSM2 and the camera arm as they are then), applies
the image model (seeded from the run's seed), runs the stereo estimator, and queues the
estimate, taken to the world frame through the camera pose at capture, for delivery
``sensing_latency + processing_delay`` s after the capture. The controller is given the last
estimate delivered, stamped with its capture time: no estimate, no new observation (the
controller's stale-pose and gate rules apply as to any observation); before the first one,
nothing (a NaN pose: the controller holds).

The delay is stated (``perception.processing_delay``), not measured, so a run repeats; the
estimator's wall and CPU times per frame are logged apart (:class:`EstimateLog`). This module
renders (MuJoCo), so ``run_episode`` imports it only for a stereo run.
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import NamedTuple

import numpy as np

from endocam.camera import Eye
from endocam.config import ExperimentConfig
from endocam.faults import DeliveredFaults
from endocam.geometry import FloatArray
from endocam.perception.estimator import EstimateStatus, RingModel, estimate_ring_detail
from endocam.perception.image_model import ImageModelConfig, degrade
from endocam.perception.loop import (
    CAPTURE_TOL_S,
    EstimateLog,
    capture_steps,
    estimate_in_world,
    prior_normal,
    resampled,
    ring_pose,
)
from endocam.perception.track import StepLimit, TrackFilter
from endocam.robot.actuator import ArmKind
from endocam.runner.step import EpisodeWorld
from endocam.sim.render import WireChaserScene

RIM_POINTS = 24  # points on the ring's core circle: the highlights' candidate sites
PRIOR_MAX_AGE = 1.0  # s, the last estimate settles an ambiguous normal for this long
"""Before the first estimate the setup's registration is the prior, without a lapse (the PSM's
far start view gave only `ambiguous` pairs once a 0.2 s prior had lapsed, and never
approached). A prior settles a choice only when one hypothesis lies within a quarter of the
two's separation of it (``EstimatorConfig.prior_fraction``)."""
MAX_BLUR_PX = 48.0  # px, the longest motion blur applied: past it the ring is a smear either way
IMAGE_STREAM = 26  # the image model's stream of the run's seed (issue 26), apart from others


class _Pending(NamedTuple):
    t_deliver: float  # s
    t_capture: float  # s
    T_world_ring: FloatArray  # (4, 4), m
    track: FloatArray  # (12,): the filter's centre (m), normal, and their rates (m/s, 1/s)


class StereoSource:
    """The loop's ring source on the stereo estimator (see the module docstring).

    Parameters
    ----------
    config : ExperimentConfig
        Its ``perception`` section is stereo; ``camera`` gives the render size.
    world : EpisodeWorld
        The episode's true world (ring poses and tool tips per step, before any fault).
    kind : ArmKind
        The carrier: a PSM or ECM is drawn at the joints the loop passes.
    seed : int
        The run's seed; the image model draws from ``default_rng((seed, IMAGE_STREAM))``.
    T_world_ring_start : (4, 4)
        The ring pose the controller is given at its reset (the setup's registration), m:
        its normal is the estimator's prior until the first estimate.
    faults : DeliveredFaults, optional
        The run's ring faults, applied to what the source gives the controller at each step
        (``T_world_ring_seen`` logs the faulted pose; ``est_*`` the estimator's own).
    """

    def __init__(
        self,
        config: ExperimentConfig,
        world: EpisodeWorld,
        kind: ArmKind,
        seed: int,
        T_world_ring_start: FloatArray,
        faults: DeliveredFaults | None = None,
    ) -> None:
        per, ep = config.perception, config.episode
        self.camera = config.camera.stereo()
        self.world = world
        self.scene = WireChaserScene(config.task, self.camera, arm=kind)
        self.model = RingModel.from_task(config.task, self.camera)
        self.image = ImageModelConfig() if per.image_model else None
        self.rng = np.random.default_rng((seed, IMAGE_STREAM))
        self.delay = ep.sensing_latency + per.processing_delay
        tracker = config.controller.tracker
        self.lead = tracker.carrier_lead if tracker.predict else 0.0
        self.resample = per.resample
        self.max_age = config.controller.ring_max_age
        self._track: tuple[float, FloatArray] | None = None  # capture time, (12,) filter state
        self.filter = TrackFilter(
            per.filter_alpha,
            per.filter_beta,
            per.filter_gate_position,
            per.filter_gate_angle,
            per.filter_alpha_normal,
            per.filter_beta_normal,
            per.filter_reference_depth,
            per.normal_adaptation(),
            StepLimit(per.gate_floor_position, per.gate_floor_angle, self.delay + self.lead),
        )
        self.dt = 1.0 / ep.control_rate
        self._rim = _rim(config.task.ring.major_radius)
        n = world.n
        self._frames = capture_steps(n, self.dt, per.frame_rate)
        self._is_frame = np.zeros(n, dtype=bool)
        self._is_frame[self._frames] = True
        self._pending: deque[_Pending] = deque()
        self._k = -1
        self._now: tuple[FloatArray, float] = (np.full((4, 4), np.nan), 0.0)
        self._given = self._now  # what the controller is given at step _k (faults applied)
        self._prev_cam: FloatArray | None = None
        # the last estimate's time and normal (world): the estimator's prior (before the
        # first estimate: the setup's registration, which does not lapse)
        self._last: tuple[float, FloatArray] = (math.inf, np.array(T_world_ring_start[:3, 2]))
        self.p_world = np.full((n, 3), np.nan)
        self.n_world = np.full((n, 3), np.nan)
        self.t_capture = np.full(n, np.nan)
        self.T_seen = np.full((n, 4, 4), np.nan)
        self.faults = faults
        self._T_given = np.full((n, 4, 4), np.nan)  # what was given without faults
        self._t_given = np.zeros(n)
        self._t_captured = np.zeros(n)  # when what was given was captured, s
        self.t_seen = np.array(world.t, dtype=float)
        self.lost = np.zeros(n, dtype=bool)
        self._last_capture = -math.inf  # the last delivered estimate's capture time, s
        self.frame_ok: list[bool] = []
        self.frame_status: list[str] = []
        self.frame_wall: list[float] = []
        self.frame_cpu: list[float] = []

    def sense(self, k: int, T_world_cam: FloatArray, q: FloatArray) -> tuple[FloatArray, float]:
        """The last estimate delivered by step ``k`` and its capture time (see RingSource).

        Steps are asked in order (a step may be asked again); ``T_world_cam`` (4, 4) and ``q``
        are the camera and the carrier's joints at the start of step ``k``.
        """
        if k == self._k:
            return self._given
        if k != self._k + 1:
            raise RuntimeError(f"StereoSource: step {k} asked after step {self._k}")
        self._k = k
        t = float(self.world.t[k])
        if self._is_frame[k]:
            self._capture(k, T_world_cam, q)
        self._prev_cam = T_world_cam
        while self._pending and self._pending[0].t_deliver <= t + CAPTURE_TOL_S:
            got = self._pending.popleft()
            self._now = (got.T_world_ring, got.t_capture)
            self._track = (got.t_capture, got.track)
            self._last_capture = got.t_capture
            self.p_world[k] = got.T_world_ring[:3, 3]
            self.n_world[k] = got.T_world_ring[:3, 2]
            self.t_capture[k] = got.t_capture
        if self.resample and self._track is not None:
            self._now = resampled(self._track[1], self._track[0], t, self.lead, self.max_age)
        self.lost[k] = not t - self._last_capture <= self.max_age
        if not math.isfinite(self._now[0][0, 0]):
            self._now = (self._now[0], t)  # nothing yet: a missing pose stamped now
        self._given = self._now
        if self.faults is not None:
            self._T_given[k], self._t_given[k] = self._now
            # the information's own age: a resampled pose is stamped now, its estimate earlier
            last = self._last_capture
            self._t_captured[k] = last if math.isfinite(last) else self._now[1]
            self._given = self.faults.apply(k, self._T_given, self._t_given, self._t_captured)
        self.T_seen[k] = self._given[0]
        if math.isfinite(self._given[0][0, 0]):
            self.t_seen[k] = self._given[1]
        return self._given

    def _capture(self, k: int, T_world_cam: FloatArray, q: FloatArray) -> None:
        """Render, degrade and estimate frame ``k``; queue its estimate for delivery."""
        scene, world = self.scene, self.world
        T_ring = world.T_world_ring[k]
        scene.set_ring_pose(T_ring)
        scene.set_psm2_tip(world.p_world_tips[k, 1])
        scene.set_camera_pose(T_world_cam)
        if scene.arm is not None:
            scene.set_arm_joints(q)
        left, right = scene.render("left"), scene.render("right")
        if self.image is not None:
            left = self._degrade(left, "left", k, T_world_cam)
            right = self._degrade(right, "right", k, T_world_cam)
        t0, c0 = time.perf_counter(), time.thread_time()
        prior = self._prior(k, T_world_cam)
        tracked = math.isfinite(self._last[0])  # a delivered estimate, not the registration
        out = estimate_ring_detail(left, right, self.model, prior=prior, mono=tracked)
        self.frame_wall.append(time.perf_counter() - t0)
        self.frame_cpu.append(time.thread_time() - c0)
        self.frame_status.append(out.status.value)
        self.frame_ok.append(out.estimate is not None)
        if out.estimate is not None:
            t = float(world.t[k])
            T_est = estimate_in_world(out.estimate, T_world_cam, self._last[1])
            depth = float(out.estimate.p_cam_ring[2])
            one_eye = out.status is EstimateStatus.MONO
            x = self.filter.update(t, T_est[:3, 3], T_est[:3, 2], depth, one_eye)
            T_est = ring_pose(x[:3], x[3:])
            track = np.concatenate([x, self.filter.v])
            self._pending.append(_Pending(t + self.delay, t, T_est, track))
            self._last = (t, T_est[:3, 2])

    def _prior(self, k: int, T_world_cam: FloatArray) -> FloatArray | None:
        """The estimator's prior at step ``k`` (:func:`~endocam.perception.loop.prior_normal`)."""
        t_last, n_last = self._last
        return prior_normal(float(self.world.t[k]), t_last, n_last, T_world_cam, PRIOR_MAX_AGE)

    def _degrade(self, image: np.ndarray, eye: Eye, k: int, T_world_cam: FloatArray) -> np.ndarray:
        """``image`` through the image model, blurred by the ring's image velocity in ``eye``.

        The velocity is the backward difference over the last control step; the highlights'
        sites are the ring's rim.
        """
        assert self.image is not None
        cam, world = self.camera, self.world
        T_ring = world.T_world_ring[k]
        velocity = np.zeros(2)
        if k > 0 and self._prev_cam is not None:
            uv1 = cam.project(T_world_cam, T_ring[:3, 3], eye)
            uv0 = cam.project(self._prev_cam, world.T_world_ring[k - 1, :3, 3], eye)
            if np.all(np.isfinite(uv0)) and np.all(np.isfinite(uv1)):
                velocity = (uv1 - uv0) / self.dt
        blur = float(np.hypot(*velocity)) * self.image.exposure
        if blur > MAX_BLUR_PX:  # a jump of the projection (near the eye's plane), not a blur
            velocity *= MAX_BLUR_PX / blur
        rim = self._rim @ T_ring[:3, :3].T + T_ring[:3, 3]
        sites = cam.project(T_world_cam, rim, eye)
        sites = sites[np.all(np.isfinite(sites), axis=1)]
        return degrade(image, self.image, self.rng, velocity, sites)

    def log(self) -> EstimateLog:
        """What the source did over the episode (the steps asked so far)."""
        return EstimateLog(
            p_world=self.p_world,
            n_world=self.n_world,
            t_capture=self.t_capture,
            T_world_ring_seen=self.T_seen,
            t_ring_seen=self.t_seen,
            frame_steps=self._frames[: len(self.frame_ok)],
            frame_ok=np.array(self.frame_ok, dtype=bool),
            frame_status=np.array(self.frame_status, dtype=str),
            frame_wall_s=np.array(self.frame_wall, dtype=float),
            frame_cpu_s=np.array(self.frame_cpu, dtype=float),
            lost=self.lost[: self._k + 1],
            dt_s=self.dt,
            filter_clipped=self.filter.clipped,
        )

    def close(self) -> None:
        """Free the renderer."""
        self.scene.close()


def _rim(radius: float) -> FloatArray:
    """(RIM_POINTS, 3) points on a circle of ``radius`` m about the ring frame's z, m."""
    phi = np.linspace(0.0, 2.0 * math.pi, RIM_POINTS, endpoint=False)
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), np.zeros_like(phi)], axis=1)
