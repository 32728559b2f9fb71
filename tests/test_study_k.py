"""A study with k = 3, 4, 5 conditions through the app and the analysis (issue 28 item 1)."""

from __future__ import annotations

import json
import math
from collections import Counter
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy import stats

from endocam.study.analysis import AnalysisConfig, OutlierRule, analyze
from endocam.study.app import create_app
from endocam.study.db import StudyDB
from endocam.study.export import codebook_markdown, export_tables
from endocam.study.flow import attention_after_set
from endocam.study.manifest import load_manifest, parse_manifest
from endocam.study.report import BOXPLOT_PNG, SD_PNG, write_outputs
from endocam.study.responses import ResponseRow
from study_helpers import ATTENTION_ANSWER, k_conditions, make_study, manifest_dict

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

ADMIN = "k-admin"
KS = (3, 4, 5)
REL = 1e-12  # relative tolerance of float statistics (float64 arithmetic)
FAST = AnalysisConfig(bootstrap_resamples=200, outliers=OutlierRule.NONE)  # cheap intervals


def _start(client: TestClient, pid: str) -> None:
    r = TestClient(client.app).post("/api/session", json={"consent": True, "participant_id": pid})
    assert r.status_code == 201, r.text


@pytest.mark.parametrize("k", KS)
def test_a_participant_sees_every_condition_in_the_williams_order_assigned(
    tmp_path: Path, k: int
) -> None:
    study = make_study(
        tmp_path, conditions=k_conditions(k), stub_videos=True, shuffle_within_set=False
    )
    manifest = load_manifest(study)
    n_orders = len(manifest.orders)
    assert n_orders == (k if k % 2 == 0 else 2 * k)  # the Williams design the manifest holds
    db_path = tmp_path / "study.db"
    with TestClient(create_app(study, db_path, ADMIN)) as c:
        for i in range(n_orders - 1):  # every order but the last is taken once
            _start(c, f"p{i}")
        r = c.post("/api/session", json={"consent": True, "participant_id": "last"})
        assert r.status_code == 201
        shown: list[str] = []
        attention_at = None
        while (step := c.get("/api/next").json())["kind"] != "done":
            if step["kind"] == "attention":
                attention_at = len(shown)
                assert c.post("/api/attention", json={"answer": ATTENTION_ANSWER}).status_code
                continue
            assert step["n_sets"] == k
            shown.append(step["video_id"])
            body = {"video_id": step["video_id"], "reported_touches": 1}
            assert c.post("/api/answer", json=body).status_code == 201
        # the HTML page of a participant's first video names set 1 of k
        page = TestClient(c.app)
        assert page.post("/start", data={"consent": "yes"}, follow_redirects=False).is_redirect
        assert f"Set 1 of {k}" in page.get("/study").text
    orders = {p.participant_id: p.order_index for p in StudyDB(db_path).participants()}
    first = [*(f"p{i}" for i in range(n_orders - 1)), "last"]
    assert [orders[p] for p in first] == list(range(n_orders))  # round robin: one of each
    order = manifest.orders[orders["last"]]
    expected = [v.id for cond in order for v in manifest.videos_of(cond)]
    assert shown == expected  # every condition's videos, set by set in the assigned order
    assert attention_at == 3 * attention_after_set(k)
    # carry-over balance of the orders the app assigned to the first n_orders participants
    assigned = [manifest.orders[orders[p]] for p in first]
    follows = Counter(pair for o in assigned for pair in pairwise(o))
    assert len(follows) == k * (k - 1) and len(set(follows.values())) == 1
    mine = [
        r
        for r in export_tables(StudyDB(db_path), manifest)["responses"]
        if r.participant_id == "last"
    ]
    assert [r.condition for r in mine if r.position_in_set == 1] == list(order)
    assert {r.condition_order for r in mine} == {">".join(order)}


def test_the_codebook_names_no_fixed_set_of_conditions() -> None:
    text = codebook_markdown()
    assert "fixed, centering or orientation" not in text
    assert "manifest's `conditions`" in text


