"""A learned ideal observer: how much information about contact each condition's video carries.

The hand-tuned observer (:mod:`endocam.study.observer`) reads a gap with fixed rules; a rule can
miss what the pixels hold. Here a classifier learns, per condition and input (``mono``: the left
eye; ``stereo``: both eyes' crops side by side), to tell frames **in contact** (the ring–wire
clearance ≤ 0 in the simulator's log) from frames **at least** ``APART_M`` **apart**; the frames in
between are left out of training and of the AUC. Each frame's input is a crop around the ring,
placed by projecting the logged ring centre through the logged camera pose and ``K_left`` (not by
segmenting the image: the crop is where the ring is even when the image hides it), scaled to the
ring's apparent size, resized to ``CROP_PX`` × ``CROP_PX`` pixels and given as hue, saturation
and value in [0, 1] (hue tells the orange ring from the blue wire).

Model: gradient-boosted trees on those pixels (``HistGradientBoostingClassifier``, ``HGB_ITER``
iterations, ``HGB_BINS`` bins per feature); training keeps every contact frame and at most
``APART_PER_CONTACT`` times as many apart frames (a seeded draw); scores are its probabilities.
Logistic regression on the pixels was tried first and stayed near chance (AUC 0.53 against 0.68
on a presentation video, which no kept seed shares).

Evaluation (all on disjoint seeds):

* Leave-one-seed-out cross-validation (:func:`seed_folds`, ``LeaveOneGroupOut`` by seed): every
  frame's score comes from a model that never saw its seed.
* AUC of the pooled out-of-fold scores of the labelled frames (:func:`auc_score`), and
  d′ = √2 · Φ⁻¹(AUC) (the equal-variance Gaussian observer with that AUC; not fitted to the score
  distributions, whose shapes a logistic model does not make Gaussian).
* 95 % CIs: seed-level bootstrap (seeds drawn with replacement, ``N_BOOT`` resamples, a seeded
  generator), percentile intervals; d′'s interval is the AUC's mapped through the same monotone
  formula.
* Touch counts: per test seed, the touches in its thresholded scores over **all** its frames
  (:func:`count_touches`, the hand-tuned observer's debounce: ``MIN_TOUCH_FRAMES`` and
  ``RELEASE_FRAMES``), the threshold chosen on the training seeds only
  (:func:`choose_threshold` on their inner ``INNER_FOLDS``-fold grouped scores, the one that
  minimises the summed absolute counting error).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.stats import norm, rankdata

from endocam.study import effects
from endocam.study.observer import MIN_TOUCH_FRAMES, RELEASE_FRAMES

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

APART_M = 0.5e-3  # m, a frame this far apart (or more) is "not in contact"
CONTACT, APART, BETWEEN = 1, 0, -1  # frame labels; BETWEEN frames are excluded
CROP_PX = 16  # px, side of the resized crop per eye
CROP_MARGIN = 1.4  # crop half-side over the ring's apparent outer radius (R + r)
MIN_HALF_PX = 4.0  # px, smallest crop half-side (a ring far away)
HGB_ITER = 100  # boosting iterations
HGB_BINS = 64  # histogram bins per feature: scikit-learn's 255 cost 3x the CPU per fit, and on
# three held-out seeds of one condition (endocam, mono) the AUCs moved by at most 0.016
APART_PER_CONTACT = 2.0  # training keeps at most this many apart frames per contact frame
TRAIN_SEED = 0  # the generator seed of the training subsample
INNER_FOLDS = 2  # grouped folds over a fold's training seeds that score them for its threshold
N_BOOT = 2000  # seed-level bootstrap resamples
BOOT_SEED = 0  # the bootstrap's generator seed
CI_LEVEL = effects.CI_LEVEL
AUC_CLIP = 1e-4  # AUC is clipped to [AUC_CLIP, 1 − AUC_CLIP] for d′ (finite: |d′| ≤ 5.3)
THRESHOLD_CANDIDATES = 101  # quantiles of the training scores tried as thresholds
MIN_SEEDS = 3  # grouped CV needs a test seed and, inside the training seeds, an inner split


# ------------------------------------------------------------------------------- labels, crops
def frame_labels(
    t_frames: FloatArray, t_log: FloatArray, clearance: FloatArray, apart_m: float = APART_M
) -> NDArray[np.int8]:
    """Label each video frame from the log step nearest in time.

    Parameters
    ----------
    t_frames : (F,)
        Frame time stamps, s (frame j at j / fps).
    t_log : (N,)
        Log time stamps, s, increasing.
    clearance : (N,)
        Ring–wire clearance per step, m (≤ 0: in contact).
    apart_m : float
        Clearance at or above which a frame is ``APART``, m.

    Returns
    -------
    (F,) int8
        ``CONTACT`` (1), ``APART`` (0) or ``BETWEEN`` (−1, also where the clearance is NaN).
    """
    steps = nearest_steps(t_frames, t_log)
    c = np.asarray(clearance, dtype=float)[steps]
    labels = np.full(len(steps), BETWEEN, dtype=np.int8)
    labels[c <= 0.0] = CONTACT
    labels[c >= apart_m] = APART
    return labels


def nearest_steps(t_frames: FloatArray, t_log: FloatArray) -> IntArray:
    """(F,) index of the log step nearest in time to each frame (t_log increasing), s."""
    t = np.asarray(t_log, dtype=float)
    tf = np.asarray(t_frames, dtype=float)
    right = np.clip(np.searchsorted(t, tf), 1, len(t) - 1)
    left = right - 1
    pick_left = np.abs(tf - t[left]) <= np.abs(t[right] - tf)
    return np.asarray(np.where(pick_left, left, right), dtype=np.int64)


def project_ring(
    K: FloatArray, T_world_eye: FloatArray, p_world_ring: FloatArray, outer_radius: float
) -> tuple[FloatArray, FloatArray]:
    """Where the ring centre is in an eye's image, and the crop half-side there.

    Parameters
    ----------
    K : (3, 3)
        The eye's intrinsics, px.
    T_world_eye : (F, 4, 4)
        The eye's optical frame (x right, y down, z forward) in world, m.
    p_world_ring : (F, 3)
        Ring centre in world, m.
    outer_radius : float
        The ring's outer radius R + r, m.

    Returns
    -------
    uv : (F, 2)
        Pixel coordinates, px; NaN where the centre is not in front of the eye.
    half_px : (F,)
        ``CROP_MARGIN`` × the apparent outer radius, at least ``MIN_HALF_PX``; NaN with ``uv``.
    """
    T = np.asarray(T_world_eye, dtype=float)
    d = np.asarray(p_world_ring, dtype=float) - T[:, :3, 3]
    p_eye = np.einsum("nji,nj->ni", T[:, :3, :3], d)  # R^T (p − t)
    z = p_eye[:, 2]
    ok = z > outer_radius
    zs = np.where(ok, z, np.nan)
    uv = np.stack([K[0, 0] * p_eye[:, 0] / zs + K[0, 2], K[1, 1] * p_eye[:, 1] / zs + K[1, 2]], 1)
    half = np.maximum(CROP_MARGIN * K[1, 1] * outer_radius / zs, MIN_HALF_PX)
    return uv, half


def crop_hsv(
    frame: NDArray[np.uint8], uv: FloatArray, half_px: float, size: int = CROP_PX
) -> NDArray[np.uint8]:
    """A square crop of ``frame`` around ``uv``, resized, in OpenCV's HSV: (size · size · 3,) uint8.

    ``frame`` : (H, W, 3) RGB uint8; ``uv`` : (2,) px; ``half_px`` : crop half-side, px. Pixels
    beyond the image repeat its border (OpenCV ``getRectSubPix``). A NaN ``uv`` (the ring is
    behind the eye) gives zeros. Hue is 0..180 (OpenCV's), saturation and value 0..255.
    """
    if not (np.isfinite(uv).all() and math.isfinite(half_px)):
        return np.zeros(size * size * 3, dtype=np.uint8)
    side = max(2, round(2.0 * half_px))
    h, w = frame.shape[:2]
    centre = (float(np.clip(uv[0], -side, w + side)), float(np.clip(uv[1], -side, h + side)))
    patch = cv2.getRectSubPix(frame, (side, side), centre)
    small = cv2.resize(patch, (size, size), interpolation=cv2.INTER_AREA)
    return np.asarray(cv2.cvtColor(small, cv2.COLOR_RGB2HSV), dtype=np.uint8).reshape(-1)


HSV_SCALE = np.array([180.0, 255.0, 255.0], dtype=np.float32)  # OpenCV's hue is 0..180


def hsv_features(hsv: NDArray[np.uint8]) -> NDArray[np.float32]:
    """(..., 3k) uint8 HSV triples from :func:`crop_hsv` → the same shape in [0, 1], float32."""
    a = np.asarray(hsv)
    flat = a.reshape(*a.shape[:-1], -1, 3).astype(np.float32) / HSV_SCALE
    return np.asarray(flat.reshape(a.shape), dtype=np.float32)


def crop_features(
    frame: NDArray[np.uint8], uv: FloatArray, half_px: float, size: int = CROP_PX
) -> NDArray[np.float32]:
    """:func:`crop_hsv` scaled to [0, 1]: (size · size · 3,) float32 (hue, saturation, value)."""
    return hsv_features(crop_hsv(frame, uv, half_px, size))


# ------------------------------------------------------------------------------------ the CV
def seed_folds(seeds: IntArray) -> list[tuple[IntArray, IntArray]]:
    """Leave-one-seed-out folds: (train, test) row indices; no seed is in both of a fold.

    ``seeds`` : (N,) the seed of each row. One fold per distinct seed, in seed order.
    """
    from sklearn.model_selection import LeaveOneGroupOut

    g = np.asarray(seeds)
    rows = np.zeros((len(g), 1))
    return [
        (np.asarray(tr, dtype=np.int64), np.asarray(te, dtype=np.int64))
        for tr, te in LeaveOneGroupOut().split(rows, groups=g)
    ]


def make_model() -> Any:
    """The classifier: gradient-boosted trees (``HGB_ITER`` iterations, ``HGB_BINS`` bins).

    Fixed random state; its OpenMP threads are whatever the caller allows (``threadpoolctl``).
    """
    from sklearn.ensemble import HistGradientBoostingClassifier

    return HistGradientBoostingClassifier(
        max_iter=HGB_ITER, max_bins=HGB_BINS, early_stopping=False, random_state=0
    )


def training_rows(labels: NDArray[np.int8], train: IntArray) -> IntArray:
    """The labelled rows of ``train`` a model is fitted on, in row order.

    Every contact row and at most ``APART_PER_CONTACT`` × as many apart rows (drawn with
    ``default_rng(TRAIN_SEED)``).
    """
    contact = train[labels[train] == CONTACT]
    apart = train[labels[train] == APART]
    cap = max(1, int(APART_PER_CONTACT * len(contact)))
    if len(apart) > cap:
        apart = np.random.default_rng(TRAIN_SEED).choice(apart, size=cap, replace=False)
    return np.sort(np.concatenate([contact, apart]))


def fit_scores(
    X: NDArray[np.float32], labels: NDArray[np.int8], train: IntArray, test: IntArray
) -> FloatArray:
    """Fit on the labelled rows of ``train``; the contact probability of every ``test`` row.

    ``X`` : (N, D) features; ``labels`` : (N,) ``CONTACT``/``APART``/``BETWEEN``. A training set
    with one class only scores every test row with that class's share (0 or 1).
    """
    tr = training_rows(labels, train)
    y = labels[tr] == CONTACT
    if y.all() or not y.any():
        return np.full(len(test), float(y.mean()) if len(y) else 0.0)
    model = make_model().fit(X[tr], y)
    return np.asarray(model.predict_proba(X[test])[:, 1], dtype=float)


def count_touches(above: NDArray[np.bool_]) -> int:
    """Touches in a per-frame contact series, with the hand-tuned observer's debounce.

    A touch starts at a frame above the threshold and ends after ``RELEASE_FRAMES`` frames in a
    row below it; it counts if it has at least ``MIN_TOUCH_FRAMES`` frames above.
    """
    count = 0
    inside = False
    run_below = above_frames = 0
    for a in np.asarray(above, dtype=bool):
        if a:
            if not inside:
                inside, above_frames = True, 0
            above_frames += 1
            run_below = 0
        elif inside:
            run_below += 1
            if run_below >= RELEASE_FRAMES:
                count += above_frames >= MIN_TOUCH_FRAMES
                inside = False
    if inside:
        count += above_frames >= MIN_TOUCH_FRAMES
    return int(count)


def choose_threshold(scores: Sequence[FloatArray], true_touches: Sequence[int]) -> float:
    """The threshold that minimises Σ |counted − true| over some seeds.

    ``scores`` : per seed (F_s,) contact scores of all its frames, in frame order;
    ``true_touches`` : per seed. Candidates are ``THRESHOLD_CANDIDATES`` quantiles of the pooled
    scores; among equally good ones, the median.
    """
    if len(scores) != len(true_touches) or not scores:
        raise ValueError("scores and true_touches need one entry per seed (at least one)")
    pooled = np.concatenate([np.asarray(s, dtype=float) for s in scores])
    candidates = np.unique(np.quantile(pooled, np.linspace(0.0, 1.0, THRESHOLD_CANDIDATES)))
    errors = np.array(
        [
            sum(abs(count_touches(s >= c) - n) for s, n in zip(scores, true_touches, strict=True))
            for c in candidates
        ]
    )
    best = candidates[errors == errors.min()]
    return float(best[len(best) // 2])


@dataclass(frozen=True)
class Dataset:
    """Every frame of one condition and input over the study's seeds.

    Attributes
    ----------
    features : (N, D) float32
        Crop pixels in [0, 1] (``D`` = CROP_PX² · 3 per eye).
    labels : (N,) int8
        ``CONTACT``, ``APART`` or ``BETWEEN`` per frame.
    seeds : (N,) int64
        The seed of each frame; each seed's frames are contiguous and in frame order.
    true_touches : dict of int to int
        The simulator's touches per seed.
    """

    features: NDArray[np.float32]
    labels: NDArray[np.int8]
    seeds: IntArray
    true_touches: dict[int, int]


@dataclass(frozen=True)
class CrossValidation:
    """Out-of-fold results of :func:`cross_validate`.

    Attributes
    ----------
    scores : (N,)
        Each frame's contact score from the model of the fold that held its seed out.
    thresholds : dict of int to float
        Per test seed, the threshold chosen on that fold's training seeds.
    counted : dict of int to int
        Per seed, the touches counted in its thresholded scores.
    """

    scores: FloatArray
    thresholds: dict[int, float]
    counted: dict[int, int]


def rows_of(seeds: IntArray, rows: IntArray) -> dict[int, IntArray]:
    """``rows`` grouped by seed (in seed order), each in row order."""
    s = seeds[rows]
    return {int(k): rows[s == k] for k in np.unique(s)}


def fold_threshold(data: Dataset, train: IntArray) -> float:
    """A fold's threshold from its training rows only: inner grouped scores.

    The training seeds are split into ``INNER_FOLDS`` groups (``GroupKFold``); each group is
    scored by a model of the others, and :func:`choose_threshold` picks the value that counts
    the training seeds' touches best.
    """
    from sklearn.model_selection import GroupKFold

    g = data.seeds[train]
    scores = np.full(len(train), np.nan)
    folds = GroupKFold(n_splits=min(INNER_FOLDS, len(np.unique(g))))
    for tr, te in folds.split(np.zeros((len(train), 1)), groups=g):
        scores[te] = fit_scores(data.features, data.labels, train[tr], train[te])
    by_seed = {int(k): scores[g == k] for k in np.unique(g)}
    return choose_threshold(list(by_seed.values()), [data.true_touches[s] for s in by_seed])


def cross_validate(
    data: Dataset,
    threshold: Callable[[Dataset, IntArray], float] = fold_threshold,
    progress: Callable[[int], object] | None = None,
) -> CrossValidation:
    """Leave-one-seed-out scores, per-fold thresholds and per-seed touch counts.

    ``threshold(data, train_rows)`` chooses a fold's threshold (it sees only the training rows'
    indices; default :func:`fold_threshold`); ``progress`` is called with 1 per fold.
    """
    scores = np.full(len(data.labels), np.nan)
    thresholds: dict[int, float] = {}
    counted: dict[int, int] = {}
    for train, test in seed_folds(data.seeds):
        scores[test] = fit_scores(data.features, data.labels, train, test)
        seed = int(data.seeds[test[0]])
        thresholds[seed] = threshold(data, train)
        counted[seed] = count_touches(scores[test] >= thresholds[seed])
        if progress is not None:
            progress(1)
    return CrossValidation(scores, thresholds, counted)


# ------------------------------------------------------------------------------ the statistics
def d_prime(auc: float | FloatArray) -> Any:
    """d′ = √2 · Φ⁻¹(AUC), the AUC clipped to [AUC_CLIP, 1 − AUC_CLIP] (finite)."""
    a = np.clip(np.asarray(auc, dtype=float), AUC_CLIP, 1.0 - AUC_CLIP)
    return math.sqrt(2.0) * norm.ppf(a)


def auc_score(positive: NDArray[np.bool_], scores: FloatArray) -> float:
    """Area under the ROC curve: the Mann–Whitney U over n₊ n₋ (ties count ½).

    Equal to ``sklearn.metrics.roc_auc_score`` (a test holds it to it), several times faster,
    which the bootstrap's thousands of resamples need. ``positive`` : (N,) bool, both classes.
    """
    y = np.asarray(positive, dtype=bool)
    n_pos = int(y.sum())
    n_neg = len(y) - n_pos
    ranks = rankdata(scores)
    return float((ranks[y].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


@dataclass(frozen=True)
class AucEstimate:
    """An AUC with its seed-level bootstrap interval (``CI_LEVEL``).

    ``auc``, ``low``, ``high``: the point estimate and the percentile interval; ``samples``:
    (n_boot,) the resamples' AUCs, NaN where a resample had one class only. Two estimates made
    with the same seeds and generator seed drew the same resamples, so their samples pair up
    (:func:`paired_difference`).
    """

    auc: float
    low: float
    high: float
    samples: FloatArray

    @property
    def half_width(self) -> float:
        """Half the interval's width."""
        return 0.5 * (self.high - self.low)

    @property
    def n_boot(self) -> int:
        """Resamples that had both classes."""
        return int(np.isfinite(self.samples).sum())


