import gc
import json
import statistics
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from endocam.runner.outputs import OUTPUT_MARKER
from endocam.study.analysis import (
    AnalysisConfig,
    OutlierRule,
    analyze,
    holm,
    outlier_mask,
)
from endocam.study.manifest import parse_manifest
from endocam.study.report import hidden_by_text, write_outputs
from endocam.study.responses import ResponseRow, rows_from_csv, rows_to_csv
from study_helpers import manifest_dict

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

REL = 1e-12  # relative tolerance of float statistics (pure float64 arithmetic)
P_ATOL = 1e-15  # p-values: the same float64 operations as statsmodels
MANIFEST = parse_manifest(json.dumps(manifest_dict()))
TRUE = {v.id: v.true_touches for v in MANIFEST.videos}
HARDEST = {"fixed": "v03", "centering": "v06", "orientation": "v09"}  # difficulty 3
# designed assessment errors on the hardest videos: participant → (fixed, centering, orientation)
DESIGN = {
    "p01": (2, 3, 1),
    "p02": (3, 2, 1),
    "p03": (1, 4, 0),
    "p04": (2, 3, 2),
    "p05": (4, 2, 1),
    "p06": (3, 3, 1),
    "p07": (2, 4, 2),
    "p08": (3, 2, 40),  # gross outlier in orientation only
}
OTHER_ERROR = 1  # error on the easier videos (ignored by default)


def _rows(design: dict[str, tuple[int, int, int]], passed: bool | None = True) -> list[ResponseRow]:
    rows = []
    for k, (pid, errors) in enumerate(design.items()):
        error_of = dict(zip(HARDEST.values(), errors, strict=True))
        for vid, true in TRUE.items():
            e = error_of.get(vid, OTHER_ERROR)
            reported = true - e if (k % 2 and true >= e) else true + e  # both signs of the error
            rows.append(
                ResponseRow(
                    participant_id=pid,
                    video_id=vid,
                    reported_touches=reported,
                    attention_passed=passed,
                )
            )
    return rows


def _study_rows() -> list[ResponseRow]:
    rows = _rows(DESIGN)
    rows += _rows({"p09": (30, 30, 30)}, passed=False)  # failed attention
    rows += _rows({"p10": (0, 0, 0)}, passed=None)  # never answered it
    rows += [r for r in _rows({"p11": (1, 1, 1)}) if r.video_id != "v09"]  # incomplete
    return rows


def test_paper_analysis_with_exclusions_and_outlier() -> None:
    result = analyze(_study_rows(), MANIFEST)
    kept = {
        "fixed": [DESIGN[p][0] for p in DESIGN],
        "centering": [DESIGN[p][1] for p in DESIGN],
        "orientation": [DESIGN[p][2] for p in DESIGN if p != "p08"],
    }
    for cond, values in kept.items():
        s = result.conditions[cond]
        assert s.n == len(values)
        assert s.mean_error == pytest.approx(statistics.mean(values), rel=REL)
        assert s.sd_error == pytest.approx(statistics.stdev(values), rel=REL)
    orient = result.conditions["orientation"]
    for ref in ("centering", "fixed"):
        red = result.reductions[f"orientation_vs_{ref}"]
        ref_s = result.conditions[ref]
        expected_mean = (
            100 * (statistics.mean(kept[ref]) - orient.mean_error) / statistics.mean(kept[ref])
        )
        expected_sd = (
            100 * (statistics.stdev(kept[ref]) - orient.sd_error) / statistics.stdev(kept[ref])
        )
        assert red.mean_error_pct == pytest.approx(expected_mean, rel=REL)
        assert red.sd_error_pct == pytest.approx(expected_sd, rel=REL)
        assert ref_s.mean_error > orient.mean_error  # the design favours orientation
    excluded = [(e.participant_id, e.reason) for e in result.excluded]
    assert [p for p, _ in excluded] == ["p09", "p10", "p11", "p08"]
    assert "failed the attention" in excluded[0][1]
    assert "did not answer the attention" in excluded[1][1]
    assert "v09" in excluded[2][1]
    assert excluded[3][1].startswith("outlier in orientation: error 40")
    # tests on the complete cases p01..p07
    complete = [p for p in DESIGN if p != "p08"]
    cols = [np.array([DESIGN[p][i] for p in complete], dtype=float) for i in range(3)]
    assert result.tests.n_complete == len(complete)
    fr = stats.friedmanchisquare(*cols)
    assert result.tests.friedman is not None
    assert result.tests.friedman.p_value == pytest.approx(fr.pvalue, rel=REL)
    w = stats.wilcoxon(cols[1], cols[2])
    pair = result.tests.wilcoxon["centering_vs_orientation"]
    assert pair.p_value == pytest.approx(w.pvalue, rel=REL)
    assert pair.p_holm is not None and pair.p_holm >= pair.p_value
    assert set(result.tests.wilcoxon) == {
        "fixed_vs_centering",
        "fixed_vs_orientation",
        "centering_vs_orientation",
    }


def test_a_participant_who_stopped_early_is_not_said_to_have_skipped_the_question() -> None:
    partial = _rows({"p12": (1, 1, 1)}, passed=None)[:4]  # left after 4 of 9 answers
    result = analyze(_rows(DESIGN) + partial, MANIFEST)
    reasons = {e.participant_id: e.reason for e in result.excluded}
    assert reasons["p12"] == "did not finish: answered 4 of 9 videos"


def test_no_rows_is_an_error() -> None:
    with pytest.raises(ValueError, match="no responses"):
        analyze([], MANIFEST)


