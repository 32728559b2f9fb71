"""study power: its batched tests equal the analysis's, its closed form a hand formula, its
simulation the known power of a near-normal model and the level under no effect."""

import gc
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from statsmodels.stats.multitest import multipletests

from endocam.cli import main
from endocam.study.analysis import AnalysisConfig, OutlierRule, within_subject_tests
from endocam.study.manifest import load_manifest
from endocam.study.power import (
    PAPER_CV,
    PAPER_RHO,
    ErrorModel,
    PowerConfig,
    closed_forms,
    draw_errors,
    holm_batch,
    paper_model,
    pilot_model,
    primary_pair,
    simulate_power,
    study_p_values,
    wilcoxon_batch,
)
from endocam.study.responses import ResponseRow, rows_to_csv
from study_helpers import make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

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
    assert np.allclose(
        holm_batch(p), [multipletests(row, method="holm")[1] for row in p], atol=P_ATOL
    )
    for n in (9, 24):  # ties/zeros (integers) and none (floats): scipy's methods differ
        # (9 with ties: scipy's exact permutation test, here signflip_p)
        a = np.vstack([rng.integers(0, 4, (4, n)), rng.normal(size=(4, n))])
        b = np.vstack([rng.integers(0, 4, (4, n)), rng.normal(size=(4, n))])
        each = [stats.wilcoxon(x, y).pvalue for x, y in zip(a, b, strict=True)]
        assert np.allclose(wilcoxon_batch(a, b), each, atol=P_ATOL)


def test_simulated_tests_are_the_analysis_tests() -> None:
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


def _pilot(study: Path) -> tuple[list[ResponseRow], list[list[int]]]:
    """Answers of 5 pilot assessors (one fails the attention question) and, by hand, the
    errors on each condition's most difficult video (v03, v06, v09) of the 4 who pass."""
    manifest = load_manifest(study)
    rows = []
    for k in range(5):
        for v in manifest.videos:
            rows.append(
                ResponseRow(
                    participant_id=f"p{k}",
                    video_id=v.id,
                    reported_touches=v.true_touches + (k * int(v.id[1:]) + int(v.id[1:]) // 3) % 4,
                    attention_passed=k != 4,
                )
            )
    errors = [[1, 2, 3], [0, 0, 0], [3, 2, 1], [2, 0, 2]]  # (k n + n // 3) mod 4, n = 3, 6, 9
    return rows, errors


def test_pilot_model_is_the_pilots_errors(tmp_path: Path) -> None:
    study = make_study(tmp_path, stub_videos=True)
    rows, errors = _pilot(study)
    model = pilot_model(rows, load_manifest(study))
    table = np.array(errors, dtype=float)
    assert model.n_pilot == 4 and model.discrete
    assert np.allclose(model.mean_error, table.mean(axis=0))
    assert np.allclose(model.sd_error, table.std(axis=0, ddof=1))
    # the paper's model: d_z from its figures and the stated assumptions, by hand
    s_ii = PAPER_CV
    s_iii = 0.69 * s_ii
    sd_d = math.sqrt(s_ii**2 + s_iii**2 - 2 * PAPER_RHO * s_ii * s_iii)
    assert closed_forms(paper_model(), 0.05, 0.8)["d_z"] == pytest.approx(0.25 / sd_d)


def test_cli_power_writes_its_files_and_refuses_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    study = make_study(tmp_path, stub_videos=True)
    responses = tmp_path / "pilot.csv"
    responses.write_text(rows_to_csv(_pilot(study)[0]), encoding="utf-8")
    out = tmp_path / "power"
    args = ["study", "power", "--out", str(out), "--simulations", "100", "--max-n", "8"]
    assert main([*args, "--study", str(study), "--responses", str(responses)]) == 0
    doc = json.loads((out / "power.json").read_text("utf-8"))
    assert doc["config"]["simulations"] == 100 and doc["curve"][0]["n"] == 5
    assert doc["model"]["source"] == "pilot of 4 assessors"
    assert doc["expected_direction"].startswith("orientation's errors larger")  # as the pilot's
    assert (doc["n_required"] is None) == ("not reached" in (out / "power.md").read_text("utf-8"))
    assert (out / "power.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["study", "power", "--out", str(tmp_path / "x"), "--power", "1.5"]) == 2
    assert main(["study", "power", "--out", str(tmp_path / "y"), "--db", "a.db"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-2:] == [
        "endocam: error: --power must be in (0, 1), got 1.5",
        "endocam: error: --study: a pilot (--db or --responses) needs its study folder",
    ]
