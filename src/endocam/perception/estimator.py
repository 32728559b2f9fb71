"""The ring's pose from one stereo pair: centre and face normal in the camera frame, or nothing.

Per pair (:func:`estimate_ring_pose`; the method and its failure modes: docs/perception.md):

1. **Segment** the ring by colour in both eyes (:func:`endocam.perception.segment.segment`, the
   study observer's segmentation).
2. **Fit the rim** in each eye: an ellipse to the ring's outer silhouette, what is hidden by the
   wire, an instrument or the image edge left out (:func:`endocam.perception.ellipse.fit_rim`).
   A fit must cover at least ``min_coverage`` of the perimeter.
3. **Depth** from the rows-aligned disparity of the two ellipse centres (the eyes are parallel,
   ``baseline`` apart along x); the tube's image radius ``f r / Z`` is taken off both semi-axes,
   which leaves the image of the core circle (radius ``R``).
4. **Normals**: each eye's core ellipse gives two candidate normals (a circle's two-fold
   ambiguity, :func:`endocam.perception.ellipse.circle_normals`); the true one is seen by both
   eyes, the false ones differ (each is the true normal mirrored about that eye's line of
   sight, and the lines of sight differ by ``baseline / Z``). The pair of candidates, one per eye,
   that agree best gives the normal (their mean); the others are discarded. Near the ring's
   axis, where an ellipse's shape barely shows the tilt, that normal is blended with the plane
   of the core ellipses' row-matched disparities (:func:`blended_normal`;
   :func:`endocam.perception.disparity.plane_normal`).
5. **Centre**: each eye's image of the circle's centre for that normal, triangulated.
6. **Once more, by perspective**: with that centre and normal, each eye's core is found again
   from its silhouette points, each moved in by the tube's image half-width at its own depth
   and ray (:func:`endocam.perception.ellipse.core_ellipse`; the uniform shrink of step 3 is
   exact only on the optical axis), and steps 4–5 are repeated on those cores.
7. **Reject what is inconsistent**: rows that differ between the eyes, a depth outside
   ``depth_range``, a core ellipse that is not a circle of radius ``R`` at the triangulated
   distance, eyes whose normals disagree by more than ``max_normal_disagreement``.

The confidence in [0, 1] is the smaller coverage times the margins left on the size and normal
checks. Everything is SI inside; pixels only for image quantities (``_px``).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from endocam.camera import Eye, StereoCamera
from endocam.geometry import FloatArray, frame_with_z
from endocam.perception.disparity import plane_normal
from endocam.perception.ellipse import (
    ImageEllipse,
    centre_image,
    circle_normals,
    core_ellipse,
    fit_rim,
    normalised_conic,
    radius_over_distance,
)
from endocam.perception.mono import PriorChoice, mono_pose
from endocam.perception.segment import ColourKeys, hue_mask, segment
from endocam.task.config import TaskConfig

COARSE_STRIDE = 3  # px, the ring is first looked for on every 3rd row and column
BOX_MARGIN_PX = 8  # px, the ring's box is grown by this beyond its coarse pixels


class EstimateStatus(enum.Enum):
    """Why a pair gave a pose or none."""

    OK = "ok"
    BAD_FRAME = "bad_frame"  # not finite, or not an image
    NO_RING = "no_ring"  # too few ring silhouette points in an eye
    LOW_COVERAGE = "low_coverage"  # the visible rim is too short a part of the ellipse
    ROWS_DIFFER = "rows_differ"  # the eyes' ellipse centres are not on one image row
    BAD_DEPTH = "bad_depth"  # disparity ≤ 0 or the depth out of range
    SIZE_MISMATCH = "size_mismatch"  # the core ellipse is not a ring of radius R at that depth
    NORMALS_DISAGREE = "normals_disagree"  # the eyes' normals do not agree
    AMBIGUOUS = "ambiguous"  # the second eye cannot tell the two candidate normals apart
    MONO = "mono"  # a pose from one eye, the other's rim hidden, its normal chosen by a prior


@dataclass(frozen=True)
class RingModel:
    """What the estimator knows of the scene: the stereo calibration, the ring and its colour.

    Attributes
    ----------
    camera : StereoCamera
        Intrinsics of each (rectified, parallel) eye and the baseline, m.
    major_radius, minor_radius : float
        The torus's core-circle radius ``R`` and tube radius ``r``, m.
    keys : ColourKeys
        Hues of the ring and the wire.
    """

    camera: StereoCamera
    major_radius: float
    minor_radius: float
    keys: ColourKeys

    @classmethod
    def from_task(cls, task: TaskConfig, camera: StereoCamera) -> RingModel:
        """The model of a task's ring and colours seen by ``camera``."""
        ring = task.ring
        return cls(camera, ring.major_radius, ring.minor_radius, ColourKeys.from_scene(task.scene))


