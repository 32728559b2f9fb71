"""Assessor statistics and effect sizes against values worked by hand on small tables."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from endocam.study.agreement import (
    PAPER_SD_RATIO,
    agreement,
    alpha_interval_batch,
    assessor_statistics,
    bonett_sd_interval,
    icc2_1_batch,
    pitman_morgan,
    ratings_table,
    sd_comparisons,
)
from endocam.study.effects import kendall_w, percentile_ci, rank_biserial
from endocam.study.manifest import parse_manifest
from endocam.study.responses import ResponseRow
from study_helpers import manifest_dict

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

REL = 1e-12  # relative tolerance: float64 arithmetic on small integers
ATOL = 1e-12  # absolute tolerance of a dimensionless coefficient near 0
RESAMPLES = 400  # bootstrap resamples in these tests

# 4 videos (rows) counted by 3 assessors (columns), touches.
COUNTS = np.array([[1, 2, 3], [4, 4, 7], [6, 8, 7], [1, 3, 2]], dtype=np.float64)


def test_icc_2_1_of_a_table_worked_by_hand() -> None:
    # n = 4 videos, k = 3 assessors; grand mean 4; row means 2, 5, 7, 2; column means 3, 17/4, 19/4.
    # SS_rows = k Σ (row − 4)² = 3 (4 + 1 + 9 + 4) = 54            → MS_R = 54 / 3 = 18
    # SS_cols = n Σ (col − 4)² = 4 (1 + 1/16 + 9/16) = 13/2       → MS_C = 13/4
    # SS_total = Σ (x − 4)² = 14 + 9 + 29 + 14 = 66; SS_E = 66 − 54 − 13/2 = 11/2 → MS_E = 11/12
    # ICC(2,1) = (MS_R − MS_E) / (MS_R + (k−1) MS_E + k (MS_C − MS_E) / n)
    #          = (205/12) / (18 + 22/12 + 3 (28/12) / 4) = (205/12) / (259/12) = 205/259
    by_hand = 205 / 259
    assert icc2_1_batch(COUNTS) == pytest.approx(by_hand, rel=REL)
    result = agreement(COUNTS, RESAMPLES, seed=0)  # pingouin's ICC(A,1)
    assert result.icc2_1.value == pytest.approx(by_hand, rel=REL)
    assert result.n_videos == 4 and result.icc_f_ci95 is not None
    assert result.icc2_1.ci95 is None  # four videos: too few to bootstrap
    lo, hi = agreement(np.vstack([COUNTS, COUNTS + 1]), RESAMPLES, seed=0).icc2_1.ci95 or (2, 2)
    assert -1.0 <= lo <= hi <= 1.0


def test_krippendorff_alpha_interval_of_a_table_worked_by_hand() -> None:
    # α = 1 − D_o / D_e, N = 12 values, m = 3 per video.
    # Σ over ordered pairs within a video of (x_i − x_j)², divided by m − 1 = 2:
    #   (1,2,3): 2·6/2 = 6; (4,4,7): 2·18/2 = 18; (6,8,7): 6; (1,3,2): 6 → Σ = 36, D_o = 36/12 = 3
    # over all ordered pairs of the 12 values: 2 · N · Σ (x − 4)² = 2 · 12 · 66 = 1584,
    #   D_e = 1584 / (12 · 11) = 12 → α = 1 − 3/12 = 3/4
    by_hand = 0.75
    assert alpha_interval_batch(COUNTS) == pytest.approx(by_hand, rel=REL)
    assert agreement(COUNTS, RESAMPLES, seed=0).alpha_interval.value == pytest.approx(
        by_hand, rel=REL
    )


def test_the_vectorised_bootstrap_formulas_equal_the_libraries() -> None:
    import krippendorff

    rng = np.random.default_rng(3)
    for _ in range(5):
        x = rng.integers(0, 12, size=(7, 5)).astype(np.float64)
        lib = krippendorff.alpha(reliability_data=x.T, level_of_measurement="interval")
        assert alpha_interval_batch(x) == pytest.approx(lib, rel=1e-9, abs=ATOL)
        assert agreement(x, 100, seed=0).icc2_1.value == pytest.approx(
            icc2_1_batch(x), rel=1e-9, abs=ATOL
        )


def test_pitman_morgan_of_a_table_worked_by_hand() -> None:
    x = np.array([1.0, 3.0, 5.0, 7.0])
    y = np.array([2.0, 3.0, 3.0, 4.0])
    # S = x + y = 3, 6, 8, 11 (mean 7); D = x − y = −1, 0, 2, 3 (mean 1)
    # Σ dS dD = 8 + 1 + 1 + 8 = 18, Σ dS² = 34, Σ dD² = 10 → r² = 324 / 340, 1 − r² = 16 / 340
    # t = r √(n − 2) / √(1 − r²) = √(324 · 2 / 16) = √40.5  (var x / var y = 10: SD ratio √10)
    # t on 2 df: P(|T| > t) = 1 − t / √(t² + 2) = 1 − √(40.5 / 42.5) = 1 − 9 / √85
    t, p = pitman_morgan(x, y)
    assert t == pytest.approx(math.sqrt(40.5), rel=REL)
    assert p == pytest.approx(1.0 - 9.0 / math.sqrt(85.0), rel=1e-9)
    t_swapped, p_swapped = pitman_morgan(y, x)  # the smaller SD first: the sign flips
    assert t_swapped == pytest.approx(-t, rel=REL) and p_swapped == pytest.approx(p, rel=REL)
    assert math.isnan(pitman_morgan(x, x + 1.0)[0])  # D constant: undefined
    assert math.isnan(pitman_morgan(x, np.full_like(x, 2.0))[1])  # y constant: no p = 0


def test_sd_across_assessors_and_the_ratio() -> None:
    complete = {"fixed": np.array([1.0, 3.0, 5.0, 7.0]), "endocam": np.array([2.0, 3.0, 3.0, 4.0])}
    sds, comp = sd_comparisons(complete, RESAMPLES, seed=0)
    # SD of 1, 3, 5, 7 = √(20/3); of 2, 3, 3, 4 = √(2/3): ratio √(1/10)
    assert sds["fixed"].value == pytest.approx(math.sqrt(20 / 3), rel=REL)
    ratio = comp["endocam_vs_fixed"]
    assert ratio.sd_ratio.value == pytest.approx(math.sqrt(0.1), rel=REL)
    assert ratio.sd_reduction_pct == pytest.approx(100 * (1 - math.sqrt(0.1)), rel=REL)
    assert ratio.pitman_morgan_t == pytest.approx(-math.sqrt(40.5), rel=REL)
    assert sds["fixed"].ci95 is None  # four assessors: too few for Bonett's interval
    assert ratio.paper_ratio == PAPER_SD_RATIO
    lo, hi = ratio.sd_ratio.ci95 or (np.nan, np.nan)
    assert 0.0 <= lo <= hi


def test_bonett_sd_interval_of_a_sample_worked_by_hand() -> None:
    x = np.arange(1.0, 11.0)  # n = 10, mean 5.5, Σ(x − 5.5)² = 82.5, s² = 82.5 / 9
    # trim 1 / (2 √6) = 0.20 → 2 values cut at each end: trimmed mean of 3..8 = 5.5
    # Σ(x − 5.5)⁴ = 2 (0.5⁴ + 1.5⁴ + 2.5⁴ + 3.5⁴ + 4.5⁴) = 1208.625
    kurtosis = 10 * 1208.625 / 82.5**2  # 1.7758 (a uniform's is 1.8)
    z = stats.norm.ppf(0.975)
    c = 10 / (10 - z)  # 1.2438
    se = c * math.sqrt((kurtosis - 7 / 10) / 9)  # 0.4300
    var_lo, var_hi = (c * 82.5 / 9 * math.exp(s * z * se) for s in (-1, 1))  # 4.908, 26.484
    lo, hi = bonett_sd_interval(x) or (np.nan, np.nan)
    assert (lo, hi) == pytest.approx((math.sqrt(var_lo), math.sqrt(var_hi)), rel=REL)
    assert (lo, hi) == pytest.approx((2.2155, 5.1462), abs=1e-4)
    assert bonett_sd_interval(np.full(10, 3.0)) is None  # no spread: no interval


def test_a_known_sd_reduction_is_found_and_none_is_not() -> None:
    rng = np.random.default_rng(7)
    n = 60
    ref = rng.normal(5.0, 2.0, n)
    # the same assessors: correlated errors, the last condition's spread 0.69 of the reference's
    same = 5.0 + 0.5 * (ref - 5.0) + rng.normal(0.0, 2.0 * math.sqrt(0.69**2 - 0.25), n)
    _, comp = sd_comparisons({"ref": ref, "new": same}, 1000, seed=0)
    c = comp["new_vs_ref"]
    assert c.p_value is not None and c.p_value < 0.05
    assert c.sd_ratio.ci95 is not None and c.sd_ratio.ci95[1] < 1.0
    _, null = sd_comparisons({"ref": ref, "new": rng.permutation(ref)}, 1000, seed=0)
    assert null["new_vs_ref"].p_value is not None and null["new_vs_ref"].p_value > 0.05


def test_rank_biserial_of_a_table_worked_by_hand() -> None:
    a = np.array([3.0, 5.0, 2.0, 4.0, 4.0])
    b = np.array([1.0, 6.0, 2.0, 1.0, 2.0])
    # d = 2, −1, 0, 3, 2; the zero is dropped; ranks of |d| = 2, 1, 3, 2 → 2.5, 1, 4, 2.5
    # T+ = 2.5 + 4 + 2.5 = 9, T− = 1 → r = (9 − 1) / (9 + 1) = 0.8
    assert rank_biserial(a, b) == pytest.approx(0.8, rel=REL)
    assert rank_biserial(b, a) == pytest.approx(-0.8, rel=REL)
    batch = rank_biserial(np.stack([a, b]), np.stack([b, a]))  # along the last axis
    assert batch == pytest.approx([0.8, -0.8], rel=REL)
    assert np.isnan(rank_biserial(a, a))


def test_kendall_w_of_a_table_worked_by_hand() -> None:
    errors = np.array([[1, 2, 3], [1, 5, 4], [0, 2, 7], [3, 1, 6]], dtype=np.float64)
    # ranks per assessor: (1,2,3), (1,3,2), (1,2,3), (2,1,3) → rank sums R = 5, 8, 11
    # S = Σ (R − n(k+1)/2)² = 9 + 0 + 9 = 18; W = 12 S / (n² (k³ − k)) = 216 / 384 = 0.5625
    assert kendall_w(errors) == pytest.approx(0.5625, rel=REL)
    rng = np.random.default_rng(5)
    for _ in range(5):  # with ties: W = Friedman χ² (tie-corrected) / (n (k − 1))
        x = rng.integers(0, 3, size=(6, 4)).astype(np.float64)
        fr = stats.friedmanchisquare(*x.T)
        assert kendall_w(x) == pytest.approx(fr.statistic / (6 * 3), rel=1e-9)


def test_percentile_ci_needs_enough_defined_resamples() -> None:
    assert percentile_ci(np.array([np.nan] * 6 + [1.0] * 4)) is None
    lo, hi = percentile_ci(np.arange(101, dtype=np.float64)) or (np.nan, np.nan)
    assert (lo, hi) == pytest.approx((2.5, 97.5), rel=REL)


def test_ratings_keep_only_assessors_who_passed_and_answered_everything() -> None:
    manifest = parse_manifest(json.dumps(manifest_dict()))
    rows = []
    for pid, passed, skip in (
        ("a", True, None),
        ("b", False, None),
        ("c", True, "v09"),
        ("d", True, None),
    ):
        rows += [
            ResponseRow(
                participant_id=pid,
                video_id=v.id,
                reported_touches=v.true_touches + (pid == "d"),
                attention_passed=passed,
            )
            for v in manifest.videos
            if v.id != skip
        ]
    table, who = ratings_table(rows, manifest)
    assert who == ["a", "d"] and table.shape == (9, 2)
    assert np.all(table[:, 1] - table[:, 0] == 1)
    stats_ = assessor_statistics(rows, manifest, {c: np.array([]) for c in manifest.conditions})
    assert stats_.n_assessors == 2 and set(stats_.agreement) == {"all videos", *manifest.conditions}
    one = assessor_statistics(rows[:9], manifest, {c: np.array([]) for c in manifest.conditions})
    assert one.agreement == {} and "at least 2" in (one.note or "")
