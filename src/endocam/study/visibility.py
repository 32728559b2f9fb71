r"""The closing gap of a touch as an assessor's eye would have it: in sight, resolved, hidden by.

An assessor counts a touch by seeing the gap between ring and wire close. For each ground-truth
touch and camera this module measures that gap at one instant, the **closing instant**: the
first instant in the observer's "just before" window (``PRE_TOUCH_S`` before the onset) at which
the exact ring–wire clearance (:func:`endocam.task.touches.clearances`, sampled every
``GAP_SEEN_DT``) is down to ``GAP_SEEN`` (0.5 mm). There, at the gap's closest-approach point
(the midpoint of the gap) and for **each eye** of the stereo pair (∓baseline/2 along the camera's
x axis, ``camera.baseline`` of the config):

- ``in_sight``: the point projects inside the eye's image (in front of it) and a MuJoCo ray cast
  from the eye's optical centre reaches it (:meth:`~endocam.sim.render.WireChaserScene.occluder`,
  every geom: the wire's near part, the rim, the handle, an instrument, the board, the camera's
  arm; ``DEFAULT_RAY_TOLERANCE``, so the two tubes the gap lies between do not hide it);
- ``hidden_by``: ``OUTSIDE_IMAGE`` or the first geom in front of the point (None: in sight);
- ``gap_px``: how many pixels the ``GAP_SEEN`` gap spans in that eye's image,
  :math:`\mathrm{GAP\_SEEN}\cdot\lVert J_\pi(p)\,\hat u\rVert` with :math:`\hat u` the contact
  normal (wire centre → ring core circle, :func:`endocam.task.touches.contact_normal`) and
  :math:`J_\pi` the pinhole projection's Jacobian (:func:`pixel_scales`); 0 when the gap opens
  along the line of sight.

Per touch: ``in_sight_either`` (either eye sees it: what a stereo viewer, or a mono viewer given
the better eye, could see), ``gap_px`` (the largest span among the eyes that see it; among both
when neither does) and ``resolved`` = in sight in an eye whose span is at least ``RESOLVED_PX``.

Why these constants:

- ``GAP_SEEN = 0.5 mm``: the study's paths touch at least 0.25 mm deep or pass at least 1 mm
  clear (``task.study_paths.STUDY_LEGIBLE_BAND``); a gap of 0.5 mm, halfway to the clear pass,
  is still open, and whoever sees it open there and then shut has seen the touch begin.
- ``RESOLVED_PX = 2 px``: an interval at least 2 px long holds at least one whole pixel at every
  sub-pixel phase, so a pixel of background shows between ring and wire however the gap falls on
  the pixel grid; a narrower gap, at some phases, covers no whole pixel and blends into the
  silhouettes (sampling: 2 samples per smallest feature).

Summaries are shares of touches per condition with **seed-level** bootstrap 95 % intervals
(:func:`seed_bootstrap_ci`): the seeds (each a noise seed: one trajectory's video) are resampled
with replacement, not the touches, since touches of one seed share one camera path and are not
independent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike
from pydantic import BaseModel, ConfigDict

from endocam.camera import MIN_DEPTH, Eye, StereoCamera, points_in_eye
from endocam.geometry import FloatArray, as_pose, as_vector3
from endocam.study.observer import PRE_TOUCH_S
from endocam.task.touches import contact_normal

if TYPE_CHECKING:
    from endocam.runner.episode import EpisodeResult
    from endocam.sim.render import WireChaserScene

GAP_SEEN = 0.5e-3  # m, the closing gap: still open, halfway to the study's 1 mm clear pass
GAP_SEEN_DT = 1e-3  # s, sampling of the clearance when finding the closing instant
RESOLVED_PX = 2.0  # px, a gap this wide holds a whole pixel at every sub-pixel phase
EYES: tuple[Eye, Eye] = ("left", "right")
OUTSIDE_IMAGE = "outside the image"  # what hides a gap outside the eye's frustum
BOOTSTRAP_RESAMPLES = 4000  # count, seed-level bootstrap resamples
BOOTSTRAP_SEED = 0  # seed of the bootstrap's numpy generator (the intervals are reproducible)
CI_LEVEL = 0.95  # two-sided, percentile interval
# What hides a gap, by the scene's geom-name prefix (endocam.sim.scene); first match wins.
HIDER_KINDS = (
    ("wire", "wire"),
    ("ring_handle", "handle"),
    ("ring", "rim"),
    ("psm", "instrument"),
    ("board", "board"),
    ("post", "post"),
    ("wall", "box"),
    ("camera_arm", "camera arm"),
)


# --------------------------------------------------------------------------- pure geometry
def in_image(
    camera: StereoCamera, T_world_cam: ArrayLike, p_world: ArrayLike, eye: Eye = "left"
) -> bool:
    """Whether ``p_world`` (3,), m, projects inside ``eye``'s image (and lies in front of it)."""
    T = as_pose(T_world_cam, "T_world_cam")
    return bool(camera.in_image(T, as_vector3(p_world, "p_world"), eye))


