r"""Agreement among assessors: ICC, Krippendorff's α, and the spread of the counting error.

The paper's second claim is about assessors: with the orientation camera the SD of the
assessment error *across assessors* is 31 % (32 %) lower than with the centring (fixed) camera.
This module measures agreement two ways.

**Agreement on the counts** (``ratings``: videos × assessors, the touches each assessor
reported; only assessors who passed the attention question and answered every video):

- **ICC(2,1)** (Shrout & Fleiss 1979; McGraw & Wong's "ICC(A,1)"): two-way random effects,
  absolute agreement, single rater — ``pingouin.intraclass_corr``'s ``ICC(A,1)`` (``ICC2``
  before pingouin 0.7). Two-way random because the videos *and* the assessors are samples
  (the study generalises to other assessors recruited the same way); absolute agreement
  because an assessor who counts every video two touches high disagrees with the truth and with
  the others, which consistency (ICC3) would forgive; single rater because a study's
  assessment is one assessor's count, not a panel's mean.

  .. math:: \mathrm{ICC}(2,1) = \frac{MS_R - MS_E}{MS_R + (k-1) MS_E + k (MS_C - MS_E)/n}

  with n videos (rows), k assessors (columns) and the two-way ANOVA mean squares.
- **Krippendorff's α, interval level** (the ``krippendorff`` package):
  :math:`\alpha = 1 - D_o / D_e`, the observed over the expected squared difference between
  two counts of the same / any video. Interval, not ratio: counts do have a true zero, but the
  ratio metric weighs a difference relative to the counts' size (1 vs 2 touches as far apart as
  10 vs 20), while a miscount of one touch is one error whatever the video's total; interval
  treats every touch alike, as the assessment error does.

Both are given over all the study's videos and per condition (that condition's videos only:
with three videos per condition these are crude). Their 95 % intervals are percentile
bootstraps that resample **videos** with replacement (assessors fixed), given only from
``MIN_BOOTSTRAP_VIDEOS`` videos on (three videos have 10 distinct resamples, one in nine of them
a single video repeated: no distribution; pingouin's F-based interval is given always). Videos,
because the agreement coefficients are ratios of between-video to within-video variance, and
the videos are the sample whose between-video spread they depend on (with 3k videos and tens of
assessors, the videos are also the scarcer sample; resampling assessors as well would add the
other source of variance, a two-way bootstrap left for later). The resamples are computed in
numpy in one vectorised pass (:func:`icc2_1_batch`, :func:`alpha_interval_batch`: the same
formulas, checked equal to the libraries in the tests).

**Spread of the counting error across assessors** (per condition, on the analysis's complete
cases, errors in touches): the sample SD with **Bonett's (2006) interval**
(:func:`bonett_sd_interval`: a log-variance interval whose standard error uses the sample's
kurtosis, not the normal's; it assumes independent assessors and a finite fourth moment), and
for the last condition against each other the SD ratio ``SD_last / SD_ref`` (paired: the same
assessors), its percentile bootstrap interval (assessors resampled as pairs; a BCa interval,
tried in round 12, covered no better: bench/agreement_coverage.py), and the **Pitman–Morgan
test**
of equal variances of paired data (Pitman 1939, Morgan 1939): with ``S = X + Y`` and
``D = X − Y``, ``var X = var Y`` iff ``corr(S, D) = 0``, tested by
:math:`t = r \sqrt{n-2} / \sqrt{1 - r^2}` on n − 2 degrees of freedom (two-sided). The paper's
"31 % lower" is a ratio of 0.69; ``paper_ratio_in_ci`` says whether the interval holds it.
Round 12 replaced the per-condition SD's percentile bootstrap, which covered 0.80–0.90 at N = 30
against 0.95, by Bonett's interval; the coverage of both intervals is measured by
``bench/agreement_coverage.py`` (docs/study.md).
The Pitman–Morgan test assumes bivariate normal errors; absolute counting errors are discrete
and skewed, so the two can disagree: the bootstrap interval, which assumes neither, is the
statement about the ratio (is 1 in it? is 0.69?), the test its normal-theory companion.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict
from scipy import stats

from endocam.study.effects import BOOTSTRAP_RESAMPLES, CI_LEVEL, percentile_ci, resample_indices
from endocam.study.manifest import Manifest
from endocam.study.responses import ResponseRow

PAPER_SD_RATIO = 0.69  # the paper's SD(orientation) / SD(centring): "31 % lower"
MIN_ASSESSORS = 2  # agreement needs at least two assessors
MIN_VIDEOS = 2  # ... and two videos
MIN_BOOTSTRAP_VIDEOS = 5  # fewer videos give no bootstrap interval (3 videos: 10 distinct draws)
MIN_BONETT_N = 5  # assessors Bonett's SD interval needs (its trim is 1 / (2 sqrt(n - 4)))


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Estimate(_Frozen):
    """A statistic and its bootstrap 95 % interval (None: undefined / too few defined resamples)."""

    value: float | None
    ci95: tuple[float, float] | None


class Agreement(_Frozen):
    """Agreement of the assessors' counts over a set of videos.

    ``icc_f_ci95`` is pingouin's parametric (F-distribution) interval, beside the bootstrap one.
    """

    n_videos: int
    icc2_1: Estimate
    icc_f_ci95: tuple[float, float] | None
    alpha_interval: Estimate


class SDComparison(_Frozen):
    """SD of the last condition's errors against a reference's, on the same assessors."""

    sd_ratio: Estimate
    sd_reduction_pct: float | None
    pitman_morgan_t: float | None
    p_value: float | None
    paper_ratio: float = PAPER_SD_RATIO
    paper_ratio_in_ci: bool | None


class AssessorStatistics(_Frozen):
    """Everything this module computes (``analysis.json``'s ``assessors``)."""

    n_assessors: int
    agreement: dict[str, Agreement]
    sd_across_assessors: dict[str, Estimate]
    sd_comparisons: dict[str, SDComparison]
    n_complete: int
    bootstrap_resamples: int
    bootstrap_seed: int
    note: str | None = None


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def ratings_table(
    rows: Sequence[ResponseRow], manifest: Manifest
) -> tuple[NDArray[np.float64], list[str]]:
    """The reported counts of every video by every assessor who passed and answered them all.

    Returns
    -------
    ratings : (n_videos, n_assessors) float array
        Reported touches; rows in the manifest's video order.
    assessors : list of str
        The participant ids of the columns, sorted.
    """
    ids = [v.id for v in manifest.videos]
    counts: dict[str, dict[str, int]] = {}
    passed: dict[str, bool | None] = {}
    for r in rows:
        counts.setdefault(r.participant_id, {})[r.video_id] = r.reported_touches
        passed[r.participant_id] = r.attention_passed
    keep = sorted(p for p, c in counts.items() if passed[p] is True and all(v in c for v in ids))
    table = np.array([[counts[p][v] for p in keep] for v in ids], dtype=np.float64)
    return table.reshape(len(ids), len(keep)), keep


def icc2_1_batch(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """ICC(2,1) of ``x`` (..., n targets, k raters) from the two-way ANOVA mean squares.

    Returns (...) floats; NaN where the denominator is 0 (every value equal).
    """
    n, k = x.shape[-2], x.shape[-1]
    grand = x.mean(axis=(-2, -1), keepdims=True)
    row = x.mean(axis=-1, keepdims=True)
    col = x.mean(axis=-2, keepdims=True)
    ms_r = k * np.sum((row - grand) ** 2, axis=(-2, -1)) / (n - 1)
    ms_c = n * np.sum((col - grand) ** 2, axis=(-2, -1)) / (k - 1)
    ms_e = np.sum((x - row - col + grand) ** 2, axis=(-2, -1)) / ((n - 1) * (k - 1))
    den = ms_r + (k - 1) * ms_e + k * (ms_c - ms_e) / n
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0.0, (ms_r - ms_e) / den, np.nan)


def alpha_interval_batch(x: NDArray[np.float64]) -> NDArray[np.float64]:
    r"""Krippendorff's α, interval metric, of complete data ``x`` (..., n units, m coders).

    .. math:: D_o = \frac{1}{N} \sum_u \frac{1}{m-1} \sum_{i \ne j} (x_{ui} - x_{uj})^2,
              \quad D_e = \frac{1}{N (N-1)} \sum_{a \ne b} (x_a - x_b)^2, \quad N = n m

    using :math:`\sum_{i \ne j} (x_i - x_j)^2 = 2 m \sum_i (x_i - \bar x)^2` over m values.
    Returns (...) floats; NaN where D_e = 0.
    """
    n, m = x.shape[-2], x.shape[-1]
    big_n = n * m
    within = 2.0 * m * np.sum((x - x.mean(axis=-1, keepdims=True)) ** 2, axis=(-2, -1))
    d_o = within / (m - 1) / big_n
    total = 2.0 * big_n * np.sum((x - x.mean(axis=(-2, -1), keepdims=True)) ** 2, axis=(-2, -1))
    d_e = total / (big_n * (big_n - 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(d_e > 0.0, 1.0 - d_o / d_e, np.nan)


def agreement(ratings: NDArray[np.float64], resamples: int, seed: int) -> Agreement:
    """ICC(2,1) (pingouin) and Krippendorff's α (krippendorff) with video-bootstrap intervals.

    Parameters
    ----------
    ratings : (n_videos, n_assessors) float array
        Reported touches, complete.
    resamples, seed : int
        Bootstrap resamples of the videos and the generator's seed (no bootstrap interval
        below ``MIN_BOOTSTRAP_VIDEOS`` videos).
    """
    import krippendorff
    import pandas as pd
    import pingouin  # slow to import (~2 s): only when agreement is computed

    n, k = ratings.shape
    long = pd.DataFrame(
        {
            "video": np.repeat(np.arange(n), k),
            "assessor": np.tile(np.arange(k), n),
            "count": ratings.ravel(),
        }
    )
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pingouin's pandas deprecations; NaN-F of a tie
        icc = pingouin.intraclass_corr(long, targets="video", raters="assessor", ratings="count")
    table = icc.set_index("Type")
    row = table.loc["ICC(A,1)" if "ICC(A,1)" in table.index else "ICC2"]  # pingouin ≥ 0.7 / older
    lo, hi = (float(v) for v in row["CI95"])
    alpha = krippendorff.alpha(reliability_data=ratings.T, level_of_measurement="interval")
    icc_ci = alpha_ci = None
    if n >= MIN_BOOTSTRAP_VIDEOS:
        boot = ratings[resample_indices(n, resamples, seed)]  # (B, n, k): videos resampled
        icc_ci = percentile_ci(icc2_1_batch(boot))
        alpha_ci = percentile_ci(alpha_interval_batch(boot))
    return Agreement(
        n_videos=n,
        icc2_1=Estimate(value=_finite(row["ICC"]), ci95=icc_ci),
        icc_f_ci95=(lo, hi) if np.isfinite(lo) and np.isfinite(hi) else None,
        alpha_interval=Estimate(value=_finite(alpha), ci95=alpha_ci),
    )


def pitman_morgan(x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[float, float]:
    """Pitman–Morgan test of ``var x == var y`` for paired samples (module docstring).

    x, y : (n,) paired values, n ≥ 3.  Returns ``(t, two-sided p)`` on n − 2 degrees of freedom;
    NaN where ``x``, ``y``, ``x + y`` or ``x − y`` is constant: a constant sample (every
    assessor giving the same error, as discrete counts can) is no bivariate normal, and the
    test would report ``p = 0`` from a correlation of exactly ±1.
    """
    n = x.size
    s, d = x + y, x - y
    if n < 3 or min(np.std(x), np.std(y), np.std(s), np.std(d)) == 0.0:
        return float("nan"), float("nan")
    r = float(np.corrcoef(s, d)[0, 1])
    if abs(r) >= 1.0:  # y exactly linear in x with a slope other than ±1: the SDs surely differ
        return float(np.sign(r) * np.inf), 0.0
    t = r * np.sqrt(n - 2) / np.sqrt(1.0 - r * r)
    return float(t), float(2.0 * stats.t.sf(abs(t), n - 2))


def bonett_sd_interval(x: NDArray[np.float64]) -> tuple[float, float] | None:
    r"""Bonett's (2006) 95 % interval of a standard deviation, for non-normal data.

    .. math:: \sigma \in \sqrt{\exp\bigl(\ln(c s^2) \pm z\, c\,
              \sqrt{(\hat\gamma_4 - (n-3)/n)/(n-1)}\bigr)},
              \quad \hat\gamma_4 = \frac{n \sum (x_i - m)^4}{(\sum (x_i - \bar x)^2)^2},
              \quad c = \frac{n}{n - z}

    with s² the sample variance, z the normal quantile of the level, and m the mean trimmed by
    :math:`1 / (2\sqrt{n - 4})` at each end (``scipy.stats.trim_mean``). Bonett, D. G.,
    "Approximate confidence interval for standard deviation of nonnormal distributions",
    Comput. Stat. Data Anal. (2006). Assumes independent values with a finite fourth
    moment (the kurtosis is estimated, not assumed normal's 3); near nominal for moderate
    skew and kurtosis, somewhat below it for heavy tails (bench/agreement_coverage.py).

    x : (n,) values (errors, touches). Returns (low, high), touches; None if n < ``MIN_BONETT_N``
    or every value is equal.
    """
    n = x.size
    if n < MIN_BONETT_N:
        return None
    ss = float(np.sum((x - x.mean()) ** 2))
    if ss == 0.0:
        return None
    z = float(stats.norm.ppf(0.5 + CI_LEVEL / 2.0))
    m = float(stats.trim_mean(x, 1.0 / (2.0 * np.sqrt(n - 4.0))))
    kurtosis = n * float(np.sum((x - m) ** 4)) / ss**2
    c = n / (n - z)
    se = c * np.sqrt(max(kurtosis - (n - 3.0) / n, 0.0) / (n - 1.0))
    centre = np.log(c * ss / (n - 1.0))
    return float(np.exp((centre - z * se) / 2.0)), float(np.exp((centre + z * se) / 2.0))


def sd_comparisons(
    complete: Mapping[str, NDArray[np.float64]], resamples: int, seed: int
) -> tuple[dict[str, Estimate], dict[str, SDComparison]]:
    """SD across assessors per condition, and the last condition's SD against each other one.

    Parameters
    ----------
    complete : mapping condition → (n,) float array
        Errors (touches) of the same n assessors in every condition, the study's order.
    resamples, seed : int
        Bootstrap resamples of the assessors and the generator's seed (the ratio's percentile
        interval; each SD's interval is Bonett's, :func:`bonett_sd_interval`).
    """
    conds = list(complete)
    n = len(complete[conds[0]]) if conds else 0
    if n < 2:
        none = Estimate(value=None, ci95=None)
        return {c: none for c in conds}, {}
    idx = resample_indices(n, resamples, seed)
    boot_sd = {c: np.std(complete[c][idx], axis=-1, ddof=1) for c in conds}
    sds = {
        c: Estimate(value=float(np.std(complete[c], ddof=1)), ci95=bonett_sd_interval(complete[c]))
        for c in conds
    }
    *refs, last = conds
    out = {}
    for ref in reversed(refs):
        sd_ref, sd_last = sds[ref].value, sds[last].value
        with np.errstate(invalid="ignore", divide="ignore"):
            boot_ratio = np.where(boot_sd[ref] > 0.0, boot_sd[last] / boot_sd[ref], np.nan)
        ci = percentile_ci(boot_ratio)
        ratio = None if not sd_ref or sd_last is None else sd_last / sd_ref
        t, p = pitman_morgan(complete[last], complete[ref])
        out[f"{last}_vs_{ref}"] = SDComparison(
            sd_ratio=Estimate(value=ratio, ci95=ci),
            sd_reduction_pct=None if ratio is None else 100.0 * (1.0 - ratio),
            pitman_morgan_t=_finite(t),
            p_value=_finite(p),
            paper_ratio_in_ci=None if ci is None else bool(ci[0] <= PAPER_SD_RATIO <= ci[1]),
        )
    return sds, out


def assessor_statistics(
    rows: Sequence[ResponseRow],
    manifest: Manifest,
    complete: Mapping[str, NDArray[np.float64]],
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = 0,
) -> AssessorStatistics:
    """Agreement on the counts and the spread of the error across assessors (module docstring).

    Parameters
    ----------
    rows : sequence of ResponseRow
        Every answer.
    manifest : Manifest
        The videos and their conditions.
    complete : mapping condition → (n,) float array
        The analysis's complete cases (errors, touches), for the SD statistics.
    resamples, seed : int
        Bootstrap resamples and the seed of ``numpy.random.default_rng``.
    """
    ratings, assessors = ratings_table(rows, manifest)
    sds, comparisons = sd_comparisons(complete, resamples, seed)
    n_complete = len(next(iter(complete.values()))) if complete else 0
    common = {
        "n_assessors": len(assessors),
        "sd_across_assessors": sds,
        "sd_comparisons": comparisons,
        "n_complete": n_complete,
        "bootstrap_resamples": resamples,
        "bootstrap_seed": seed,
    }
    if len(assessors) < MIN_ASSESSORS:
        note = f"agreement needs at least {MIN_ASSESSORS} assessors with every video answered"
        return AssessorStatistics(agreement={}, note=note, **common)
    groups = {"all videos": list(range(len(manifest.videos)))}
    for c in manifest.conditions:
        groups[c] = [i for i, v in enumerate(manifest.videos) if v.condition == c]
    result = {
        name: agreement(ratings[rows_of], resamples, seed)
        for name, rows_of in groups.items()
        if len(rows_of) >= MIN_VIDEOS
    }
    return AssessorStatistics(agreement=result, **common)