def _k_rows(k: int, n: int, seed: int) -> tuple[list[ResponseRow], np.ndarray]:
    """n assessors' counts of every video; the last condition has a smaller, tighter error.

    Returns the rows and the (n, k) errors on each condition's most difficult video.
    """
    rng = np.random.default_rng(seed)
    manifest = parse_manifest(json.dumps(manifest_dict(k_conditions(k))))
    rows, hardest = [], np.zeros((n, k))
    for p in range(n):
        for v in manifest.videos:
            c = manifest.conditions.index(v.condition)
            scale = 1.0 if c == k - 1 else 3.0
            error = int(rng.integers(0, 2 + int(scale * (1 + c % 2))))
            reported = v.true_touches + error
            if v.difficulty == 3:
                hardest[p, c] = error
            rows.append(
                ResponseRow(
                    participant_id=f"a{p:02d}",
                    video_id=v.id,
                    reported_touches=reported,
                    attention_passed=True,
                )
            )
    return rows, hardest


@pytest.mark.parametrize("k", KS)
def test_the_analysis_runs_over_k_conditions(tmp_path: Path, k: int) -> None:
    n = 14  # scipy's Wilcoxon with ties is a permutation test (2^n) up to n = 13: slow
    rows, hardest = _k_rows(k, n, seed=k)
    manifest = parse_manifest(json.dumps(manifest_dict(k_conditions(k))))
    result = analyze(rows, manifest, FAST)
    conds = list(manifest.conditions)
    fr = stats.friedmanchisquare(*hardest.T)
    assert result.tests.friedman is not None
    assert result.tests.friedman.statistic == pytest.approx(fr.statistic, rel=REL)
    assert result.tests.kendall_w == pytest.approx(fr.statistic / (n * (k - 1)), rel=REL)
    assert len(result.tests.wilcoxon) == math.comb(k, 2)
    p_raw = np.array([t.p_value for t in result.tests.wilcoxon.values()])
    p_holm = np.array([t.p_holm for t in result.tests.wilcoxon.values()])
    assert np.all(p_holm >= p_raw) and np.all(p_holm <= 1.0)
    smallest = int(np.argmin(p_raw))  # Holm multiplies the smallest p by the number of tests
    assert p_holm[smallest] == pytest.approx(min(1.0, len(p_raw) * p_raw[smallest]), rel=REL)
    for name, t in result.tests.wilcoxon.items():
        a, b = name.split("_vs_")
        assert t.rank_biserial_ci95 is not None and t.rank_biserial is not None
        lo, hi = t.rank_biserial_ci95
        assert -1.0 <= lo <= hi <= 1.0
        i, j = conds.index(a), conds.index(b)
        w = stats.wilcoxon(hardest[:, i], hardest[:, j])
        assert t.p_value == pytest.approx(w.pvalue, rel=REL)
    assert list(result.reductions) == [f"{conds[-1]}_vs_{c}" for c in reversed(conds[:-1])]
    assessors = result.assessors
    assert assessors is not None and assessors.n_assessors == n
    assert list(assessors.agreement) == ["all videos", *conds]
    assert list(assessors.sd_comparisons) == list(result.reductions)
    for c in conds:
        assert assessors.sd_across_assessors[c].value == pytest.approx(
            np.std(hardest[:, conds.index(c)], ddof=1), rel=REL
        )
    written = write_outputs(result, tmp_path / "out")
    assert {BOXPLOT_PNG, SD_PNG} <= set(written)
    html = written["report.html"].read_text()
    assert all(f">{c}<" in html for c in conds if c.startswith("extra"))
    assert "Krippendorff" in html and "Pitman" in html and "Kendall" in html
    doc = json.loads(written["analysis.json"].read_text())
    assert len(doc["assessors"]["agreement"]) == k + 1


def test_the_intervals_are_seeded() -> None:
    rows, _ = _k_rows(4, 14, seed=1)
    manifest = parse_manifest(json.dumps(manifest_dict(k_conditions(4))))
    one, two = analyze(rows, manifest, FAST), analyze(rows, manifest, FAST)
    assert one.model_dump() == two.model_dump()
    other = analyze(rows, manifest, FAST.model_copy(update={"bootstrap_seed": 1}))
    assert other.tests.kendall_w_ci95 != one.tests.kendall_w_ci95
