"""Analysis of the skill-assessment study (paper Sec. V, Fig. 7).

Pipeline (each step is a pure function; :func:`analyze` chains them):

1. **Assessment error** ``|reported − true|`` (touches) per participant and condition, on the most
   difficult video of each condition (the paper's choice) or, with ``all_videos``, the mean over
   the condition's videos.
2. **Exclusions, in order.** (a) Participants who failed or never answered the attention question
   are removed entirely. (b) Participants without an answer for a needed video are removed
   entirely. (c) Outliers are found per condition among the remaining participants: Tukey's fences
   (outside ``[Q1 − k·IQR, Q3 + k·IQR]``, quartiles by numpy's default linear interpolation,
   default k = 1.5), or ``|z| > 3`` with the sample SD, or none. An outlier is removed **from that
   condition only**: the per-condition n, mean and SD use every value that is not an outlier in
   that condition.
3. **Tests** are within-subject and need complete cases, so they use only the participants that
   have a kept value in every condition (``tests.n_complete``): a Friedman test (three or more
   conditions), then pairwise two-sided Wilcoxon signed-rank tests with Holm's step-down
   correction.
4. **Reductions**: ``100 · (ref − last) / ref`` of the mean and of the SD, for the manifest's
   last condition (the study's proposed camera: ``endocam``, the paper's orientation camera)
   against each other one, nearest first: with the default conditions ref = centering and
   ref = fixed (the paper's 25 %/21 % and 31 %/32 %).

5. **Assessors** (:mod:`endocam.study.agreement`): ICC(2,1) and Krippendorff's α of the counts,
   the SD of the error across assessors per condition, and the SD ratio of the last condition
   against each other one with a Pitman–Morgan test.

Any number k ≥ 2 of conditions is analysed, in the manifest's order.
"""

from __future__ import annotations

import gc
import warnings
from collections.abc import Mapping, Sequence
from enum import StrEnum
from itertools import combinations
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy import stats

from endocam.study.agreement import AssessorStatistics, assessor_statistics
from endocam.study.effects import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    kendall_w,
    percentile_ci,
    rank_biserial,
    resample_indices,
)
from endocam.study.manifest import Manifest
from endocam.study.responses import ResponseRow

MIN_TEST_N = 3  # participants with complete cases needed before any test is run
ZSCORE_THRESHOLD = 3.0  # |z| above which a value is an outlier (z-score rule)
FRIEDMAN_MIN_CONDITIONS = 3  # conditions a Friedman test needs (with two, Wilcoxon is the test)


class OutlierRule(StrEnum):
    """How outliers are found within each condition."""

    TUKEY = "tukey"
    ZSCORE = "zscore"
    NONE = "none"


class AnalysisConfig(BaseModel):
    """Settings of :func:`analyze`.

    Attributes
    ----------
    all_videos : bool
        Mean error over all videos of a condition instead of the most difficult one.
    outliers : OutlierRule
        Outlier rule applied per condition.
    tukey_k : float
        Fence multiplier of the IQR for the Tukey rule (> 0).
    z_threshold : float
        ``|z|`` threshold for the z-score rule (> 0).
    bootstrap_resamples, bootstrap_seed : int
        Resamples (≥ 100) and ``numpy.random.default_rng`` seed of every bootstrap interval
        (effect sizes, agreement, SDs).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
    all_videos: bool = False
    outliers: OutlierRule = OutlierRule.TUKEY
    tukey_k: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 1.5
    z_threshold: Annotated[float, Field(gt=0, allow_inf_nan=False)] = ZSCORE_THRESHOLD
    bootstrap_resamples: Annotated[int, Field(ge=100)] = BOOTSTRAP_RESAMPLES
    bootstrap_seed: Annotated[int, Field(ge=0)] = BOOTSTRAP_SEED


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class ConditionSummary(_Frozen):
    """Per-condition statistics of the assessment error (touches); SD is the sample SD."""

    n: int
    mean_error: float | None
    sd_error: float | None


class Reduction(_Frozen):
    """Percentage reduction of the last condition against a reference one (None if ref is 0)."""

    mean_error_pct: float | None
    sd_error_pct: float | None


class StatResult(_Frozen):
    """One test's statistic and p-value (None where scipy returns NaN)."""

    statistic: float | None
    p_value: float | None


class PairwiseResult(StatResult):
    """A pairwise test with its Holm-adjusted p-value and its effect size.

    ``rank_biserial``: the matched-pairs rank-biserial correlation of ``a`` against ``b``
    (> 0: ``a``'s errors are larger), with a participant-bootstrap 95 % interval
    (:mod:`endocam.study.effects`).
    """

    p_holm: float | None
    rank_biserial: float | None = None
    rank_biserial_ci95: tuple[float, float] | None = None