def percentile_ci(samples: FloatArray) -> tuple[float, float]:
    """The ``CI_LEVEL`` percentile interval of the finite ``samples`` (NaN if there are none).

    :func:`endocam.study.effects.percentile_ci` with any number of defined resamples.
    """
    ci = effects.percentile_ci(np.asarray(samples, dtype=float), min_share=0.0)
    return (math.nan, math.nan) if ci is None else ci


def bootstrap_auc(
    labels: NDArray[np.int8],
    scores: FloatArray,
    seeds: IntArray,
    n_boot: int = N_BOOT,
    rng: np.random.Generator | None = None,
) -> AucEstimate:
    """AUC of the labelled frames and its seed-level bootstrap percentile interval.

    ``labels``, ``scores``, ``seeds`` : (N,) per frame (``BETWEEN`` frames are ignored). Each
    resample draws as many seeds as there are, with replacement, and pools their frames.
    ``rng`` defaults to ``default_rng(BOOT_SEED)``.
    """
    keep = labels != BETWEEN
    y = labels[keep] == CONTACT
    s = np.asarray(scores, dtype=float)[keep]
    g = np.asarray(seeds)[keep]
    if y.all() or not y.any():
        raise ValueError("the AUC needs frames of both classes (in contact and apart)")
    gen = np.random.default_rng(BOOT_SEED) if rng is None else rng
    groups = np.unique(g)
    members = {int(k): np.flatnonzero(g == k) for k in groups}
    samples = np.full(n_boot, np.nan)
    for b in range(n_boot):
        pick = gen.choice(groups, size=len(groups), replace=True)
        rows = np.concatenate([members[int(k)] for k in pick])
        if y[rows].any() and not y[rows].all():
            samples[b] = auc_score(y[rows], s[rows])
    low, high = percentile_ci(samples)
    return AucEstimate(auc_score(y, s), low, high, samples)


def paired_difference(a: AucEstimate, b: AucEstimate) -> tuple[float, float, float]:
    """AUC a − b and its paired seed-bootstrap interval (same seeds, same resamples)."""
    if a.samples.shape != b.samples.shape:
        raise ValueError("paired estimates need the same number of resamples")
    low, high = percentile_ci(a.samples - b.samples)
    return a.auc - b.auc, low, high


def seeds_needed(half_width: float, n_seeds: int, target: float) -> int:
    """Seeds for a CI half-width of ``target``, by the bootstrap's 1/√n scaling."""
    if not (half_width > 0.0 and target > 0.0):
        return n_seeds
    return max(n_seeds, math.ceil(n_seeds * (half_width / target) ** 2))