@dataclass(frozen=True)
class EstimatorConfig:
    """Thresholds of :func:`estimate_ring_pose` (each derived in docs/perception.md).

    Attributes
    ----------
    min_coverage : float
        Share of the rim's perimeter each eye's fit must cover, in (0, 1].
    max_row_px : float
        Largest row difference of the eyes' ellipse centres, px, plus ``row_fraction`` of ``b``.
    row_fraction : float
        The part of the row tolerance that grows with the ellipse's minor semi-axis.
    depth_range : (2,) float
        Accepted depths of the ring centre, m.
    size_tol : float
        Largest relative difference between ``R`` and the radius each eye's core ellipse implies
        at the triangulated centre's distance
        (:func:`~endocam.perception.ellipse.radius_over_distance`).
    max_normal_disagreement : float
        Largest angle between the two eyes' chosen normals, rad.
    min_normal_margin : float
        Least margin of the chosen normal over the other (:class:`NormalChoice`), rad, up to the
        depth ``margin_depth``; beyond it, the margin needed grows in proportion to the depth
        (the eyes' parallax, baseline / depth, shrinks and the ring's image with it) ...
    margin_depth : float
        The depth up to which ``min_normal_margin`` holds unscaled, m.
    ambiguous_separation : float
        ... required where the two candidates are farther apart than this, rad (closer
        candidates are both near the truth).
    plane_tilt : float
        The tilt (rad) from the line of sight at which the ellipses' normal and the disparity
        plane's (:func:`plane_normal`) weigh the same: the normal is their mean weighted
        ``sin² tilt`` to the ellipses' and ``sin² plane_tilt`` to the plane's (the ellipses'
        error grows as ``1 / sin tilt`` near the axis; the plane's stays about 1°).
    mono_max_depth : float
        m: a pose from one eye (:func:`_one_eye`) only this near. One image's size gives the
        distance with an error ``d² δr / (f R)`` growing as its square: at 0.1 m an error
        ``δr`` of 0.1 px in the rim's radius (the one-eye poses' centres were 0.02–0.06 mm off
        at 50 mm, i.e. 0.02–0.05 px) moves the centre 0.48 mm (``f`` 416 px, ``R`` 5 mm), half
        the observation gate's 1 mm stereo floor (``perception.loop.STEREO_FLOOR_M``). (Round
        15's 60 mm, the working band, cut off the poses a lagging PSM needed at 60–66 mm:
        1.1 s lost on ``t3-71-high``; the approach's far poses it was meant to keep out are
        kept out by ``mono=False`` before the track exists, :func:`estimate_ring_detail`.)
    prior_fraction : float
        An ambiguous choice is settled by a prior normal (the track's, e.g. the last
        estimate) when one hypothesis lies within this fraction of the hypotheses' separation
        of it (the other then lies about ``1 - prior_fraction`` of it away), in (0, 0.5).
    """

    min_coverage: float = 0.5
    max_row_px: float = 2.0
    row_fraction: float = 0.1
    depth_range: tuple[float, float] = (0.01, 0.3)
    size_tol: float = 0.08
    max_normal_disagreement: float = math.radians(15.0)
    min_normal_margin: float = math.radians(2.0)
    margin_depth: float = 0.06
    ambiguous_separation: float = math.radians(20.0)
    prior_fraction: float = 0.25
    plane_tilt: float = math.radians(15.0)
    mono_max_depth: float = 0.1

    def __post_init__(self) -> None:
        if not 0.0 < self.min_coverage <= 1.0:
            raise ValueError(f"min_coverage must be in (0, 1], got {self.min_coverage}")
        if not 0.0 < self.prior_fraction < 0.5:
            raise ValueError(f"prior_fraction must be in (0, 0.5), got {self.prior_fraction}")
        if not 0.0 < self.depth_range[0] < self.depth_range[1]:
            raise ValueError(f"depth_range must be 0 < near < far m, got {self.depth_range}")
        for name in (
            "max_row_px",
            "row_fraction",
            "size_tol",
            "max_normal_disagreement",
            "min_normal_margin",
            "margin_depth",
            "ambiguous_separation",
            "plane_tilt",
            "mono_max_depth",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")


@dataclass(frozen=True)
class RingEstimate:
    """The ring's pose as one stereo pair shows it.

    Attributes
    ----------
    p_cam_ring : (3,)
        Ring centre in the camera (centre, optical) frame, m.
    n_cam : (3,)
        Unit face normal in the camera frame, pointing towards the camera (a ring has no front:
        compare normals up to sign).
    confidence : float
        In (0, 1]: the smaller coverage times the margins left on the size and normal checks.
    left, right : ImageEllipse or None
        The fitted outer silhouettes, px (None for an eye without one: a one-eye pose,
        ``EstimateStatus.MONO``).
    """

    p_cam_ring: FloatArray
    n_cam: FloatArray
    confidence: float
    left: ImageEllipse | None
    right: ImageEllipse | None


@dataclass(frozen=True)
class EstimateResult:
    """:func:`estimate_ring_detail`'s answer: the estimate (None unless ``status`` is OK)."""

    estimate: RingEstimate | None
    status: EstimateStatus


def _as_frame(
    frame: NDArray[np.generic], name: str, shape: tuple[int, int]
) -> NDArray[np.uint8] | None:
    """The frame as uint8 RGB; None if it is not a finite numeric image (shape checked)."""
    a = np.asarray(frame)
    if a.shape != (*shape, 3):
        raise ValueError(f"{name} must be an (H, W, 3) = {(*shape, 3)} RGB image, got {a.shape}")
    if a.dtype == np.uint8:
        return a
    if not np.issubdtype(a.dtype, np.number) or not np.all(np.isfinite(a)):
        return None
    return np.asarray(np.clip(np.round(a), 0, 255), dtype=np.uint8)


def ring_box(frame: NDArray[np.uint8], keys: ColourKeys) -> tuple[int, int, int, int] | None:
    """Where the ring can be: (u0, v0, u1, v1), px (end-exclusive), or None.

    Ring-hued pixels of every ``COARSE_STRIDE``-th row and column (a ring tube at least that
    thick in the image is never missed), their box grown by ``COARSE_STRIDE`` + ``BOX_MARGIN_PX``
    and clipped to the image. ``frame`` : (H, W, 3) uint8 RGB.
    """
    coarse = np.ascontiguousarray(frame[::COARSE_STRIDE, ::COARSE_STRIDE])
    hsv = cv2.cvtColor(coarse, cv2.COLOR_RGB2HSV)
    mask = hue_mask(hsv, keys.ring_hue)
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    if w == 0 or h == 0:
        return None
    grow = COARSE_STRIDE + BOX_MARGIN_PX
    H, W = frame.shape[:2]
    u0, v0 = max(x * COARSE_STRIDE - grow, 0), max(y * COARSE_STRIDE - grow, 0)
    u1 = min((x + w - 1) * COARSE_STRIDE + grow + 1, W)
    v1 = min((y + h - 1) * COARSE_STRIDE + grow + 1, H)
    return u0, v0, u1, v1


def _fit_eye(frame: NDArray[np.uint8], keys: ColourKeys) -> ImageEllipse | None:
    """One eye's rim ellipse (full-image pixels): segmented and fitted inside :func:`ring_box`.

    The crop's edges that are not the image's lie ``BOX_MARGIN_PX`` away from any ring pixel, so
    the fit's border rule (:func:`endocam.perception.ellipse.silhouette_points`) only drops
    points on the image's own border.
    """
    box = ring_box(frame, keys)
    if box is None:
        return None
    u0, v0, u1, v1 = box
    ring, wire = segment(frame[v0:v1, u0:u1], keys)
    H, W = frame.shape[:2]
    if (u0, v0, u1, v1) != (0, 0, W, H):
        ring = _pad_inner_edges(ring, box, (H, W))
        wire = _pad_inner_edges(wire, box, (H, W))
    fit = fit_rim(ring, wire)
    if fit is None:
        return None
    return fit.shifted(np.array([u0 - (u0 > 0), v0 - (v0 > 0)], dtype=float))


def _pad_inner_edges(
    mask: NDArray[np.bool_], box: tuple[int, int, int, int], shape: tuple[int, int]
) -> NDArray[np.bool_]:
    """``mask`` of a crop padded by one empty pixel on each edge that is not the image's."""
    u0, v0, u1, v1 = box
    H, W = shape
    pads = ((int(v0 > 0), int(v1 < H)), (int(u0 > 0), int(u1 < W)))
    return np.asarray(np.pad(mask, pads))


def estimate_ring_pose(
    left: NDArray[np.generic],
    right: NDArray[np.generic],
    model: RingModel,
    config: EstimatorConfig | None = None,
) -> RingEstimate | None:
    """The ring's centre and face normal in the camera frame from one stereo pair, or None.

    Parameters
    ----------
    left, right : (H, W, 3)
        The eyes' RGB images, uint8 (a float image is rounded into 0..255; one with a NaN gives
        None), ``H × W`` the camera's image size.
    model : RingModel
    config : EstimatorConfig, optional

    Returns
    -------
    RingEstimate or None
        None where the pair shows no consistent ring (see :func:`estimate_ring_detail`).

    Raises
    ------
    ValueError
        If an image's shape is not the camera's.
    """
    return estimate_ring_detail(left, right, model, config).estimate


def estimate_ring_detail(
    left: NDArray[np.generic],
    right: NDArray[np.generic],
    model: RingModel,
    config: EstimatorConfig | None = None,
    prior: FloatArray | None = None,
    mono: bool = True,
) -> EstimateResult:
    """:func:`estimate_ring_pose` with the reason when there is no estimate (same parameters).

    ``prior`` (3,): a unit normal in the camera frame the ring is expected to have (a
    tracker's last estimate, carried to this camera pose), or None. It settles a choice
    of normal the second eye leaves ambiguous, only when one hypothesis lies within
    ``config.prior_fraction`` of their separation of it (:func:`settle_choice`), and picks a
    one-eye pose's normal (status ``mono``) when ``mono`` is True and one eye's rim is
    hidden. A loop passes ``mono=False`` until its track exists: a one-eye pose on the
    approach, whose prior is only the setup's registration, made the gate refuse the good
    stereo poses that followed for 2.4 s (round 15, the free camera's ``ideal-36``).
    """
    cfg = EstimatorConfig() if config is None else config
    k = model.camera.intrinsics
    shape = (k.height, k.width)
    frame_l, frame_r = _as_frame(left, "left", shape), _as_frame(right, "right", shape)
    if frame_l is None or frame_r is None:
        return EstimateResult(None, EstimateStatus.BAD_FRAME)
    fl, fr = _fit_eye(frame_l, model.keys), _fit_eye(frame_r, model.keys)
    seen = [f is not None and f.coverage >= cfg.min_coverage for f in (fl, fr)]
    if mono and seen in ([True, False], [False, True]):  # one eye's rim hidden
        one_eye = _one_eye(fl, fr, model, cfg, prior)
        if one_eye is not None:
            return EstimateResult(one_eye, EstimateStatus.MONO)
    if fl is None or fr is None:
        return EstimateResult(None, EstimateStatus.NO_RING)
    coverage = min(fl.coverage, fr.coverage)
    if coverage < cfg.min_coverage:
        return EstimateResult(None, EstimateStatus.LOW_COVERAGE)
    row_tol = cfg.max_row_px + cfg.row_fraction * min(fl.b, fr.b)
    if abs(fl.centre[1] - fr.centre[1]) > row_tol:
        return EstimateResult(None, EstimateStatus.ROWS_DIFFER)
    fb = k.fx * model.camera.baseline
    disparity = float(fl.centre[0] - fr.centre[0])
    if disparity <= 0.0 or not cfg.depth_range[0] <= fb / disparity <= cfg.depth_range[1]:
        return EstimateResult(None, EstimateStatus.BAD_DEPTH)
    z = fb / disparity
    tube_px = k.fx * model.minor_radius / z
    K = k.K
    normals = []
    conics = []
    for fit in (fl, fr):
        if fit.b <= tube_px:
            return EstimateResult(None, EstimateStatus.SIZE_MISMATCH)
        Q = normalised_conic(fit.shrunk(tube_px), K)
        cand = circle_normals(Q)
        if cand is None:
            return EstimateResult(None, EstimateStatus.SIZE_MISMATCH)
        normals.append(cand)
        conics.append(Q)
    choice = choose_normal(normals[0], normals[1])
    n, disagreement = choice.n, choice.disagreement
    if disagreement > cfg.max_normal_disagreement:
        return EstimateResult(None, EstimateStatus.NORMALS_DISAGREE)
    needed = cfg.min_normal_margin * max(1.0, z / cfg.margin_depth)
    if choice.separation > cfg.ambiguous_separation and choice.margin < needed:
        settled = settle_choice(choice, prior, cfg.prior_fraction * choice.separation)
        if settled is None or settled.disagreement > cfg.max_normal_disagreement:
            return EstimateResult(None, EstimateStatus.AMBIGUOUS)
        n, disagreement = settled.n, settled.disagreement
    n = blended_normal(n, plane_normal(conics[0], conics[1]), fl, fr, K, cfg.plane_tilt)
    p = _triangulate(conics[0], conics[1], n, model.camera)
    if p is None or not cfg.depth_range[0] <= p[2] <= cfg.depth_range[1]:
        return EstimateResult(None, EstimateStatus.BAD_DEPTH)
    refined = _refined(fl, fr, model, n, p, cfg)
    if refined is not None:
        n, p, conics = refined
    size_err = 0.0
    half_baseline = np.array([0.5 * model.camera.baseline, 0.0, 0.0])
    for Q, p_eye in zip(conics, (p + half_baseline, p - half_baseline), strict=True):
        d = abs(float(n @ p_eye))  # the eyes sit at ∓baseline/2 along x
        rho = d * radius_over_distance(Q)
        size_err = max(size_err, abs(rho / model.major_radius - 1.0))
    if not size_err <= cfg.size_tol:
        return EstimateResult(None, EstimateStatus.SIZE_MISMATCH)
    confidence = (
        coverage
        * (1.0 - size_err / cfg.size_tol)
        * (1.0 - disagreement / cfg.max_normal_disagreement)
    )
    est = RingEstimate(p, n, max(confidence, 1e-6), fl, fr)
    return EstimateResult(est, EstimateStatus.OK)


MONO_CONFIDENCE = 0.5
"""The confidence of a one-eye pose is its eye's coverage times this: the distance comes from
the ring's size in one image (its error grows as the distance over the image radius), and the
normal's choice from the prior, not from a second view."""


def _one_eye(
    fl: ImageEllipse | None,
    fr: ImageEllipse | None,
    model: RingModel,
    cfg: EstimatorConfig,
    prior: FloatArray | None,
) -> RingEstimate | None:
    """The pose from the eye that sees the rim (:func:`~endocam.perception.mono.mono_pose`).

    None without a ``prior`` (camera frame), or when the prior does not single out one of that
    eye's two normals as :func:`settle_choice` would (within ``prior_fraction`` of their
    separation; either, if they are within ``ambiguous_separation``). The other eye's fit, if
    any, is kept for drawing.
    """
    if prior is None:
        return None
    left_seen = fl is not None and fl.coverage >= cfg.min_coverage
    eye: Eye = "left" if left_seen else "right"
    fit = fl if left_seen else fr
    assert fit is not None
    K = model.camera.intrinsics.K
    choice = PriorChoice(cfg.prior_fraction, cfg.ambiguous_separation)
    got = mono_pose(fit, K, (model.major_radius, model.minor_radius), prior, choice)
    if got is None:
        return None
    p_eye, n = got
    p = np.asarray(p_eye + model.camera.T_cam_eye(eye)[:3, 3])
    if not cfg.depth_range[0] <= p[2] <= min(cfg.depth_range[1], cfg.mono_max_depth):
        return None
    return RingEstimate(p, n, max(fit.coverage * MONO_CONFIDENCE, 1e-6), fl, fr)


def _refined(
    fl: ImageEllipse,
    fr: ImageEllipse,
    model: RingModel,
    n: FloatArray,
    p: FloatArray,
    cfg: EstimatorConfig,
) -> tuple[FloatArray, FloatArray, list[FloatArray]] | None:
    """The pose again from each eye's core by perspective (:func:`core_ellipse`), or None.

    ``n`` (3,), ``p`` (3,), m: the first estimate, camera frame; the hypothesis of normal kept
    is the one nearer ``n``. Returns the unit normal (3,), the centre (3,), m, and the eyes'
    core conics (normalised), or None where a core or its pose cannot be had (the first
    estimate then stands).
    """
    K = model.camera.intrinsics.K
    half_baseline = np.array([0.5 * model.camera.baseline, 0.0, 0.0])
    conics = []
    normals = []
    for fit, p_eye in ((fl, p + half_baseline), (fr, p - half_baseline)):
        core = core_ellipse(fit, K, model.minor_radius, p_eye, n)
        if core is None:
            return None
        Q = normalised_conic(core, K)
        cand = circle_normals(Q)
        if cand is None:
            return None
        conics.append(Q)
        normals.append(cand)
    choice = choose_normal(normals[0], normals[1])
    n2 = choice.n if abs(float(choice.n @ n)) >= abs(float(choice.other @ n)) else choice.other
    n2 = blended_normal(n2, plane_normal(conics[0], conics[1]), fl, fr, K, cfg.plane_tilt)
    p2 = _triangulate(conics[0], conics[1], n2, model.camera)
    if p2 is None or not cfg.depth_range[0] <= p2[2] <= cfg.depth_range[1]:
        return None
    return n2, p2, conics


class NormalChoice(NamedTuple):
    """:func:`choose_normal`'s answer.

    Attributes
    ----------
    n : (3,)
        The unit mean of the best-agreeing pair of candidates, camera frame.
    disagreement : float
        The angle between that pair, rad.
    margin : float
        How much worse the other hypothesis agrees (its best pair's angle minus
        ``disagreement``), rad: the evidence for the choice.
    separation : float
        The angle between the two candidates of the left eye, rad (about twice the viewing
        angle): what a wrong choice would cost.
    other : (3,)
        The other hypothesis: the unit mean of its best-agreeing pair, camera frame.
    """

    n: FloatArray
    disagreement: float
    margin: float
    separation: float
    other: FloatArray


def settle_choice(
    choice: NormalChoice, prior: FloatArray | None, tolerance: float
) -> NormalChoice | None:
    """An ambiguous :class:`NormalChoice` settled by a ``prior`` unit normal (3,), or None.

    The hypothesis within ``tolerance`` (rad) of the prior (up to sign) is taken, if exactly
    one is; its ``disagreement`` is its pair's (the best one's plus the margin for the other).
    """
    if prior is None:
        return None
    near = [
        math.acos(min(1.0, abs(float(h @ prior)))) <= tolerance for h in (choice.n, choice.other)
    ]
    if near == [True, False]:
        return choice
    if near == [False, True]:
        return choice._replace(
            n=choice.other, other=choice.n, disagreement=choice.disagreement + choice.margin
        )
    return None


def choose_normal(
    left: tuple[FloatArray, FloatArray], right: tuple[FloatArray, FloatArray]
) -> NormalChoice:
    """The normal both eyes see: of the 2 × 2 candidate pairs, the one that agrees best.

    Parameters
    ----------
    left, right : pair of (3,)
        Each eye's two candidate unit normals (camera frame; the eyes are parallel), pointing
        towards the camera.

    Returns
    -------
    NormalChoice
    """
    # each eye's tilt from its line of sight is half its candidates' separation; the tilt
    # read off an ellipse's axis ratio has an error ~ 1 / sin(tilt): weigh by sin²
    w_left = 1.0 - float(np.clip(left[0] @ left[1], -1.0, 1.0))  # 2 sin²(tilt)
    w_right = 1.0 - float(np.clip(right[0] @ right[1], -1.0, 1.0))
    if w_left + w_right <= 0.0:
        w_left = w_right = 1.0
    per_left = []
    for a in left:
        cos = [float(np.clip(a @ b, -1.0, 1.0)) for b in right]
        j = int(np.argmax(cos))
        per_left.append((math.acos(cos[j]), w_left * a + w_right * right[j]))
    (d0, s0), (d1, s1) = per_left
    best, other, s, s_other = (d0, d1, s0, s1) if d0 <= d1 else (d1, d0, s1, s0)
    separation = math.acos(float(np.clip(left[0] @ left[1], -1.0, 1.0)))
    return NormalChoice(
        np.asarray(s / np.linalg.norm(s)),
        best,
        other - best,
        separation,
        np.asarray(s_other / np.linalg.norm(s_other)),
    )


def _triangulate(
    Q_left: FloatArray, Q_right: FloatArray, n: FloatArray, camera: StereoCamera
) -> FloatArray | None:
    """Centre (3,) in the camera frame, m, from each eye's image of it; None if degenerate."""
    xl = centre_image(Q_left, n)
    xr = centre_image(Q_right, n)
    if xl is None or xr is None:
        return None
    d = float(xl[0] - xr[0])  # normalised disparity = baseline / Z
    if d <= 0.0:
        return None
    z = camera.baseline / d
    x = 0.5 * (xl[0] + xr[0]) * z  # the eyes sit at ∓baseline/2: their mean is the centre's
    y = 0.5 * (xl[1] + xr[1]) * z
    return np.array([x, y, z])


def draw_estimate(
    image: NDArray[np.uint8],
    estimate: RingEstimate,
    model: RingModel,
    eye: str = "left",
) -> NDArray[np.uint8]:
    """A copy of ``image`` (H, W, 3) uint8 with the fit and the estimated pose drawn over it.

    The fitted silhouette (green), its supporting points (white), and the estimated ring: its
    core circle (magenta) and its normal from the centre, ``R`` long (cyan), projected into
    ``eye``'s image.
    """
    out = np.ascontiguousarray(image.copy())
    fit = estimate.left if eye == "left" else estimate.right
    if fit is None:
        raise ValueError(f"the estimate has no fit in the {eye} eye (a one-eye pose)")
    if fit.points is not None:
        for u, v in fit.points.astype(int):
            out[v, u] = (255, 255, 255)
    axes = (round(fit.a), round(fit.b))
    centre = (round(fit.centre[0]), round(fit.centre[1]))
    cv2.ellipse(out, centre, axes, math.degrees(fit.angle), 0, 360, (0, 255, 0), 1, cv2.LINE_AA)
    p_eye = (
        estimate.p_cam_ring - model.camera.T_cam_eye("left" if eye == "left" else "right")[:3, 3]
    )
    n = estimate.n_cam
    e1, e2, _ = frame_with_z(n).T  # the circle's plane
    phi = np.linspace(0.0, 2.0 * math.pi, 72)
    R = model.major_radius
    circle = p_eye + R * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    k = model.camera.intrinsics
    uv = circle[:, :2] / circle[:, 2:3] * [k.fx, k.fy] + [k.cx, k.cy]
    cv2.polylines(out, [np.round(uv).astype(np.int32)], True, (255, 0, 255), 1, cv2.LINE_AA)
    tip = np.stack([p_eye, p_eye + 2.0 * R * n])
    uv = tip[:, :2] / tip[:, 2:3] * [k.fx, k.fy] + [k.cx, k.cy]
    a, b = np.round(uv).astype(int)
    cv2.arrowedLine(out, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), (0, 255, 255), 2)
    return out