def pixel_scales(
    camera: StereoCamera,
    T_world_cam: ArrayLike,
    p_world: ArrayLike,
    u_world: ArrayLike,
    eye: Eye = "left",
) -> tuple[float, float]:
    r"""Image scale at a point and the image length of a unit step along a direction.

    With the point in the eye frame :math:`(X, Y, Z)` and the direction :math:`(a, b, c)`, the
    projection's Jacobian gives the image velocity
    :math:`(f_x (a - c X/Z)/Z,\; f_y (b - c Y/Z)/Z)`.

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (4, 4)
        Camera pose (optical frame), m.
    p_world : (3,)
        Point in world, m.
    u_world : (3,)
        Unit direction in world.
    eye : {"left", "right"}

    Returns
    -------
    px_per_m : float
        :math:`f_y / Z`, px per m perpendicular to the line of sight at the point's depth
        (NaN behind the eye).
    step_px_per_m : float
        Image length of a step along ``u_world``, px per m (NaN behind the eye).
    """
    T = as_pose(T_world_cam, "T_world_cam")
    p = points_in_eye(camera, T, as_vector3(p_world, "p_world"), eye)[0]
    R_world_eye = (T @ camera.T_cam_eye(eye))[:3, :3]
    a, b, c = R_world_eye.T @ as_vector3(u_world, "u_world")
    K = camera.intrinsics.K
    if not p[2] >= MIN_DEPTH:
        return math.nan, math.nan
    du = K[0, 0] * (a - c * p[0] / p[2]) / p[2]
    dv = K[1, 1] * (b - c * p[1] / p[2]) / p[2]
    return float(K[1, 1] / p[2]), float(math.hypot(du, dv))


def hider_kind(name: str) -> str:
    """The kind of thing a geom is, for counting what hides gaps (``"wire"``, ``"rim"``, ...).

    Names not in ``HIDER_KINDS`` (``OUTSIDE_IMAGE``, an unnamed geom) are returned as they are.
    """
    return next((kind for prefix, kind in HIDER_KINDS if name.startswith(prefix)), name)


# ------------------------------------------------------------------------------ one gap
@dataclass(frozen=True)
class EyeGap:
    """What one eye sees of a closing gap.

    Attributes
    ----------
    in_sight : bool
        In the image and unoccluded.
    hidden_by : str or None
        ``OUTSIDE_IMAGE`` or the first geom in front of the gap; None when in sight.
    gap_px : float
        Image length of the ``GAP_SEEN`` gap along the contact normal, px (NaN behind the eye
        or when the normal is undefined).
    """

    in_sight: bool
    hidden_by: str | None
    gap_px: float


