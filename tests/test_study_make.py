import json
import re
import shutil
from pathlib import Path
from typing import Any

import imageio_ffmpeg
import pytest
from markupsafe import escape

from endocam.cli import main
from endocam.config import load_config
from endocam.runner.experiments import ground_truth
from endocam.study.counterbalance import presentation_orders
from endocam.study.hypothesis import HYPOTHESIS_JSON, SEEDS_DIR, TRUTH_JSON
from endocam.study.make import (
    DESIGN_JSON,
    STUDY_TRAJECTORIES,
    ExtraSeeds,
    extra_seed_values,
    make_study,
    practice_seed,
    right_video,
    run_extra_seeds,
    seed_log,
    trajectory_config,
    trajectory_seeds,
    video_ids,
)
from endocam.study.manifest import DEFAULT_CONDITIONS, load_manifest
from endocam.study.observability import OBSERVABILITY_CSV, OBSERVABILITY_JSON, load_summary
from endocam.study.observer import OBSERVER_HTML, OBSERVER_JSON, ColourKeys
from endocam.study.report import kinds_text, share_text
from endocam.study.responses import ResponseRow, rows_to_csv
from endocam.study.tables import hypothesis_table
from endocam.study.visibility import ShareCI
from endocam.task.trajectory import TrajectoryKind

SEED = 7
CONDITIONS = DEFAULT_CONDITIONS  # the default study's: fixed, centering, endocam
WIDTH_PX, HEIGHT_PX, FPS, DURATION_S = 160, 120, 10.0, 1.5
N_FRAMES = int(DURATION_S * FPS) + 1  # frames per video, t = 0 .. duration
TINY = f"""
[task.trajectory]
duration = {DURATION_S}
[camera]
width = {WIDTH_PX}
height = {HEIGHT_PX}
[episode]
video_fps = {FPS}
"""

SHORTEST = f"""
[task.trajectory]
duration = {DURATION_S / 3}
[camera]
width = {WIDTH_PX // 2}
height = {HEIGHT_PX // 2}
[episode]
video_fps = {FPS}
"""  # the cheapest study that still makes: for checks of what is (not) written


