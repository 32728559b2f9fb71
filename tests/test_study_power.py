"""study power: its batched tests equal the analysis's, its closed form a hand formula, its
simulation the known power of a near-normal model and the level under no effect."""

import gc
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from endocam.cli import main
from endocam.study.analysis import AnalysisConfig, OutlierRule, holm, within_subject_tests
from endocam.study.power import (
    ErrorModel,
    PowerConfig,
    closed_forms,
    draw_errors,
    holm_batch,
    paper_model,
    primary_pair,
    simulate_power,
    study_p_values,
    wilcoxon_batch,
)

P_ATOL = 1e-12  # p-values computed two ways by the same formulas
SIMULATIONS = 400  # simulated studies per check here (the CLI's default is 2000)


@pytest.fixture
def quick_holm(monkeypatch: pytest.MonkeyPatch) -> None:
    """statsmodels' Holm without its full garbage collection per call (~1 s in pytest)."""
    monkeypatch.setattr(gc, "collect", lambda generation=2: 0)  # (imported inside multipletests)


def _model(means: tuple[float, float], sd: float, rho: float) -> ErrorModel:
    return ErrorModel(
        conditions=("a", "b"),
        mean_error=means,
        sd_error=(sd, sd),
        corr=((1.0, rho), (rho, 1.0)),
        discrete=False,
        source="test",
    )


def test_batched_holm_and_wilcoxon_equal_statsmodels_and_scipy_per_row(quick_holm: None) -> None:
    rng = np.random.default_rng(3)
    p = rng.uniform(size=(6, 4)) ** 3
    assert np.allclose(holm_batch(p), [holm(row) for row in p], atol=P_ATOL)
    for n in (9, 24):  # ties/zeros (integers) and none (floats): scipy's methods differ
        a = np.vstack([rng.integers(0, 4, (4, n)), rng.normal(size=(4, n))])
        b = np.vstack([rng.integers(0, 4, (4, n)), rng.normal(size=(4, n))])
        each = [stats.wilcoxon(x, y).pvalue for x, y in zip(a, b, strict=True)]
        assert np.allclose(wilcoxon_batch(a, b), each, atol=P_ATOL)


def test_simulated_tests_are_the_analysis_tests(quick_holm: None) -> None:
    model = paper_model()
    errors = draw_errors(model, 25, 1, np.random.default_rng(5))  # one study
    config = AnalysisConfig(outliers=OutlierRule.NONE)
    p_holm, effect, p_friedman = study_p_values(errors, config)
    table = {c: errors[0, :, i] for i, c in enumerate(model.conditions)}
    ref = within_subject_tests(table, resamples=1, seed=0)
    index, name = primary_pair(model.conditions)
    assert name == "centering_vs_orientation"
    assert p_holm[0, index] == pytest.approx(ref.wilcoxon[name].p_holm, abs=P_ATOL)
    assert effect[0, index] == pytest.approx(ref.wilcoxon[name].rank_biserial, abs=P_ATOL)
    assert ref.friedman is not None
    assert p_friedman[0] == pytest.approx(ref.friedman.p_value, abs=P_ATOL)


def test_closed_form_matches_the_normal_approximation_by_hand() -> None:
    d_z = 0.5
    model = _model((1.0 + d_z, 1.0), 1.0 / math.sqrt(2.0), 0.0)  # sd of differences 1
    cf = closed_forms(model, 0.05, 0.8)
    assert cf["d_z"] == pytest.approx(d_z)
    z_a, z_b = stats.norm.ppf(0.975), stats.norm.ppf(0.8)
    by_hand = ((z_a + z_b) / d_z) ** 2 + z_a**2 / 2.0  # 33.3 (Guenther's correction)
    assert cf["n_paired_t"] == pytest.approx(by_hand, abs=0.5)  # statsmodels: 33.37
    assert cf["n_wilcoxon_are"] == pytest.approx(cf["n_paired_t"] * math.pi / 3.0)


def test_simulated_power_is_the_known_power_and_the_level_without_effect() -> None:
    # near-normal errors (gamma shape 100): the signed-rank test needs n_t * pi / 3 for 0.8
    config = PowerConfig(simulations=SIMULATIONS, seed=1, outliers=OutlierRule.NONE)
    model = _model((10.6, 10.0), 1.0, 0.5)  # d_z = 0.6 (SD of the differences 1)
    n = math.ceil(closed_forms(model, 0.05, 0.8)["n_wilcoxon_are"] or 0)
    point = simulate_power(model, n, config)
    assert point.power == pytest.approx(0.8, abs=4 * point.mc_se + 0.02)
    null = simulate_power(_model((10.0, 10.0), 1.0, 0.5), n, config)
    level = 0.025  # one direction of a two-sided 0.05 test
    assert abs(null.power - level) < 4 * math.sqrt(level * (1 - level) / SIMULATIONS)


def test_cli_power_writes_its_files_and_refuses_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "power"
    args = ["study", "power", "--out", str(out), "--simulations", "100", "--max-n", "8"]
    assert main(args) == 0
    doc = json.loads((out / "power.json").read_text("utf-8"))
    assert doc["config"]["simulations"] == 100 and doc["n_required"] is None  # 8 is too few
    assert "not reached" in (out / "power.md").read_text("utf-8")
    assert (out / "power.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["study", "power", "--out", str(tmp_path / "x"), "--power", "1.5"]) == 2
    assert main(["study", "power", "--out", str(tmp_path / "y"), "--db", "a.db"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-2:] == [
        "endocam: error: --power must be in (0, 1), got 1.5",
        "endocam: error: --study: a pilot (--db or --responses) needs its study folder",
    ]