@dataclass(frozen=True)
class ClosingGap:
    """The closing gap of one touch from both eyes (module docstring).

    Attributes
    ----------
    t_s : float
        The closing instant, s (NaN when placed by hand).
    left, right : EyeGap
    """

    t_s: float
    left: EyeGap
    right: EyeGap

    def eye(self, eye: Eye) -> EyeGap:
        """The view of ``eye``."""
        return self.left if eye == "left" else self.right

    @property
    def in_sight_either(self) -> bool:
        """Either eye sees the gap."""
        return self.left.in_sight or self.right.in_sight

    @property
    def gap_px(self) -> float:
        """Largest ``gap_px`` among the eyes that see the gap (among both if neither), px."""
        eyes = [e for e in (self.left, self.right) if e.in_sight] or [self.left, self.right]
        spans = [e.gap_px for e in eyes if math.isfinite(e.gap_px)]
        return max(spans) if spans else math.nan

    @property
    def resolved(self) -> bool:
        """Some eye sees the gap and it spans at least ``RESOLVED_PX`` there."""
        return any(e.in_sight and e.gap_px >= RESOLVED_PX for e in (self.left, self.right))

    @property
    def hidden_by(self) -> str | None:
        """What hides the gap from a viewer with both eyes (None: an eye sees it).

        The left eye's hider: the video's eye, and the one the mono columns name.
        """
        return None if self.in_sight_either else self.left.hidden_by


def view_gap(
    scene: WireChaserScene,
    T_world_ring: ArrayLike,
    T_world_cam: ArrayLike,
    p_world_gap: ArrayLike,
    t_s: float = math.nan,
) -> ClosingGap:
    """Place the ring and camera in ``scene`` and measure a gap of ``GAP_SEEN`` from both eyes.

    Parameters
    ----------
    scene : WireChaserScene
        The world (its ring and camera poses are changed; the rest is left as it is).
    T_world_ring : (4, 4)
        Ring pose, m.
    T_world_cam : (4, 4)
        Camera pose (optical frame), m.
    p_world_gap : (3,)
        The gap's closest-approach point in world, m.
    t_s : float
        The instant, s, copied into the result.

    Returns
    -------
    ClosingGap
    """
    T_ring = as_pose(T_world_ring, "T_world_ring")
    T_cam = as_pose(T_world_cam, "T_world_cam")
    p = as_vector3(p_world_gap, "p_world_gap")
    scene.set_ring_pose(T_ring)
    scene.set_camera_pose(T_cam)
    try:
        u = contact_normal(p, T_ring, scene.task_cfg.ring.major_radius)
    except ValueError:  # on the ring's axis or core circle: no opening direction
        u = None
    views = []
    for eye in EYES:
        span = math.nan if u is None else pixel_scales(scene.camera, T_cam, p, u, eye)[1]
        hider = (
            scene.occluder(p, T_cam, eye)
            if in_image(scene.camera, T_cam, p, eye)
            else OUTSIDE_IMAGE
        )
        views.append(EyeGap(in_sight=hider is None, hidden_by=hider, gap_px=GAP_SEEN * span))
    return ClosingGap(t_s=float(t_s), left=views[0], right=views[1])


# ------------------------------------------------------------------------------ per touch
def control_step(result: EpisodeResult, t: float) -> int:
    """Control step nearest to time ``t`` (s)."""
    rate = result.config.episode.control_rate
    return int(np.clip(round(t * rate), 0, len(result.log.t) - 1))


def closing_gap(result: EpisodeResult, scene: WireChaserScene, t_start: float) -> ClosingGap:
    """The closing gap of the touch whose onset is ``t_start`` (s), from the episode's camera.

    The closing instant is as the module docstring says (the window's start if the clearance is
    below ``GAP_SEEN`` throughout); the camera pose and PSM2 tip are the logged ones of the
    nearest control step: the test every validation clip's view passes
    (:func:`endocam.study.observer_clips.gap_visible`).
    """
    moment = closing_moment(result, t_start)
    scene.set_psm2_tip(result.log.p_world_tips[moment.k, 1])
    return view_gap(
        scene, moment.T_world_ring, result.log.T_world_cam[moment.k], moment.p_world_gap, moment.t_s
    )


class ClosingMoment(NamedTuple):
    """The closing instant of one touch (module docstring).

    Attributes
    ----------
    t_s : float
        The instant, s.
    k : int
        The control step nearest to it.
    T_world_ring : (4, 4)
        The true ring pose then, world, m.
    p_world_gap : (3,)
        The ring's point closest to the wire then, world, m.
    """

    t_s: float
    k: int
    T_world_ring: FloatArray
    p_world_gap: FloatArray


