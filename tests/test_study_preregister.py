"""study preregister: the plan from the study's own files, its hash, and the deviations
``study analyze`` flags (a changed video, another outlier rule, too few assessors)."""

import json
from pathlib import Path

import pytest

from endocam.cli import main
from endocam.cli.study_plan import report_preregistration
from endocam.study.analysis import AnalysisConfig
from endocam.study.preregister import check, plan, plan_sha256
from study_helpers import make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

PLANNED_N = 40  # assessors of the (hand-written) power calculation
ANALYSED_N = 4  # assessors the (stand-in) analysis kept


def test_plan_hash_and_deviations(tmp_path: Path) -> None:
    study = make_study(tmp_path, stub_videos=True)
    config = AnalysisConfig()
    doc = plan(study, config)
    assert doc["analysis"]["analysed_videos"] == {
        "fixed": ["v03"],
        "centering": ["v06"],
        "orientation": ["v09"],
    }
    assert "centering_vs_orientation" in doc["analysis"]["tests"][0]
    registered = {"plan": doc, "plan_sha256": plan_sha256(doc), "sample_size": None}
    assert check(registered, study, config, ANALYSED_N)["follows"]
    changed = check(registered, study, AnalysisConfig(tukey_k=3.0), ANALYSED_N)
    assert not changed["follows"]
    assert [d.split(":")[0] for d in changed["deviations"]] == [
        "analysis.config.tukey_k",
        "exclusions",
    ]
    registered["plan"] = {**doc, "hypotheses": {"primary": "edited later"}}
    (edited,) = [d for d in check(registered, study, config, 3)["deviations"] if "sha" in d]
    assert edited.startswith("plan_sha256")


def test_cli_preregister_and_the_check_analyze_reports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    study = make_study(tmp_path, stub_videos=True)
    power = tmp_path / "power.json"
    power.write_text(json.dumps({"n_required": PLANNED_N, "n_recruit": 45}), encoding="utf-8")
    args = ["study", "preregister", "--study", str(study)]
    assert main([*args, "--power", str(power)]) == 0
    assert main(args) == 2  # frozen: not replaced without --force
    path = study / "preregistration.json"
    registered = json.loads(path.read_text("utf-8"))
    assert registered["sample_size"]["n_analysed"] == PLANNED_N
    assert "## Exclusions, in order" in (study / "preregistration.md").read_text("utf-8")
    # analyze reads it before any work: a foreign file is refused in one line, nothing written
    responses = tmp_path / "responses.csv"
    responses.write_text(
        "participant_id,video_id,reported_touches,attention_passed\np0,v01,2,true\n", "utf-8"
    )
    analyze = ["study", "analyze", "--manifest", str(study), "--responses", str(responses)]
    out = tmp_path / "analysis"
    assert main([*analyze, "--out", str(out), "--preregistration", str(power)]) == 2
    assert "is not a pre-registration" in capsys.readouterr().err and not out.exists()
    # after the analysis: the verdict (here the lines of a changed video and too few assessors)
    (study / "videos" / "v09.mp4").write_bytes(b"another video")
    out.mkdir()
    report_preregistration((path, registered), study, AnalysisConfig(), ANALYSED_N, out)
    printed = capsys.readouterr().out
    assert "2 deviation(s)" in printed and "deviation: files.videos/v09.mp4" in printed
    assert f"{ANALYSED_N} assessors analysed, {PLANNED_N} registered" in printed
    result = json.loads((out / "preregistration-check.json").read_text("utf-8"))
    assert result["follows"] is False and result["registered_sha256"] == registered["plan_sha256"]