@pytest.fixture(scope="module")
def config_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "tiny.toml"
    path.write_text(TINY, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def shortest_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "shortest.toml"
    path.write_text(SHORTEST, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def study(config_file: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("made") / "study"
    args = ["study", "make", "--out", str(out), "--config", str(config_file)]
    # one extra seed needs no pool (the pool is test_extra_seeds_in_the_process_pool_...'s)
    args += ["--seed", str(SEED), "--seeds", "1", "--keep-seed-videos", "--workers", "1"]
    assert main(args) == 0
    return out


def test_manifest_is_valid_with_nine_videos_and_six_orders(study: Path) -> None:
    manifest = load_manifest(study)  # also checks that every file exists
    assert len(manifest.videos) == 9
    assert manifest.orders == presentation_orders()
    assert manifest.conditions == CONDITIONS
    for condition in CONDITIONS:
        videos = manifest.videos_of(condition)
        assert [v.difficulty for v in videos] == [1, 2, 3]
        assert [v.trajectory for v in videos] == [t.name for t in STUDY_TRAJECTORIES]
    assert not list(study.parent.glob(".study.tmp-*"))  # the temporary folder was renamed
    doc = json.loads((study / "manifest.json").read_text())
    assert "touch" in doc["touch_definition"]  # what participants are told to count


def test_ids_do_not_reveal_the_condition(study: Path) -> None:
    manifest = load_manifest(study)
    for v in manifest.videos:
        assert re.fullmatch(r"[0-9a-f]{8}", v.id)
        assert v.file == f"videos/{v.id}.mp4"
    assert set(video_ids(SEED, 9)) == {v.id for v in manifest.videos}


def test_videos_decode_with_the_configured_size_and_rate(study: Path) -> None:
    for v in load_manifest(study).videos:
        reader = imageio_ffmpeg.read_frames(str(study / v.file))
        meta = next(reader)
        frames = sum(1 for _ in reader)
        assert meta["size"] == (WIDTH_PX, HEIGHT_PX)
        assert meta["fps"] == pytest.approx(FPS)
        assert frames == N_FRAMES


def test_true_touches_equal_the_simulator_counts(study: Path, config_file: Path) -> None:
    manifest = load_manifest(study)
    design = json.loads((study / DESIGN_JSON).read_text())
    seeds = trajectory_seeds(SEED)
    config = load_config(config_file)
    for traj, seed, entry in zip(STUDY_TRAJECTORIES, seeds, design["trajectories"], strict=True):
        assert entry["noise_seed"] == seed
        truth = ground_truth(
            trajectory_config(config, traj), TrajectoryKind.NOISY, traj.control_points, seed
        )
        for v in manifest.videos:
            if v.trajectory == traj.name:
                assert v.true_touches == truth.count
                # the share of time in contact: the events' total length over the trajectory
                spent = sum(e.t_end - e.t_start for e in truth.events)
                duration = truth.t[-1] - truth.t[0]
                assert v.contact_fraction == pytest.approx(spent / duration)
                assert entry["contact_fraction"] == pytest.approx(spent / duration)
                assert entry["videos"][v.condition] == v.id
                metrics = json.loads((study / "logs" / v.id / "metrics.json").read_text())
                assert (
                    metrics["episode"]["policy"] == v.condition == design["conditions"][v.condition]
                )
                assert metrics["touches"] == truth.count
    assert design["trajectories"][0]["angle_noise_deg"] == pytest.approx([5.0, 10.0])


def test_practice_video_is_the_easiest_path_with_its_own_seed_and_fixed_camera(
    study: Path, config_file: Path
) -> None:
    manifest = load_manifest(study)  # checks that the practice file exists
    assert manifest.practice is not None
    assert manifest.practice.file not in {v.file for v in manifest.videos}
    design = json.loads((study / DESIGN_JSON).read_text())
    easiest = min(STUDY_TRAJECTORIES, key=lambda t: t.difficulty)
    seed = design["practice"]["noise_seed"]
    assert seed == practice_seed(SEED)
    assert seed not in trajectory_seeds(SEED)  # never one of the nine videos
    truth = ground_truth(
        trajectory_config(load_config(config_file), easiest),
        TrajectoryKind.NOISY,
        easiest.control_points,
        seed,
    )
    assert manifest.practice.true_touches == truth.count
    reader = imageio_ffmpeg.read_frames(str(study / manifest.practice.file))
    assert next(reader)["size"] == (WIDTH_PX, HEIGHT_PX)
    assert sum(1 for _ in reader) == N_FRAMES
    metrics = json.loads((study / "logs" / "practice" / "metrics.json").read_text())
    assert metrics["episode"]["policy"] == "fixed"
    assert metrics["touches"] == truth.count


def _one_trajectory(monkeypatch: pytest.MonkeyPatch) -> None:
    """``study make`` (the command) makes the study of the easiest trajectory alone: 3 videos.

    For checks of what the command does (or does not) write that do not depend on the design.
    """
    from endocam.study import make

    real = make.make_study

    def easiest_only(*args: Any, **kwargs: Any) -> Any:
        return real(*args, trajectories=STUDY_TRAJECTORIES[:1], **kwargs)

    monkeypatch.setattr(make, "make_study", easiest_only)


def test_no_practice_flag_writes_no_practice_video(
    shortest_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "study"
    args = ["study", "make", "--out", str(out), "--config", str(shortest_file), "--no-practice"]
    _one_trajectory(monkeypatch)
    assert main(args) == 0
    assert len(load_manifest(out).videos) == len(CONDITIONS)  # the easiest trajectory's
    assert load_manifest(out).practice is None
    assert not (out / "videos" / "practice.mp4").exists()
    assert not (out / "logs" / "practice").exists()
    assert json.loads((out / DESIGN_JSON).read_text())["practice"] is None


def test_difficulty_design_uses_more_points_and_more_noise() -> None:
    by_level = {t.difficulty: t for t in STUDY_TRAJECTORIES}
    assert by_level[1].control_points == by_level[2].control_points < by_level[3].control_points
    assert by_level[1].angle_noise is not None and by_level[2].angle_noise is None


def test_observability_covers_every_touch(study: Path) -> None:
    manifest = load_manifest(study)
    summary = load_summary(study / OBSERVABILITY_JSON)
    doc = json.loads((study / OBSERVABILITY_JSON).read_text())
    assert list(summary.conditions) == list(CONDITIONS)
    for condition in CONDITIONS:
        expected = sum(v.true_touches for v in manifest.videos_of(condition))
        assert summary.conditions[condition].touches == expected
        rows = [t for t in doc["touches"] if t["condition"] == condition]
        assert len(rows) == expected
        assert {t["video_id"] for t in rows} <= {v.id for v in manifest.videos_of(condition)}
    csv_rows = (study / OBSERVABILITY_CSV).read_text().splitlines()
    assert len(csv_rows) == 1 + len(doc["touches"])
    # the old columns stay; the image-space ones (what the video shows) are added
    header = csv_rows[0].split(",")
    for column in ("visible", "gap_px_per_mm", "gap_before_px", "gap_min_px", "closes_visibly"):
        assert column in header


def test_observer_json_has_the_issue_schema(study: Path) -> None:
    manifest = load_manifest(study)
    doc = json.loads((study / OBSERVER_JSON).read_text())
    assert set(doc) == {"conditions", "videos"}
    assert set(doc["conditions"]) == set(CONDITIONS)
    for row in doc["conditions"].values():
        assert set(row) == {"videos", "mean_abs_error", "sd_abs_error"} and row["videos"] == 3
    assert [v["id"] for v in doc["videos"]] == [v.id for v in manifest.videos]
    for v, m in zip(doc["videos"], manifest.videos, strict=True):
        assert set(v) == {"id", "condition", "true_touches", "counted_touches", "events"}
        assert v["true_touches"] == m.true_touches and v["counted_touches"] == len(v["events"])
    errors = [
        abs(v["counted_touches"] - v["true_touches"])
        for v in doc["videos"]
        if v["condition"] == "fixed"
    ]
    assert doc["conditions"]["fixed"]["mean_abs_error"] == pytest.approx(sum(errors) / 3)
    assert "<img" in (study / OBSERVER_HTML).read_text() or not any(
        v["events"] for v in doc["videos"]
    )
    hypothesis = json.loads((study / HYPOTHESIS_JSON).read_text())
    assert hypothesis["trajectory"] == STUDY_TRAJECTORIES[-1].name
    assert list(hypothesis["study"]) == list(CONDITIONS)
    assert hypothesis["extra_seeds"]["n"] == 1  # --seeds 1: one more seed, three conditions
    assert len(hypothesis["extra_seeds"]["videos"]) == 3


def test_study_observe_rewrites_the_observer_files(study: Path, tmp_path: Path) -> None:
    before = json.loads((study / OBSERVER_JSON).read_text())
    (study / OBSERVER_JSON).unlink()
    assert main(["study", "observe", "--study", str(study)]) == 0
    assert json.loads((study / OBSERVER_JSON).read_text()) == before  # same video, same count
    assert main(["study", "observe", "--study", str(tmp_path)]) == 2  # no manifest: one line


def test_analyze_report_shows_observability(study: Path, tmp_path: Path) -> None:
    manifest = load_manifest(study)
    rows = [
        ResponseRow(
            participant_id=f"p{k}",
            video_id=v.id,
            reported_touches=min(99, v.true_touches + k % 3),
            attention_passed=True,
        )
        for k in range(6)
        for v in manifest.videos
    ]
    responses = tmp_path / "responses.csv"
    responses.write_text(rows_to_csv(rows), encoding="utf-8")
    out = tmp_path / "results"
    args = ["study", "analyze", "--responses", str(responses), "--manifest"]
    assert main([*args, str(study / "manifest.json"), "--out", str(out)]) == 0
    html = (out / "report.html").read_text()
    assert "Objective touch observability" in html
    # the report's rows carry what hides each condition's gaps, as observability.json counts them
    summary = json.loads((study / OBSERVABILITY_JSON).read_text())["conditions"]
    for c in CONDITIONS:  # the closing gap leads: resolved, then in sight from either eye
        cells = [share_text(ShareCI.model_validate(summary[c][k])) for k in RESOLVED_FIRST]
        assert f"<td>{cells[0]}</td><td>{cells[1]}</td>" in html
        hidden = escape(kinds_text(summary[c]["hidden_from_both"]))
        assert f'<td style="text-align: left">{hidden}</td></tr>' in html
    out2 = tmp_path / "results2"
    assert main([*args, str(study), "--out", str(out2), "--outliers", "none"]) == 0
    assert "Objective touch observability" in (out2 / "report.html").read_text()


RESOLVED_FIRST = ("resolved", "gap_in_sight_either")  # the report's first two closing-gap columns
STEREO_COLUMNS = (
    "gap_in_sight_right",
    "gap_hidden_by_right",
    "gap_in_sight_either",
    "gap_px",
    "resolved",
)


def test_seeds_and_ids_are_deterministic_and_distinct() -> None:
    assert trajectory_seeds(SEED) == trajectory_seeds(SEED)
    assert trajectory_seeds(SEED) != trajectory_seeds(SEED + 1)
    ids = video_ids(SEED, 9)
    assert ids == video_ids(SEED, 9) and len(set(ids)) == 9
    with pytest.raises(ValueError, match="seed"):
        video_ids(-1, 9)


@pytest.mark.parametrize(
    ("setup", "needle"),
    [
        ("file_parent", "cannot create output folder"),
        ("out_is_file", "is not a folder"),
        ("bad_toml", "malformed"),
        ("odd_width", "must be even"),
        ("unknown_key", "camera.colour"),
        ("negative_seed", "--seed"),
        ("negative_seeds", "--seeds"),
        ("zero_workers", "--workers"),
    ],
)
def test_bad_input_is_one_line_exit_2(
    setup: str, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    config = tmp_path / "c.toml"
    config.write_text(TINY, encoding="utf-8")
    extra: list[str] = []
    if setup == "file_parent":
        (tmp_path / "blocker").write_text("x")
        out = tmp_path / "blocker" / "out"
    elif setup == "out_is_file":
        out.write_text("x")
    elif setup == "bad_toml":
        config.write_text("[camera\nwidth = 3", encoding="utf-8")
    elif setup == "odd_width":
        config.write_text("[camera]\nwidth = 161\n", encoding="utf-8")
    elif setup == "unknown_key":
        config.write_text("[camera]\ncolour = 1\n", encoding="utf-8")
    elif setup == "negative_seeds":
        extra = ["--seeds", "-1"]
    elif setup == "zero_workers":
        extra = ["--seeds", "1", "--workers", "0"]
    else:
        extra = ["--seed", "-3"]
    code = main(["study", "make", "--out", str(out), "--config", str(config), *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert needle in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").is_dir()


def test_extra_seeds_in_the_process_pool_equal_a_serial_run(
    shortest_file: Path, tmp_path: Path
) -> None:
    config = load_config(shortest_file)
    hardest = max(STUDY_TRAJECTORIES, key=lambda t: t.difficulty)
    keys = ColourKeys.from_scene(config.task.scene)
    conditions = CONDITIONS[:2]  # one seed of two conditions on two workers: the pool's order
    extra = ExtraSeeds(hardest, SEED, 1, conditions)
    serial, skipped = run_extra_seeds(config, extra, keys, tmp_path, workers=1)
    pooled, _ = run_extra_seeds(config, extra, keys, tmp_path, workers=2)
    assert skipped == []
    assert [(r["seed"], r["condition"]) for r in serial] == [
        (s, c) for s in extra_seed_values(SEED, 1) for c in conditions
    ]
    assert json.dumps(pooled) == json.dumps(serial)  # NaN gaps compare equal as text
    assert not list(tmp_path.iterdir())  # the seeds' videos are deleted


def _copy(study: Path, tmp_path: Path) -> Path:
    """A copy of the module's study folder that a test may change."""
    copy = tmp_path / "study"
    shutil.copytree(study, copy)
    return copy


def _frames(path: Path) -> int:
    reader = imageio_ffmpeg.read_frames(str(path))
    next(reader)
    return sum(1 for _ in reader)


def test_kept_seed_videos_hold_the_three_conditions_and_the_true_touches(
    study: Path, config_file: Path
) -> None:
    (s,) = extra_seed_values(SEED, 1)
    folder = study / SEEDS_DIR / str(s)
    assert sorted(p.name for p in (study / SEEDS_DIR).iterdir()) == [str(s)]
    for c in CONDITIONS:
        assert _frames(folder / f"{c}.mp4") == N_FRAMES
        assert _frames(folder / right_video(c)) == N_FRAMES  # the ideal observer's stereo input
        header = (folder / seed_log(c)).read_text().splitlines()[0].split(",")
        assert {"t", "clearance", "ring_x", "cam_qw"} <= set(header)
    truth = json.loads((folder / TRUTH_JSON).read_text())
    hardest = max(STUDY_TRAJECTORIES, key=lambda t: t.difficulty)
    cfg = trajectory_config(load_config(config_file), hardest)
    events = ground_truth(cfg, TrajectoryKind.NOISY, hardest.control_points, s).events
    assert truth["seed"] == s and truth["fps"] == FPS
    assert truth["true_events"] == [[e.t_start, e.t_end] for e in events]


def test_study_observe_recounts_the_kept_seeds_and_the_gap_columns(
    study: Path, tmp_path: Path
) -> None:
    copy = _copy(study, tmp_path)
    hypothesis = json.loads((copy / HYPOTHESIS_JSON).read_text())
    observability = json.loads((copy / OBSERVABILITY_JSON).read_text())
    spoiled = json.loads(json.dumps(hypothesis))
    for row in spoiled["extra_seeds"]["videos"]:
        row["counted_touches"] = 99
    (copy / HYPOTHESIS_JSON).write_text(json.dumps(spoiled))
    spoiled_obs = json.loads(json.dumps(observability))
    for touch in spoiled_obs["touches"]:
        touch["gap_before_px"], touch["closes_visibly"] = 1234.0, True
    (copy / OBSERVABILITY_JSON).write_text(json.dumps(spoiled_obs))
    assert main(["study", "observe", "--study", str(copy), "--workers", "1"]) == 0
    # the same videos and observer give back exactly what study make wrote
    assert json.loads((copy / HYPOTHESIS_JSON).read_text()) == hypothesis
    assert json.loads((copy / OBSERVABILITY_JSON).read_text()) == observability
    assert (copy / OBSERVABILITY_CSV).read_text() == (study / OBSERVABILITY_CSV).read_text()
    assert not list(copy.glob(".*.tmp-*"))  # every file replaced atomically


def test_study_observe_without_kept_videos_keeps_and_marks_the_earlier_seed_rows(
    study: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = _copy(study, tmp_path)
    shutil.rmtree(copy / SEEDS_DIR)
    before = json.loads((copy / HYPOTHESIS_JSON).read_text())
    assert main(["study", "observe", "--study", str(copy), "--workers", "1"]) == 0
    after = json.loads((copy / HYPOTHESIS_JSON).read_text())
    assert after["extra_seeds"]["videos"] == before["extra_seeds"]["videos"]
    assert after["extra_seeds"]["recounted"] is False and before["extra_seeds"]["recounted"]
    assert "not counted again" in capsys.readouterr().out


def test_study_observe_names_a_kept_seed_without_its_video(
    study: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = _copy(study, tmp_path)
    (s,) = extra_seed_values(SEED, 1)
    (copy / SEEDS_DIR / str(s) / "endocam.mp4").unlink()
    before = (copy / OBSERVER_JSON).read_text()
    assert main(["study", "observe", "--study", str(copy)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing video(s) endocam" in err[0]
    assert (copy / OBSERVER_JSON).read_text() == before  # nothing rewritten


def _children(pid: int) -> set[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


# `endocam study make ARGS` (the command's `main`) making the easiest trajectory's videos alone
# (its noise seed is the full study's first: each trajectory's seed is the k-th draw)
EASIEST_ONLY_CLI = """
import sys
from endocam.study import make
real = make.make_study
make.make_study = lambda *a, **k: real(*a, trajectories=make.STUDY_TRAJECTORIES[:1], **k)
from endocam.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_during_the_extra_seeds_leaves_no_folder_and_no_worker(
    shortest_file: Path, tmp_path: Path
) -> None:
    """A job scheduler stops `study make` half-way: nothing half-written, no orphan process.

    The study is the shortest one of the easiest trajectory alone (the command's own `main`):
    what is checked happens after its videos, while the extra seeds run in the pool.
    """
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "study"
    cmd = [sys.executable, "-c", EASIEST_ONLY_CLI, "study", "make", "--out", str(out)]
    cmd += ["--config", str(shortest_file), "--seeds", "6", "--workers", "2", "--no-practice"]
    cmd += ["--conditions", "fixed,centering"]  # the two cheapest: what is checked is the pool
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300.0  # s: the study's own videos come first
    while not list(tmp_path.glob(f".{out.name}.tmp-*/{SEEDS_DIR}/*")):
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        assert time.monotonic() < deadline, "the extra seeds never started"
        time.sleep(0.05)
    workers = _children(proc.pid)
    assert workers  # the pool's processes (and multiprocessing's resource tracker)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60.0) == 130
    assert proc.stderr is not None and "interrupted" in proc.stderr.read().decode()
    assert not out.exists()
    assert not list(tmp_path.glob(f".{out.name}*"))  # the temporary folder is gone
    time.sleep(1.0)  # s: the resource tracker leaves once its pipe closes
    alive = [p for p in workers if Path(f"/proc/{p}").exists()]
    for p in alive:  # a zombie is gone already; anything else outlived the command
        state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
        assert state == "Z", f"process {p} outlived the command"


def test_gap_in_sight_and_what_hides_it_are_recorded_for_every_touch_and_seed(study: Path) -> None:
    records = json.loads((study / OBSERVABILITY_JSON).read_text())["touches"]
    assert records and all(isinstance(r["gap_in_sight"], bool) for r in records)
    (s,) = extra_seed_values(SEED, 1)
    truth = json.loads((study / SEEDS_DIR / str(s) / TRUTH_JSON).read_text())
    assert set(truth["gap_in_sight"]) == set(CONDITIONS)
    for flags in truth["gap_in_sight"].values():
        assert len(flags) == len(truth["true_events"])
    # what hides a gap is named exactly when the gap is not in sight
    assert all((r["gap_hidden_by"] == "") == r["gap_in_sight"] for r in records)
    for c, hiders in truth["gap_hidden_by"].items():
        assert [h is None for h in hiders] == truth["gap_in_sight"][c]
    hypothesis = json.loads((study / HYPOTHESIS_JSON).read_text())
    for c in CONDITIONS:
        rows = [r for r in records if r["video_id"] == hypothesis["study"][c]["video"]]
        share = hypothesis["study"][c]["gap_in_sight_share"]
        if rows:
            assert share == pytest.approx(sum(r["gap_in_sight"] for r in rows) / len(rows))
        else:
            assert share is None
        counts = hypothesis["study"][c]["gap_hidden_by"]
        assert sum(counts.values()) == sum(not r["gap_in_sight"] for r in rows)
        seed_counts = hypothesis["extra_seeds"]["conditions"][c]["gap_hidden_by"]
        assert sum(seed_counts.values()) == truth["gap_in_sight"][c].count(False)
        # the closing gap from both eyes: resolved only where an eye sees it
        gaps = truth["closing_gap"][c]
        assert len(gaps) == len(truth["true_events"])
        assert all(
            g["in_sight_either"] == (g["in_sight_left"] or g["in_sight_right"]) for g in gaps
        )
        assert all(g["in_sight_either"] for g in gaps if g["resolved"])
        resolved = hypothesis["extra_seeds"]["conditions"][c]["resolved"]
        if gaps:
            assert resolved["share"] == pytest.approx(sum(g["resolved"] for g in gaps) / len(gaps))
            assert resolved["ci95"] is None  # one seed: nothing to resample


def test_study_observe_replays_the_episodes_for_a_missing_gap_in_sight(
    study: Path, tmp_path: Path
) -> None:
    """A folder made before the columns existed gets them from replayed episodes, the same values.

    Round-3 records lack both ``gap_in_sight`` and ``gap_hidden_by``; round-5 records and kept
    seeds have the first only: both kinds are replayed. Two of the videos lack them (both kinds
    of records; two conditions, two trajectories) and so does the kept seed (its three
    conditions): a video's replay does not depend on which video it is.
    """
    copy = _copy(study, tmp_path)
    observability = json.loads((copy / OBSERVABILITY_JSON).read_text())
    (s,) = extra_seed_values(SEED, 1)
    truth_path = copy / SEEDS_DIR / str(s) / TRUTH_JSON
    truth = json.loads(truth_path.read_text())
    old = json.loads(json.dumps(observability))
    first = old["touches"][0]
    second = next(
        r
        for r in old["touches"]
        if r["condition"] != first["condition"] and r["trajectory"] != first["trajectory"]
    )
    stripped = [
        r for r in old["touches"] if r["video_id"] in (first["video_id"], second["video_id"])
    ]
    assert len(stripped) > 2
    for k, r in enumerate(stripped):
        for column in STEREO_COLUMNS:  # round 8 and before
            del r[column]
        if k % 2:  # round 3
            del r["gap_in_sight"], r["gap_hidden_by"]
        else:  # round 5
            del r["gap_hidden_by"]
    (copy / OBSERVABILITY_JSON).write_text(json.dumps(old))
    older = {k: v for k, v in truth.items() if k not in ("gap_hidden_by", "closing_gap")}
    truth_path.write_text(json.dumps({**older, "assessor_note": "kept by the replay"}))
    assert main(["study", "observe", "--study", str(copy), "--workers", "1"]) == 0
    assert json.loads((copy / OBSERVABILITY_JSON).read_text()) == observability
    assert json.loads(truth_path.read_text()) == {**truth, "assessor_note": "kept by the replay"}
    assert json.loads((copy / HYPOTHESIS_JSON).read_text()) == json.loads(
        (study / HYPOTHESIS_JSON).read_text()
    )


def test_study_observe_names_a_malformed_observability_file(
    study: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = _copy(study, tmp_path)
    (copy / OBSERVABILITY_JSON).write_text('{"touches": [{"video_id": 1}]}')
    assert main(["study", "observe", "--study", str(copy), "--workers", "1"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "endocam:" in line]
    assert len(errors) == 1 and OBSERVABILITY_JSON in errors[0]  # (the progress bar aside)


FOUR = ("fixed", "centering", "orientation", "endocam")  # registered policies, k = 4


def test_a_study_of_four_conditions_is_made_observed_and_tabulated(
    shortest_file: Path, tmp_path: Path
) -> None:
    out = tmp_path / "study"
    config = load_config(shortest_file)
    kwargs: dict[str, Any] = {"seed": SEED, "practice": False, "workers": 1}
    make_study(config, out, trajectories=STUDY_TRAJECTORIES[:1], conditions=FOUR, **kwargs)
    manifest = load_manifest(out)
    assert manifest.conditions == FOUR and len(manifest.videos) == len(FOUR)
    assert manifest.orders == presentation_orders(FOUR) and len(manifest.orders) == len(FOUR)
    design = json.loads((out / DESIGN_JSON).read_text())
    assert design["conditions"] == {c: c for c in FOUR}
    assert list(design["trajectories"][0]["videos"]) == list(FOUR)
    assert list(load_summary(out / OBSERVABILITY_JSON).conditions) == list(FOUR)
    hypothesis = json.loads((out / HYPOTHESIS_JSON).read_text())
    assert list(hypothesis["study"]) == list(FOUR)
    assert set(json.loads((out / OBSERVER_JSON).read_text())["conditions"]) == set(FOUR)
    table = hypothesis_table(hypothesis)
    assert all(f"| {c} |" in table for c in FOUR)
    assert table.index("resolved") < table.index("counted")  # the closing gap leads


@pytest.mark.parametrize(
    ("conditions", "needle"),
    [
        ("fixed,warp", "unknown condition 'warp'; choose policies from: fixed, centering"),
        ("fixed,endocam,fixed", "repeated: fixed"),
        ("endocam", "at least 2 conditions"),
    ],
)
def test_bad_conditions_are_one_line_exit_2(
    conditions: str, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main(["study", "make", "--out", str(out), "--conditions", conditions]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--conditions" in err[0] and needle in err[0]
    assert not out.exists()