def closing_moment(result: EpisodeResult, t_start: float) -> ClosingMoment:
    """The closing instant of the touch whose onset is ``t_start`` (s).

    The first sample of the window before the onset with the clearance at most ``GAP_SEEN``
    (the window's end if none is).
    """
    from endocam.task.touches import clearances

    t0 = max(t_start - PRE_TOUCH_S, 0.0)
    ts = np.append(np.arange(t0, t_start, GAP_SEEN_DT), t_start)
    T_rings = result.trajectory.poses(ts)
    c, p = clearances(T_rings, result.wire, result.config.task.ring)
    closing = np.flatnonzero(c <= GAP_SEEN)
    i = int(closing[0]) if closing.size else len(ts) - 1
    t_s = float(ts[i])
    return ClosingMoment(t_s, control_step(result, t_s), T_rings[i], p[i])


def gap_hidden_by(
    result: EpisodeResult, scene: WireChaserScene, t_start: float, eye: Eye = "left"
) -> str | None:
    """What hides the gap that closes at ``t_start`` (s) from ``eye`` (None: it is in sight)."""
    return closing_gap(result, scene, t_start).eye(eye).hidden_by


def gap_in_sight(
    result: EpisodeResult, scene: WireChaserScene, t_start: float, eye: Eye = "left"
) -> bool:
    """Whether the gap that closes at ``t_start`` (s) is in sight from ``eye``."""
    return gap_hidden_by(result, scene, t_start, eye) is None


def gap_row(gap: ClosingGap) -> dict[str, Any]:
    """One touch's closing gap as JSON values (``hypothesis.json``'s seed rows, ``truth.json``)."""
    return {
        "in_sight_left": gap.left.in_sight,
        "in_sight_right": gap.right.in_sight,
        "in_sight_either": gap.in_sight_either,
        "gap_px": gap.gap_px if math.isfinite(gap.gap_px) else None,
        "resolved": gap.resolved,
        "hidden_by_left": gap.left.hidden_by,
        "hidden_by_right": gap.right.hidden_by,
    }


# ------------------------------------------------------------------------------ summaries
class ShareCI(BaseModel):
    """A share of touches with its seed-level bootstrap 95 % interval.

    ``ci95`` is None with fewer than two seeds (nothing to resample).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    share: float
    ci95: tuple[float, float] | None
    touches: int
    seeds: int


def seed_bootstrap_ci(
    hits: Sequence[int], totals: Sequence[int], seed: int = BOOTSTRAP_SEED
) -> tuple[float, float] | None:
    """Percentile 95 % interval of a pooled share, resampling seeds (clusters) with replacement.

    Parameters
    ----------
    hits, totals : (n_seeds,)
        Per seed, the touches that pass and the touches (≥ 0).
    seed : int
        Seed of the generator (``np.random.default_rng``).

    Returns
    -------
    (2,) or None
        ``(low, high)`` of ``sum(hits) / sum(totals)`` over ``BOOTSTRAP_RESAMPLES`` resamples
        (resamples without a touch are left out); None with fewer than two seeds with touches.
    """
    h = np.asarray(hits, dtype=float)
    n = np.asarray(totals, dtype=float)
    if h.shape != n.shape or h.ndim != 1 or np.any(h < 0) or np.any(h > n):
        raise ValueError("hits and totals must be equal-length 1-D counts with 0 ≤ hits ≤ totals")
    if np.count_nonzero(n) < 2:
        return None
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, h.size, size=(BOOTSTRAP_RESAMPLES, h.size))
    num, den = h[idx].sum(axis=1), n[idx].sum(axis=1)
    shares = num[den > 0] / den[den > 0]
    alpha = 1.0 - CI_LEVEL
    lo, hi = np.quantile(shares, [alpha / 2, 1.0 - alpha / 2])
    return float(lo), float(hi)


def share_ci(flags_by_seed: dict[Any, list[bool]]) -> ShareCI | None:
    """Pooled share of True over every seed's flags, with its seed-level interval.

    None when there is no touch at all.
    """
    hits = [sum(fs) for fs in flags_by_seed.values()]
    totals = [len(fs) for fs in flags_by_seed.values()]
    if sum(totals) == 0:
        return None
    return ShareCI(
        share=sum(hits) / sum(totals),
        ci95=seed_bootstrap_ci(hits, totals),
        touches=sum(totals),
        seeds=sum(1 for t in totals if t),
    )