def blended_normal(
    n_ellipse: FloatArray,
    n_plane: FloatArray | None,
    left: ImageEllipse,
    right: ImageEllipse,
    K: FloatArray,
    plane_tilt: float,
) -> FloatArray:
    """The ellipses' normal (3,) and the disparity plane's, weighted by the tilt from the sight.

    The tilt is the plane normal's angle to the ray through the mean of the eyes' ellipse
    centres (``K`` (3, 3) the eyes' intrinsics); the ellipses' weight is ``sin² tilt``, the
    plane's ``sin² plane_tilt`` (rad). Both unit, camera frame, towards the eyes; the plane's
    sign is taken to agree with the ellipses'. ``n_ellipse`` alone if there is no plane normal.
    """
    if n_plane is None:
        return n_ellipse
    uv = 0.5 * (left.centre + right.centre)
    ray = np.linalg.solve(K, np.array([uv[0], uv[1], 1.0]))
    ray /= np.linalg.norm(ray)
    sin2_tilt = 1.0 - float(n_plane @ ray) ** 2
    w_plane = math.sin(plane_tilt) ** 2
    sign = 1.0 if float(n_plane @ n_ellipse) >= 0.0 else -1.0
    n = sin2_tilt * n_ellipse + w_plane * sign * n_plane
    return np.asarray(n / np.linalg.norm(n))
