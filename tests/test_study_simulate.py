"""Synthetic assessors with known errors: the exact known values, and one replication through
the app's HTTP API, the database and the analysis giving the tests of the fast path."""

from pathlib import Path

import numpy as np
import pytest

from endocam.study.analysis import AnalysisConfig, OutlierRule
from endocam.study.manifest import load_manifest
from endocam.study.power import primary_pair, study_p_values
from endocam.study.simulate import (
    error_moments,
    preset,
    run_replication,
    true_effects,
)
from study_helpers import k_conditions, make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

MC_DRAWS = 400_000  # reports drawn to check the exact moments
MC_ATOL = 0.01  # touches: well above the Monte Carlo SE (≈ 1.5 / sqrt(MC_DRAWS) · 2)
P_ATOL = 1e-12
N_ASSESSORS = 3  # the fewest the analysis tests


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
