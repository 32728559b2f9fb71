"""Synthetic assessors with known errors: the exact known values; one replication through
the app's HTTP API, the database and ``analyze`` giving the tests of the in-process path; and
the analysis's rejection rates on many in-process studies, with and without an effect, against
the rates ``study power``'s simulation predicts (and a check that a broken analysis fails)."""

import math
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from endocam.study.analysis import AnalysisConfig, OutlierRule
from endocam.study.effects import rank_biserial
from endocam.study.manifest import Manifest, load_manifest
from endocam.study.power import holm_batch, primary_pair, study_p_values, wilcoxon_batch
from endocam.study.simulate import (
    AGREEMENT_SE,
    PREDICTION_SIMULATIONS,
    AssessorModel,
    Criterion,
    RateCheck,
    error_moments,
    model_errors,
    preset,
    rate_check,
    rejected,
    run_replication,
    true_effects,
)
from study_helpers import k_conditions, make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

MC_DRAWS = 400_000  # reports drawn to check the exact moments
MC_ATOL = 0.01  # touches: well above the Monte Carlo SE (≈ 1.5 / sqrt(MC_DRAWS) · 2)
P_ATOL = 1e-12
N_ASSESSORS = 3  # the fewest the analysis tests
ALPHA = 0.05  # the stated level: Holm keeps the family-wise false-positive rate at or below it
RATE_ASSESSORS = 40  # per simulated study: power ≈ 0.27 with the preset effect (k = 3)
# Replications of the analysis: with them (and the prediction's simulations) a Holm-less
# analysis fails the check with probability ≥ CATCH_HOLM, a one-sided one ≥ CATCH_ONE_SIDED
# (the predicted rates from PREDICTION_SIMULATIONS studies).
EFFECT_REPLICATIONS, NULL_REPLICATIONS = 300, 200
CATCH_HOLM, CATCH_ONE_SIDED = 0.9, 0.8  # probability that the check catches a broken analysis


@pytest.mark.parametrize(("true", "bias", "sd"), [(9, -0.75, 1.05), (1, -1.0, 1.5)])
def test_exact_error_moments_match_drawn_reports(true: int, bias: float, sd: float) -> None:
    rng = np.random.default_rng(11)  # (1, -1, 1.5): clipping at 0 counts
    reports = np.clip(np.rint(true + bias + sd * rng.standard_normal(MC_DRAWS)), 0, 99)
    errors = np.abs(reports - true)
    mean, spread = error_moments(true, bias, sd)
    assert mean == pytest.approx(errors.mean(), abs=MC_ATOL)
    assert spread == pytest.approx(errors.std(), abs=MC_ATOL)


def test_one_replication_through_the_app_is_the_fast_path(tmp_path: Path) -> None:
    study = make_study(  # two conditions: fewer requests (k = 3 is the same code path)
        tmp_path, stub_videos=True, must_watch=True, demographics=True, conditions=k_conditions(2)
    )
    manifest = load_manifest(study)
    model = preset(manifest, effect=True, n_assessors=N_ASSESSORS)
    effects = true_effects(model, manifest)
    assert effects.sd_ratio["centering_vs_fixed"] < 0.8  # the injected effect
    config = AnalysisConfig(outliers=OutlierRule.NONE, bootstrap_resamples=100)
    result, reports = run_replication(study, model, np.random.default_rng(2), config)
    assert result.tests.n_complete == N_ASSESSORS and not result.excluded
    hardest = [manifest.most_difficult(c) for c in manifest.conditions]
    errors = np.stack([np.abs(reports[v.id] - v.true_touches) for v in hardest], axis=-1)
    kept = {c: sorted(v) for c, v in result.kept_errors.items()}
    assert kept == {c: sorted(errors[:, i].tolist()) for i, c in enumerate(manifest.conditions)}
    p_holm, _, _ = study_p_values(errors[None].astype(float), config)
    index, name = primary_pair(manifest.conditions)
    assert result.tests.wilcoxon[name].p_holm == pytest.approx(p_holm[0, index], abs=P_ATOL)


def _catch_probability(check: RateCheck, broken_rate: float) -> float:
    """P(the check fails) for an analysis whose true rejection rate is ``broken_rate``."""
    r, low = check.replications, check.predicted_rate - check.tolerance
    high = check.predicted_rate + check.tolerance
    inside = stats.binom.cdf(math.floor(high * r + 1e-9), r, broken_rate) - stats.binom.cdf(
        math.ceil(low * r - 1e-9) - 1, r, broken_rate
    )
    return float(1.0 - inside)


def _broken_rates(check: RateCheck, model: AssessorModel, manifest: Manifest) -> dict:
    """Rates a Holm-less and a one-sided analysis would give (study power's batched tests)."""
    errors = model_errors(model, manifest, np.random.default_rng(7), PREDICTION_SIMULATIONS)
    pairs = list(combinations(range(len(model.conditions)), 2))
    p_raw = np.stack([wilcoxon_batch(errors[..., i], errors[..., j]) for i, j in pairs], -1)
    p_raw = np.where(np.isfinite(p_raw), p_raw, 1.0)
    effect = np.stack([rank_biserial(errors[..., i], errors[..., j]) for i, j in pairs], -1)
    one_sided = np.where(effect > 0, p_raw / 2.0, 1.0 - p_raw / 2.0)  # "a's errors larger"
    index, _ = primary_pair(model.conditions)
    return {
        name: float(np.mean(rejected(p, effect, check.criterion, index, ALPHA)))
        for name, p in (("no Holm", p_raw), ("one-sided", holm_batch(one_sided)))
    }


@pytest.mark.parametrize(
    ("effect", "replications"), [(True, EFFECT_REPLICATIONS), (False, NULL_REPLICATIONS)]
)
def test_analysis_rejects_at_the_rates_study_power_predicts(
    tmp_path: Path, effect: bool, replications: int
) -> None:
    manifest = load_manifest(make_study(tmp_path, stub_videos=True, conditions=k_conditions(3)))
    model = preset(manifest, effect=effect, n_assessors=RATE_ASSESSORS)
    criterion = Criterion.PRIMARY if effect else Criterion.FAMILYWISE
    check = rate_check(model, manifest, replications, 0, ALPHA, criterion)
    assert check.tolerance == pytest.approx(AGREEMENT_SE * check.mc_se)
    assert check.agrees, check
    if effect:  # with the effect: the power, well away from the level
        assert check.predicted_rate > ALPHA + check.tolerance
    else:  # without: at or below the stated false-positive rate
        assert check.predicted_rate <= ALPHA and check.rate <= ALPHA + check.tolerance
    broken = _broken_rates(check, model, manifest)
    assert _catch_probability(check, broken["no Holm"]) >= CATCH_HOLM, broken
    if effect:  # (without an effect a one-sided test only doubles a small rate)
        assert _catch_probability(check, broken["one-sided"]) >= CATCH_ONE_SIDED, broken