class WithinSubjectTests(_Frozen):
    """Friedman and pairwise Wilcoxon results on the complete cases."""

    n_complete: int
    friedman: StatResult | None
    wilcoxon: dict[str, PairwiseResult]
    kendall_w: float | None = None
    kendall_w_ci95: tuple[float, float] | None = None
    correction: str = "holm"
    note: str | None = None


class Exclusion(_Frozen):
    """A participant (or one condition of a participant) left out, with the reason."""

    participant_id: str
    reason: str


class AnalysisResult(_Frozen):
    """Result of :func:`analyze`; ``model_dump`` gives exactly the ``analysis.json`` shape."""

    conditions: dict[str, ConditionSummary]
    reductions: dict[str, Reduction]
    tests: WithinSubjectTests
    excluded: list[Exclusion]
    assessors: AssessorStatistics | None = None
    kept_errors: dict[str, list[float]] = Field(default_factory=dict, exclude=True)
    config: AnalysisConfig = Field(default_factory=AnalysisConfig, exclude=True)
    video_ids: dict[str, list[str]] = Field(default_factory=dict, exclude=True)


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def assessment_errors(
    rows: Sequence[ResponseRow], manifest: Manifest, video_ids: Mapping[str, Sequence[str]]
) -> tuple[dict[str, dict[str, float]], list[Exclusion]]:
    """Assessment error per participant and condition, and the participants left out.

    Parameters
    ----------
    rows : sequence of ResponseRow
        Every answer.
    manifest : Manifest
        Ground truth (``true_touches``).
    video_ids : mapping condition → sequence of video ids
        The videos whose errors are averaged per condition.

    Returns
    -------
    errors : dict participant id → {condition: mean |reported − true|, touches}
        Only participants who passed the attention question and answered every needed video.
    excluded : list of Exclusion
        Attention failures first, then incomplete participants.

    Raises
    ------
    ValueError
        ``rows``: an unknown video id, a duplicate answer or inconsistent attention flags.
    """
    known = {v.id for v in manifest.videos}
    answers: dict[str, dict[str, int]] = {}
    attention: dict[str, bool | None] = {}
    for r in rows:
        if r.video_id not in known:
            raise ValueError(f"rows: unknown video {r.video_id!r} (participant {r.participant_id})")
        own = answers.setdefault(r.participant_id, {})
        if r.video_id in own:
            raise ValueError(f"rows: {r.participant_id} answered {r.video_id} twice")
        own[r.video_id] = r.reported_touches
        if attention.setdefault(r.participant_id, r.attention_passed) != r.attention_passed:
            raise ValueError(f"rows: {r.participant_id} has inconsistent attention_passed")
    errors: dict[str, dict[str, float]] = {}
    excluded: list[Exclusion] = []
    incomplete: list[Exclusion] = []
    for pid in sorted(answers):
        if attention[pid] is False:
            excluded.append(Exclusion(participant_id=pid, reason="failed the attention question"))
            continue
        if attention[pid] is None:
            n_given = len(answers[pid])
            if n_given < len(known):  # stopped early: the question was perhaps never shown
                reason = f"did not finish: answered {n_given} of {len(known)} videos"
            else:
                reason = "did not answer the attention question"
            excluded.append(Exclusion(participant_id=pid, reason=reason))
            continue
        needed = [vid for ids in video_ids.values() for vid in ids]
        missing = [vid for vid in needed if vid not in answers[pid]]
        if missing:
            reason = f"incomplete: no answer for {', '.join(missing)}"
            incomplete.append(Exclusion(participant_id=pid, reason=reason))
            continue
        errors[pid] = {
            cond: float(
                np.mean([abs(answers[pid][v] - manifest.video(v).true_touches) for v in ids])
            )
            for cond, ids in video_ids.items()
        }
    return errors, excluded + incomplete


