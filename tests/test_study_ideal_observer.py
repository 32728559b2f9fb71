"""The learned ideal observer (issue 27): seed split, training-only threshold, AUC/d′, CLI."""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Iterator
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from scipy.stats import norm
from threadpoolctl import threadpool_limits

from endocam.cli import main
from endocam.study import ideal_observer as io_
from endocam.study import ideal_observer_study as ios
from endocam.study.make import right_video, seed_log
from study_helpers import CONDITIONS, make_study

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

ATOL = 1e-12  # dimensionless (AUC, d′, probabilities): float round-off
ATOL_PX = 1e-9  # px
W_PX, H_PX, FPS, N_FRAMES = 64, 48, 10.0, 60  # the tiny kept seeds' videos
FOCAL_PX = 40.0  # px, the tiny camera's focal length
RING_DEPTH_M = 0.05  # m, the tiny ring straight ahead of the camera
OUTER_RADIUS_M = 6e-3  # m, R + r of the tiny ring


@pytest.fixture(autouse=True)
def cheap_model(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Few boosting iterations on one thread: tiny data, and no OpenMP spin beside xdist."""
    monkeypatch.setattr(io_, "HGB_ITER", 10)
    with threadpool_limits(limits=1):
        yield


def synthetic(n_seeds: int, n_frames: int, rng: np.random.Generator) -> io_.Dataset:
    """Two Gaussian classes in 6 features, alternating runs of contact and apart frames."""
    labels = np.tile(np.repeat([io_.APART, io_.CONTACT, io_.BETWEEN], n_frames // 3), n_seeds)
    X = rng.normal(size=(len(labels), 6)).astype(np.float32)
    X[labels == io_.CONTACT, 0] += 2.0
    seeds = np.repeat(np.arange(n_seeds) * 7 + 3, 3 * (n_frames // 3))
    return io_.Dataset(X, labels.astype(np.int8), seeds, {int(s): 1 for s in np.unique(seeds)})


def test_seed_folds_keep_every_seed_on_one_side() -> None:
    seeds = np.random.default_rng(0).choice([11, 5, 42, 7], size=200)
    folds = io_.seed_folds(seeds)
    assert len(folds) == 4
    tested = []
    for train, test in folds:
        assert not set(seeds[train]) & set(seeds[test])  # no seed in both
        assert len(set(seeds[test])) == 1
        assert len(train) + len(test) == len(seeds)
        tested.append(int(seeds[test[0]]))
    assert sorted(tested) == [5, 7, 11, 42]


def test_cross_validation_thresholds_never_see_the_test_seed() -> None:
    data = synthetic(4, 30, np.random.default_rng(1))
    held: list[tuple[set[int], int]] = []

    def spy(d: io_.Dataset, train: np.ndarray) -> float:
        held.append((set(d.seeds[train].tolist()), len(train)))
        return 0.5

    cv = io_.cross_validate(data, spy)
    for (train_seeds, n_train), (seed, _) in zip(held, sorted(cv.thresholds.items()), strict=True):
        assert seed not in train_seeds
        assert n_train == int((data.seeds != seed).sum())


def test_fold_threshold_ignores_the_test_fold() -> None:
    rng = np.random.default_rng(2)
    data = synthetic(4, 30, rng)
    train, test = io_.seed_folds(data.seeds)[0]
    before = io_.fold_threshold(data, train)
    X = data.features.copy()
    X[test] = rng.normal(scale=50.0, size=X[test].shape)  # the test seed's frames and scores change
    perturbed = io_.Dataset(X, data.labels, data.seeds, data.true_touches)
    assert io_.fold_threshold(perturbed, train) == before
    s0 = io_.fit_scores(data.features, data.labels, train, test)
    s1 = io_.fit_scores(X, data.labels, train, test)
    assert not np.allclose(s0, s1)
    # and the threshold does move when the training seeds' frames change
    X2 = data.features.copy()
    X2[train[: len(train) // 2], 0] += 5.0
    moved = io_.fold_threshold(io_.Dataset(X2, data.labels, data.seeds, data.true_touches), train)
    assert moved != before


def test_auc_and_d_prime_separable_and_random() -> None:
    rng = np.random.default_rng(3)
    seeds = np.repeat(np.arange(8), 50)
    labels = np.tile(np.repeat([io_.CONTACT, io_.APART], 25), 8).astype(np.int8)
    separable = np.where(labels == io_.CONTACT, 0.9, 0.1) + rng.uniform(-0.05, 0.05, len(labels))
    sep = est = io_.bootstrap_auc(labels, separable, seeds, n_boot=200)
    assert est.auc == pytest.approx(1.0, abs=ATOL)
    assert est.low == pytest.approx(1.0, abs=ATOL)
    assert io_.d_prime(est.auc) == pytest.approx(math.sqrt(2) * norm.ppf(1 - io_.AUC_CLIP))
    random = rng.uniform(size=len(labels))
    est = io_.bootstrap_auc(labels, random, seeds, n_boot=200)
    assert est.low < 0.5 < est.high
    assert 0.0 < est.half_width < 0.15
    again = io_.bootstrap_auc(labels, random, seeds, n_boot=200)  # seeded: repeatable
    assert (again.low, again.high) == (est.low, est.high)
    assert io_.paired_difference(est, again) == (0.0, 0.0, 0.0)
    diff, low, high = io_.paired_difference(sep, est)
    assert diff == pytest.approx(sep.auc - est.auc, abs=ATOL) and 0.0 < low < diff < high
    assert io_.d_prime(0.5) == pytest.approx(0.0, abs=ATOL)
    assert io_.d_prime(norm.cdf(1 / math.sqrt(2))) == pytest.approx(1.0, abs=1e-9)
    from sklearn.metrics import roc_auc_score

    ties = np.round(random, 1)  # ties count one half, as in sklearn
    y = labels == io_.CONTACT
    assert io_.auc_score(y, ties) == pytest.approx(roc_auc_score(y, ties), abs=ATOL)
    with pytest.raises(ValueError, match="both classes"):
        io_.bootstrap_auc(np.ones(10, dtype=np.int8), random[:10], seeds[:10])


def test_labels_counts_and_projection() -> None:
    t_log = np.arange(0.0, 1.0, 0.01)
    clearance = np.where(t_log < 0.3, -1e-4, np.where(t_log < 0.5, 2e-4, 1e-3))
    labels = io_.frame_labels(np.array([0.0, 0.288, 0.4, 0.6]), t_log, clearance)
    assert labels.tolist() == [io_.CONTACT, io_.CONTACT, io_.BETWEEN, io_.APART]
    on = np.zeros(60, dtype=bool)
    on[5:8] = on[10:12] = True  # one touch (a gap shorter than RELEASE_FRAMES)
    on[30] = True  # one frame: flicker
    on[40:45] = True
    assert io_.count_touches(on) == 2
    assert io_.choose_threshold([np.where(on, 0.9, 0.1)], [2]) > 0.1
    K = np.array([[FOCAL_PX, 0, 32.0], [0, FOCAL_PX, 24.0], [0, 0, 1]])
    T = np.tile(np.eye(4), (2, 1, 1))
    p = np.array([[0.0, 0.0, RING_DEPTH_M], [0.0, 0.0, -RING_DEPTH_M]])
    uv, half = io_.project_ring(K, T, p, OUTER_RADIUS_M)
    assert uv[0] == pytest.approx([32.0, 24.0], abs=ATOL_PX)
    assert half[0] == pytest.approx(io_.CROP_MARGIN * FOCAL_PX * OUTER_RADIUS_M / RING_DEPTH_M)
    assert np.isnan(uv[1]).all()
    frame = np.zeros((H_PX, W_PX, 3), dtype=np.uint8)
    assert io_.crop_features(frame, uv[1], half[1]).shape == (io_.CROP_PX**2 * 3,)


def write_video(path: Path, shade: np.ndarray) -> None:
    """A tiny H.264 video, frame j a grey of ``shade[j]``."""
    writer = imageio_ffmpeg.write_frames(
        str(path), (W_PX, H_PX), fps=FPS, macro_block_size=16, ffmpeg_log_level="error"
    )
    writer.send(None)
    for s in shade:
        writer.send(np.full((H_PX, W_PX, 3), int(s), dtype=np.uint8))
    writer.close()


def kept_study(root: Path, n_seeds: int, videos: bool = True) -> Path:
    """The tiny study plus ``n_seeds`` kept seeds: videos (both eyes), logs, truth.json."""
    study = make_study(root, with_videos=False)
    K = [[FOCAL_PX, 0, W_PX / 2], [0, FOCAL_PX, H_PX / 2], [0, 0, 1]]
    eye = np.eye(4).tolist()
    scene = {
        "camera": {"K_left": K, "T_cam_left": eye, "T_cam_right": eye},
        "ring": {"major_radius": 5e-3, "minor_radius": 1e-3},
    }
    (study / "logs" / "v01").mkdir(parents=True)
    (study / "logs" / "v01" / "scene.json").write_text(json.dumps(scene), "utf-8")
    t = np.arange(0.0, (N_FRAMES - 1) / FPS + 1e-9, 0.05)
    contact = (t % 2.0) < 0.5  # touches apart by more than the count's RELEASE_FRAMES
    clearance = np.where(contact, -1e-4, 1e-3)
    header = "t,ring_x,ring_y,ring_z,cam_x,cam_y,cam_z,cam_qw,cam_qx,cam_qy,cam_qz,clearance"
    rows = [f"{a},0,0,{RING_DEPTH_M},0,0,0,1,0,0,0,{c}" for a, c in zip(t, clearance, strict=True)]
    shade = np.where(io_.frame_labels(np.arange(N_FRAMES) / FPS, t, clearance) == 1, 200, 40)
    video = root / "tiny.mp4"
    write_video(video, shade)  # once: every kept video is a copy (an encoder start is slow)
    for k in range(n_seeds):
        folder = study / "seeds" / str(100 + k)
        folder.mkdir(parents=True)
        events = [[a, a + 0.5] for a in np.arange(0.0, t[-1], 2.0)]
        truth = {"seed": 100 + k, "fps": FPS, "true_events": events}
        (folder / "truth.json").write_text(json.dumps(truth), "utf-8")
        for c in CONDITIONS:
            (folder / seed_log(c)).write_text("\n".join([header, *rows]) + "\n", "utf-8")
            if videos:
                shutil.copyfile(video, folder / f"{c}.mp4")
                shutil.copyfile(video, folder / right_video(c))
    return study


def test_cli_measures_a_tiny_study(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(io_, "N_BOOT", 20)  # cheap: the statistics have their own tests
    monkeypatch.setattr(io_, "CROP_PX", 4)
    study = kept_study(tmp_path, 3)
    assert main(["study", "ideal-observer", "--study", str(study)]) == 0
    doc = json.loads((study / "ideal_observer.json").read_text("utf-8"))
    assert [(r["condition"], r["input"]) for r in doc["rows"]] == [
        (c, i) for c in CONDITIONS for i in ("mono", "stereo")
    ]
    for r in doc["rows"]:
        assert r["auc"] == pytest.approx(1.0, abs=ATOL)  # bright frames are the contact frames
        assert r["n_seeds"] == 3 and r["true_touches"] == 3 * 3
        assert r["counted_touches"] == r["true_touches"]  # a clean signal counts right
    assert (study / "ideal_observer.md").read_text("utf-8").count("| fixed |") == 2
    assert (study / "ideal_observer.csv").read_text("utf-8").startswith("condition,input,auc,")
    page = (study / "ideal_observer.html").read_text("utf-8")
    assert page.count("<tr class='best'>") == 2 and "data:image/png;base64," in page
    cached = sorted(p.name for p in (study / ios.CACHE_DIR / "100").iterdir())
    assert cached == sorted(f"{c}.{eye}.npz" for c in CONDITIONS for eye in ("left", "right"))


def test_crop_cache_is_used_only_while_its_key_matches(tmp_path: Path) -> None:
    study = kept_study(tmp_path, 3)
    video = study / "seeds" / "100" / f"{CONDITIONS[0]}.mp4"
    uv = np.tile([W_PX / 2, H_PX / 2], (N_FRAMES, 1))
    half = np.full(N_FRAMES, 5.0)  # px
    cache = tmp_path / "cache" / "v.npz"
    frames: list[int] = []
    first, hit = ios.cached_crops(video, uv, half, cache, frames.append)
    assert not hit and cache.is_file() and sum(frames) == N_FRAMES
    again, hit = ios.cached_crops(video, uv, half, cache, frames.append)
    assert hit and np.array_equal(again, first) and sum(frames) == 2 * N_FRAMES
    moved, hit = ios.cached_crops(video, uv + 3.0, half, cache, frames.append)  # other centres
    assert not hit
    write_video(video, np.full(N_FRAMES, 90))  # other pixels, same name and length
    grey, hit = ios.cached_crops(video, uv + 3.0, half, cache, frames.append)
    assert not hit and not np.array_equal(grey, moved)
    cache.write_bytes(b"not an npz")
    _, hit = ios.cached_crops(video, uv + 3.0, half, cache, frames.append)
    assert not hit and ios.cached_crops(video, uv + 3.0, half, cache, frames.append)[1]
    blocked = tmp_path / "file"
    blocked.write_text("", "utf-8")  # a file where the cache's folder would be: cannot write
    crops, hit = ios.cached_crops(video, uv + 3.0, half, blocked / "v.npz", frames.append)
    assert not hit and np.array_equal(crops, grey)
    none, hit = ios.cached_crops(video, uv, half, None, frames.append)  # no cache
    assert not hit and none.dtype == np.uint8
    checked = ios.check_study(study, ("mono",), cache=False)  # --no-cache writes nothing
    got = ios.seed_frames(checked, checked.seed_dirs[0], CONDITIONS[0], False, frames.append)
    assert got.cached == 0 and got.left.shape == (N_FRAMES, io_.CROP_PX**2 * 3)
    assert not (study / ios.CACHE_DIR).exists()
    hsv = np.array([[180, 255, 0, 90, 0, 255]], dtype=np.uint8)
    assert io_.hsv_features(hsv).tolist() == [[1.0, 1.0, 0.0, 0.5, 0.0, 1.0]]


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("none", "no such study folder"),
        ("two", "needs at least 3"),
        ("no-videos", "missing fixed.mp4"),
        ("threads", "--threads must be at least 1"),
    ],
)
def test_cli_bad_study_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], setup: str, message: str
) -> None:
    if setup == "none":
        study = tmp_path / "nope"
    else:
        study = kept_study(tmp_path, 2 if setup == "two" else 3, videos=False)
    extra = ["--threads", "0"] if setup == "threads" else []
    assert main(["study", "ideal-observer", "--study", str(study), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (study / "ideal_observer.json").exists()