def test_no_outlier_rule_keeps_the_gross_value() -> None:
    result = analyze(_study_rows(), MANIFEST, AnalysisConfig(outliers=OutlierRule.NONE))
    orientation = [DESIGN[p][2] for p in DESIGN]
    assert result.conditions["orientation"].n == len(DESIGN)
    assert result.conditions["orientation"].mean_error == pytest.approx(
        statistics.mean(orientation)
    )
    assert [e.participant_id for e in result.excluded] == ["p09", "p10", "p11"]


def test_all_videos_averages_the_three_errors() -> None:
    result = analyze(_rows(DESIGN), MANIFEST, AnalysisConfig(all_videos=True, outliers="none"))
    # each condition: two easier videos with error OTHER_ERROR plus the designed one
    for i, cond in enumerate(("fixed", "centering", "orientation")):
        per_participant = [(2 * OTHER_ERROR + DESIGN[p][i]) / 3 for p in DESIGN]
        assert result.conditions[cond].mean_error == pytest.approx(statistics.mean(per_participant))


def test_outlier_rules() -> None:
    values = np.array([1.0, 1.0, 0.0, 2.0, 1.0, 1.0, 2.0, 40.0])
    mask, text = outlier_mask(values, OutlierRule.TUKEY, tukey_k=1.5)
    assert mask.tolist() == [False] * 7 + [True]
    assert "Tukey" in text
    wide, _ = outlier_mask(values, OutlierRule.TUKEY, tukey_k=100.0)
    assert not wide.any()
    rng = np.random.default_rng(7)
    many = np.concatenate([rng.normal(2.0, 0.5, 40), [50.0]])
    zmask, _ = outlier_mask(many, OutlierRule.ZSCORE, z_threshold=3.0)
    assert zmask.tolist() == [False] * 40 + [True]
    none, _ = outlier_mask(values, OutlierRule.NONE)
    assert not none.any()


def test_holm_step_down() -> None:
    # sorted: 0.01·3 = 0.03; 0.03·2 = 0.06; 0.04·1 = 0.04 → monotone 0.06
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5, 0.6]) == pytest.approx([1.0, 1.0])
    with pytest.raises(ValueError, match="p_values"):
        holm([0.1, 1.5])
    assert holm([]) == []


def test_holm_leaves_the_garbage_collector_as_it_found_it() -> None:
    """holm freezes the existing objects around statsmodels' forced collection, then thaws them."""
    before = gc.get_freeze_count()
    holm([0.01, 0.04, 0.03])
    assert gc.get_freeze_count() == before
    with pytest.raises(ValueError, match="p_values"):
        holm([float("nan")])
    assert gc.get_freeze_count() == before


def test_bad_rows_are_rejected() -> None:
    row = ResponseRow(participant_id="a", video_id="v99", reported_touches=1, attention_passed=True)
    with pytest.raises(ValueError, match="unknown video"):
        analyze([row], MANIFEST)
    twice = _rows({"a": (1, 1, 1)})
    with pytest.raises(ValueError, match="twice"):
        analyze([*twice, twice[0]], MANIFEST)


def test_too_few_participants_skip_the_tests() -> None:
    result = analyze(_rows({"a": (1, 2, 3), "b": (2, 2, 2)}), MANIFEST)
    assert result.tests.friedman is None
    assert result.tests.n_complete == 2
    assert "at least" in (result.tests.note or "")


def test_outputs_are_written_with_the_exact_shape(tmp_path: Path) -> None:
    result = analyze(_study_rows(), MANIFEST)
    out = tmp_path / "out"
    written = write_outputs(result, out)
    assert sorted(p.name for p in out.iterdir()) == sorted([*written, OUTPUT_MARKER])  # no temp
    doc = json.loads((out / "analysis.json").read_text())
    assert set(doc) == {"conditions", "reductions", "tests", "excluded", "assessors"}
    assert set(doc["conditions"]) == {"fixed", "centering", "orientation"}
    assert set(doc["conditions"]["fixed"]) == {"n", "mean_error", "sd_error"}
    assert all(set(e) == {"participant_id", "reason"} for e in doc["excluded"])
    assert (out / "assessment_errors.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    html = (out / "report.html").read_text()
    assert "p08" in html and "outlier in orientation" in html
    assert '<html lang="en">' in html


def test_csv_round_trip_and_errors() -> None:
    rows = _study_rows()
    assert rows_from_csv(rows_to_csv(rows)) == rows
    assert (
        rows_to_csv(rows).splitlines()[0]
        == "participant_id,video_id,reported_touches,attention_passed"
    )
    with pytest.raises(ValueError, match="columns"):
        rows_from_csv("a,b\n")
    bad = "participant_id,video_id,reported_touches,attention_passed\np,v01,-3,true\n"
    with pytest.raises(ValueError, match="line 2"):
        rows_from_csv(bad)
    with pytest.raises(ValueError, match="attention_passed"):
        rows_from_csv(bad.replace("-3,true", "3,maybe"))


def test_hidden_by_text_words_and_sums_the_geoms() -> None:
    """The report names kinds of things, summed over their geoms, most first; unknown names stay."""
    counts = {
        "ring_torus": 3,
        "psm1_jaw_b": 1,
        "wire": 20,
        "psm1_shaft": 2,
        "ring_handle": 1,
        "outside the image": 4,
        "wall_front": 1,
    }
    assert hidden_by_text(counts) == (
        "the wire 20, outside the image 4, an instrument 3, the ring 3, the box 1, "
        "the ring's handle 1"
    )
    assert hidden_by_text({}) == "–"  # nothing hidden
    assert "not recorded" in hidden_by_text(None)  # a folder from before the column