def outlier_mask(
    values: NDArray[np.float64], rule: OutlierRule, tukey_k: float = 1.5, z_threshold: float = 3.0
) -> tuple[NDArray[np.bool_], str]:
    """Flag outliers in one condition's errors.

    Parameters
    ----------
    values : (n,) float array
        Assessment errors, touches.
    rule : OutlierRule
        Tukey's fences, z-score or none.
    tukey_k : float
        IQR multiplier of the fences.
    z_threshold : float
        ``|z|`` threshold (sample SD, ddof = 1).

    Returns
    -------
    mask : (n,) bool array
        True where the value is an outlier.
    description : str
        The rule with its numbers, for the report.
    """
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 1:
        raise ValueError(f"values must be 1-D, got shape {values.shape}")
    none = np.zeros(values.shape, dtype=bool)
    if rule == OutlierRule.NONE or values.size < 2:
        return none, "no outlier rule"
    if rule == OutlierRule.TUKEY:
        q1, q3 = np.percentile(values, [25.0, 75.0])
        low, high = q1 - tukey_k * (q3 - q1), q3 + tukey_k * (q3 - q1)
        text = f"Tukey fences [{low:g}, {high:g}] (Q1 {q1:g}, Q3 {q3:g}, k {tukey_k:g})"
        return (values < low) | (values > high), text
    sd = float(np.std(values, ddof=1))
    if sd == 0.0:
        return none, f"|z| > {z_threshold:g} (SD 0)"
    z = (values - values.mean()) / sd
    return np.abs(z) > z_threshold, f"|z| > {z_threshold:g} (mean {values.mean():g}, SD {sd:g})"


def holm(p_values: Sequence[float]) -> list[float]:
    r"""Holm's step-down adjusted p-values (``statsmodels``' ``multipletests(method="holm")``).

    .. math:: \tilde p_{(i)} = \min\bigl(1, \max_{j \le i} (m - j + 1)\, p_{(j)}\bigr)

    ``multipletests`` runs a full garbage collection on every Holm call (0.1–0.5 s in a process
    that has imported the scientific stack, more than the rest of an analysis's tests), so the
    objects that exist before the call are frozen out of it (:func:`gc.freeze`): the collection
    then visits only what the call made (~20 µs).

    Parameters
    ----------
    p_values : sequence of m floats in [0, 1]

    Returns
    -------
    list of m floats
        Adjusted p-values in the input order.
    """
    p = np.asarray(p_values, dtype=np.float64)
    if p.ndim != 1 or np.any((p < 0) | (p > 1)) or np.any(np.isnan(p)):
        raise ValueError(f"p_values must be a 1-D sequence in [0, 1], got {list(p_values)}")
    if p.size == 0:
        return []
    from statsmodels.stats.multitest import multipletests  # the study extra; imported on use

    gc.freeze()
    try:
        adjusted = multipletests(p, method="holm")[1]
    finally:
        gc.unfreeze()
    return [float(x) for x in adjusted]


def within_subject_tests(
    complete: Mapping[str, NDArray[np.float64]],
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> WithinSubjectTests:
    """Friedman test (k ≥ 3 conditions), then pairwise Wilcoxon signed-rank tests with Holm.

    Parameters
    ----------
    complete : mapping condition → (n,) float array
        Errors of the same n participants (complete cases) in each condition, same order; the
        conditions in the study's order.
    resamples, seed : int
        The participant bootstrap of the effect sizes' intervals (:mod:`endocam.study.effects`).

    Returns
    -------
    WithinSubjectTests
        ``friedman`` is None and ``wilcoxon`` empty when n < ``MIN_TEST_N``; ``friedman`` is
        None with two conditions (the one Wilcoxon test is the test). Kendall's W goes with the
        Friedman test, a rank-biserial correlation with each Wilcoxon test, each with its
        bootstrap 95 % interval.
    """
    conds = list(complete)
    n = len(complete[conds[0]]) if conds else 0
    if n < MIN_TEST_N:
        note = f"tests need at least {MIN_TEST_N} complete cases, have {n}"
        return WithinSubjectTests(n_complete=n, friedman=None, wilcoxon={}, note=note)
    table = np.column_stack([complete[c] for c in conds])  # (n, k)
    boot = table[resample_indices(n, resamples, seed)]  # (B, n, k): participants resampled
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # scipy warns when all values tie
        fr = (
            stats.friedmanchisquare(*(complete[c] for c in conds))
            if len(conds) >= FRIEDMAN_MIN_CONDITIONS
            else None
        )
        pairs = list(combinations(range(len(conds)), 2))
        raw = [stats.wilcoxon(table[:, i], table[:, j]) for i, j in pairs]
    p_raw = [float(r.pvalue) if np.isfinite(r.pvalue) else 1.0 for r in raw]
    p_adj = holm(p_raw)
    wilcoxon = {}
    for m, ((i, j), r) in enumerate(zip(pairs, raw, strict=True)):
        effect = float(rank_biserial(table[:, i], table[:, j]))
        wilcoxon[f"{conds[i]}_vs_{conds[j]}"] = PairwiseResult(
            statistic=_finite_or_none(r.statistic),
            p_value=_finite_or_none(r.pvalue),
            p_holm=p_adj[m] if np.isfinite(r.pvalue) else None,
            rank_biserial=_finite_or_none(effect),
            rank_biserial_ci95=percentile_ci(rank_biserial(boot[..., i], boot[..., j])),
        )
    if fr is None:
        why: str | None = f"two conditions: no Friedman test (it needs {FRIEDMAN_MIN_CONDITIONS})"
        w, w_ci = None, None
    else:
        why = None if np.isfinite(fr.pvalue) else "all errors tie: the Friedman test is undefined"
        w = _finite_or_none(float(fr.statistic) / (n * (len(conds) - 1)))
        w_ci = percentile_ci(kendall_w(boot))
    return WithinSubjectTests(
        n_complete=n,
        friedman=None
        if fr is None
        else StatResult(
            statistic=_finite_or_none(fr.statistic), p_value=_finite_or_none(fr.pvalue)
        ),
        wilcoxon=wilcoxon,
        kendall_w=w,
        kendall_w_ci95=w_ci,
        note=why,
    )


def _summary(values: NDArray[np.float64]) -> ConditionSummary:
    return ConditionSummary(
        n=int(values.size),
        mean_error=float(values.mean()) if values.size else None,
        sd_error=float(np.std(values, ddof=1)) if values.size > 1 else None,
    )


def _reduction(ref: float | None, new: float | None) -> float | None:
    if ref is None or new is None or ref == 0.0:
        return None
    return 100.0 * (ref - new) / ref


def analyze(
    rows: Sequence[ResponseRow], manifest: Manifest, config: AnalysisConfig | None = None
) -> AnalysisResult:
    """Run the whole analysis (see the module docstring for every rule).

    Parameters
    ----------
    rows : sequence of ResponseRow
        Every answer (from the database or a responses CSV).
    manifest : Manifest
        Ground truth and the difficulty of each video.
    config : AnalysisConfig, optional
        Video selection and outlier rule; defaults as in the paper.

    Returns
    -------
    AnalysisResult
        Per-condition statistics, reductions, tests and the exclusion list.

    Raises
    ------
    ValueError
        No rows at all (an empty export), or inconsistent rows (one line).
    """
    if not rows:
        raise ValueError("no responses to analyse (the source has no answers)")
    config = config or AnalysisConfig()
    video_ids = {
        c: [v.id for v in manifest.videos_of(c)]
        if config.all_videos
        else [manifest.most_difficult(c).id]
        for c in manifest.conditions
    }
    errors, excluded = assessment_errors(rows, manifest, video_ids)
    pids = sorted(errors)
    kept: dict[str, set[str]] = {}
    for cond in manifest.conditions:
        values = np.array([errors[p][cond] for p in pids], dtype=np.float64)
        mask, rule = outlier_mask(values, config.outliers, config.tukey_k, config.z_threshold)
        for pid, value in zip(np.array(pids)[mask], values[mask], strict=True):
            reason = f"outlier in {cond}: error {value:g} outside {rule}"
            excluded.append(Exclusion(participant_id=str(pid), reason=reason))
        kept[cond] = {p for p, out in zip(pids, mask, strict=True) if not out}
    kept_errors = {c: np.array([errors[p][c] for p in pids if p in kept[c]]) for c in kept}
    summaries = {c: _summary(kept_errors[c]) for c in manifest.conditions}
    complete_ids = [p for p in pids if all(p in kept[c] for c in manifest.conditions)]
    complete = {c: np.array([errors[p][c] for p in complete_ids]) for c in manifest.conditions}
    *refs, last = manifest.conditions
    new = summaries[last]
    reductions = {
        f"{last}_vs_{ref}": Reduction(
            mean_error_pct=_reduction(summaries[ref].mean_error, new.mean_error),
            sd_error_pct=_reduction(summaries[ref].sd_error, new.sd_error),
        )
        for ref in reversed(refs)
    }
    return AnalysisResult(
        conditions=summaries,
        reductions=reductions,
        tests=within_subject_tests(complete, config.bootstrap_resamples, config.bootstrap_seed),
        assessors=assessor_statistics(
            rows, manifest, complete, config.bootstrap_resamples, config.bootstrap_seed
        ),
        excluded=excluded,
        kept_errors={c: [float(x) for x in v] for c, v in kept_errors.items()},
        config=config,
        video_ids=dict(video_ids),
    )


def result_json(result: AnalysisResult) -> dict[str, Any]:
    """The ``analysis.json`` document: keys conditions, reductions, tests, excluded."""
    return result.model_dump(mode="json")
