"""``endocam study ideal-observer``: run :mod:`endocam.study.ideal_observer` on a study folder.

Material: the study's kept extra seeds (``study make --seeds N --keep-seed-videos``), each
``seeds/<seed>/`` with, per condition, the left-eye video ``<c>.mp4``, the right-eye video
``<c>.right.mp4``, the per-step log ``<c>.episode.csv`` (the ring and camera poses, the clearance)
and ``truth.json`` (the true touches, the frame rate). The camera (``K_left``, the eyes' poses in
the camera frame) and the ring's radii come from the study's ``logs/*/scene.json``. The study's
three presentation trajectories are not used: they differ in difficulty and have no right eye.

Written: ``ideal_observer.json`` (per condition × input: AUC and d′ with their CIs, frames,
seeds, counted and true touches, per seed the AUC, threshold and counts), and beside it the same
table as ``ideal_observer.md``, ``ideal_observer.csv`` and a page, ``ideal_observer.html``
(:mod:`endocam.study.ideal_observer_report`).

Crop cache: decoding every frame of every kept video is most of a first run's time, so each
video's crops (uint8 HSV, ``(F, CROP_PX² · 3)``) are kept in
``<study>/ideal_observer_cache/<seed folder>/<condition>.<eye>.npz`` with a key
(:func:`cache_key`): the SHA-256 of the video's bytes, the crop centres and half-sides (which
follow from the log, the camera and the ring) and ``CROP_PX``/``CACHE_VERSION``. A file whose
key differs, or that cannot be read, is recomputed and overwritten; deleting the folder is
always safe.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import io
import json
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from endocam import __version__
from endocam.geometry import R_from_quat_wxyz
from endocam.runner.log_schema import quat_names, xyz_names
from endocam.runner.outputs import write_atomic
from endocam.study import ideal_observer as io_
from endocam.study.hypothesis import SEEDS_DIR, TRUTH_JSON
from endocam.study.make import LOGS_DIR, right_video, seed_log
from endocam.study.manifest import load_manifest

IDEAL_OBSERVER_JSON = "ideal_observer.json"
INPUTS = ("mono", "stereo")  # mono: the left eye (the participants' video); stereo: both eyes
TARGET_HALF_WIDTH = 0.05  # the AUC CI half-width the study aims at (issue 27)
LOG_COLUMNS = ("t", *xyz_names("ring"), *xyz_names("cam"), *quat_names("cam"), "clearance")
CACHE_DIR = "ideal_observer_cache"  # the crop cache, inside the study folder (safe to delete)
CACHE_VERSION = 1  # raise it when crop_hsv's output changes for the same inputs
PROGRESS_EVERY = 30  # frames between progress-bar updates


@dataclass(frozen=True)
class StudyCamera:
    """The study's camera and ring, from a ``scene.json``.

    ``K`` : (3, 3) each eye's intrinsics, px; ``T_cam_left``/``T_cam_right`` : (4, 4) the eyes in
    the camera (optical) frame, m; ``outer_radius`` : the ring's R + r, m.
    """

    K: NDArray[np.float64]
    T_cam_left: NDArray[np.float64]
    T_cam_right: NDArray[np.float64]
    outer_radius: float


@dataclass(frozen=True)
class StudyInputs:
    """A checked study folder: its conditions, kept seed folders, camera.

    ``cache``: whether the crops are cached in ``<folder>/CACHE_DIR``.
    """

    folder: Path
    conditions: tuple[str, ...]
    seed_dirs: tuple[Path, ...]
    camera: StudyCamera
    cache: bool = True


def check_study(folder: Path, inputs: Sequence[str] = INPUTS, cache: bool = True) -> StudyInputs:
    """Check that ``folder`` holds what the ideal observer needs (before anything is computed).

    Raises
    ------
    ValueError
        One line naming the problem: no folder, no manifest, no scene.json, fewer than
        ``MIN_SEEDS`` kept seeds, a kept seed without a video, log or truth.json.
    """
    if not folder.is_dir():
        raise ValueError(f"no such study folder: {folder}")
    manifest = load_manifest(folder, check_files=False)
    scenes = sorted((folder / LOGS_DIR).glob("*/scene.json"))
    if not scenes:
        raise ValueError(f"{folder}: no {LOGS_DIR}/*/scene.json (not a study made by endocam)")
    camera = read_camera(scenes[0])
    root = folder / SEEDS_DIR
    dirs = tuple(sorted((p for p in root.iterdir() if p.is_dir()), key=lambda p: p.name))
    dirs = dirs if root.is_dir() else ()
    if len(dirs) < io_.MIN_SEEDS:
        raise ValueError(
            f"{folder}: {len(dirs)} kept seed(s) in {SEEDS_DIR}/, the ideal observer needs at "
            f"least {io_.MIN_SEEDS} for grouped cross-validation (study make --seeds N "
            "--keep-seed-videos)"
        )
    for d in dirs:
        need = [TRUTH_JSON]
        for c in manifest.conditions:
            need += [f"{c}.mp4", seed_log(c)] + ([right_video(c)] if "stereo" in inputs else [])
        missing = [n for n in need if not (d / n).is_file()]
        if missing:
            raise ValueError(f"{d}: missing {', '.join(missing)} (made before the ideal observer?)")
    return StudyInputs(folder, manifest.conditions, dirs, camera, cache)


def read_camera(scene_json: Path) -> StudyCamera:
    """The camera and ring radii of a ``scene.json`` (``ValueError`` if malformed)."""
    try:
        doc = json.loads(scene_json.read_text("utf-8"))
        cam, ring = doc["camera"], doc["ring"]
        return StudyCamera(
            np.asarray(cam["K_left"], dtype=float).reshape(3, 3),
            np.asarray(cam["T_cam_left"], dtype=float).reshape(4, 4),
            np.asarray(cam["T_cam_right"], dtype=float).reshape(4, 4),
            float(ring["major_radius"]) + float(ring["minor_radius"]),
        )
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{scene_json}: malformed scene.json: {exc}") from None


def read_log(path: Path) -> dict[str, NDArray[np.float64]]:
    """The columns ``LOG_COLUMNS`` of an ``episode.csv``, float (NaN for an empty cell)."""
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None or not set(LOG_COLUMNS) <= set(header):
            raise ValueError(f"{path}: not an episode.csv (needs {', '.join(LOG_COLUMNS)})")
        idx = [header.index(c) for c in LOG_COLUMNS]
        rows = [[float(r[i]) if r[i] else np.nan for i in idx] for r in reader]
    data = np.asarray(rows, dtype=float).reshape(-1, len(LOG_COLUMNS))
    return {c: data[:, k] for k, c in enumerate(LOG_COLUMNS)}


def read_truth(folder: Path) -> tuple[int, int, float]:
    """A kept seed's noise seed, true touches and frame rate (frames/s) from ``truth.json``."""
    try:
        doc = json.loads((folder / TRUTH_JSON).read_text("utf-8"))
        return int(doc["seed"]), len(doc["true_events"]), float(doc["fps"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{folder}: no valid {TRUTH_JSON}: {exc}") from None


def eye_poses(log: dict[str, NDArray[np.float64]], T_cam_eye: NDArray[np.float64]) -> Any:
    """(N, 4, 4) an eye's pose in world per log step, m (camera pose ∘ ``T_cam_eye``)."""
    n = len(log["t"])
    T = np.tile(np.eye(4), (n, 1, 1))
    q = np.stack([log[c] for c in quat_names("cam")], axis=1)
    ok = np.isfinite(q).all(axis=1)
    T[:, :3, :3] = np.nan
    T[ok, :3, :3] = R_from_quat_wxyz(q[ok])
    T[:, :3, 3] = np.stack([log[c] for c in xyz_names("cam")], axis=1)
    return T @ T_cam_eye


def video_crops(
    path: Path,
    uv: NDArray[np.float64],
    half: NDArray[np.float64],
    progress: Callable[[int], object],
) -> NDArray[np.uint8]:
    """Decode ``path`` and crop frame j around ``uv[j]`` (``half[j]``): (F, CROP_PX² · 3) HSV.

    Every frame is decoded (the touch count reads every frame's score; H.264 decodes in order
    anyway). The frames beyond ``len(uv)`` are dropped; a video shorter than ``uv`` is an error.
    """
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24")
    try:
        meta = next(reader)
        width, height = meta["size"]
        out = np.zeros((len(uv), io_.CROP_PX * io_.CROP_PX * 3), dtype=np.uint8)
        n = 0
        for buf in reader:
            if n == len(uv):
                break
            frame = np.frombuffer(buf, dtype=np.uint8).reshape(height, width, 3)
            out[n] = io_.crop_hsv(frame, uv[n], float(half[n]), io_.CROP_PX)
            n += 1
            if n % PROGRESS_EVERY == 0:
                progress(PROGRESS_EVERY)
        progress(n % PROGRESS_EVERY)
    finally:
        reader.close()
    if n < len(uv):
        raise ValueError(f"{path}: {n} frames, the log needs {len(uv)}")
    return out


def cache_key(video: Path, uv: NDArray[np.float64], half: NDArray[np.float64]) -> str:
    """What a cached crop file must match (SHA-256, hex).

    It hashes the video's bytes, the crop centres and half-sides (from the log, the camera and
    the ring), ``CROP_PX`` and ``CACHE_VERSION``.
    """
    h = hashlib.sha256(f"v{CACHE_VERSION}|{io_.CROP_PX}|".encode())
    with open(video, "rb") as fh:
        for block in iter(functools.partial(fh.read, 1 << 20), b""):
            h.update(block)
    h.update(np.ascontiguousarray(uv, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(half, dtype=np.float64).tobytes())
    return h.hexdigest()


def read_cache(path: Path, key: str, shape: tuple[int, int]) -> NDArray[np.uint8] | None:
    """The crops in ``path`` if it is readable and holds ``key`` and ``shape``; else None."""
    try:
        with np.load(path) as z:
            crops = np.asarray(z["crops"])
            ok = str(z["key"]) == key and crops.shape == shape and crops.dtype == np.uint8
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):
        return None
    return crops if ok else None


def write_cache(path: Path, key: str, crops: NDArray[np.uint8]) -> None:
    """Save ``crops`` with ``key`` to ``path`` (.npz, compressed), atomically."""

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, key=np.str_(key), crops=crops)

    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, save)


def cached_crops(
    video: Path,
    uv: NDArray[np.float64],
    half: NDArray[np.float64],
    cache_file: Path | None,
    progress: Callable[[int], object],
) -> tuple[NDArray[np.uint8], bool]:
    """:func:`video_crops`, read from ``cache_file`` when its key matches (:func:`cache_key`).

    The rule: a cache file is used only if it holds the same key; otherwise the video is decoded
    and the file (re)written (if it cannot be written, the crops are still returned).
    ``cache_file`` None: no cache. Returns the crops and whether they
    came from the cache.
    """
    if cache_file is None:
        return video_crops(video, uv, half, progress), False
    key = cache_key(video, uv, half)
    crops = read_cache(cache_file, key, (len(uv), io_.CROP_PX * io_.CROP_PX * 3))
    if crops is not None:
        progress(len(uv))
        return crops, True
    crops = video_crops(video, uv, half, progress)
    try:
        write_cache(cache_file, key, crops)
    except OSError:  # a read-only study folder (with --out elsewhere): work without the cache
        pass
    return crops, False


@dataclass(frozen=True)
class SeedFrames:
    """One seed and condition: per frame the label and each eye's HSV crops (uint8).

    ``labels`` : (F,) int8; ``left``/``right`` : (F, CROP_PX² · 3) uint8 (:func:`crop_hsv`),
    ``right`` None for mono; ``cached`` : how many of its videos came from the crop cache.
    """

    seed: int
    labels: NDArray[np.int8]
    left: NDArray[np.uint8]
    right: NDArray[np.uint8] | None
    true_touches: int
    cached: int = 0


def seed_frames(
    study: StudyInputs,
    folder: Path,
    condition: str,
    stereo: bool,
    progress: Callable[[int], object],
) -> SeedFrames:
    """Labels and crops of one kept seed's videos of ``condition`` (the right eye if ``stereo``).

    Crops are cached in ``<study>/CACHE_DIR/<seed folder>/<condition>.<eye>.npz`` unless
    ``study.cache`` is False (:func:`cached_crops` says when a cache file is used).
    """
    seed, touches, fps = read_truth(folder)
    log = read_log(folder / seed_log(condition))
    n_frames = int(np.floor(log["t"][-1] * fps + 1e-9)) + 1
    t_frames = np.arange(n_frames) / fps
    steps = io_.nearest_steps(t_frames, log["t"])
    labels = io_.frame_labels(t_frames, log["t"], log["clearance"])
    p_ring = np.stack([log[c] for c in xyz_names("ring")], axis=1)[steps]
    cam = study.camera
    crops, cached = [], 0
    for eye, T_cam_eye, name in (
        ("left", cam.T_cam_left, f"{condition}.mp4"),
        ("right", cam.T_cam_right, right_video(condition)),
    ):
        if eye == "right" and not stereo:
            break
        T_world_eye = eye_poses(log, T_cam_eye)[steps]
        uv, half = io_.project_ring(cam.K, T_world_eye, p_ring, cam.outer_radius)
        cache = study.folder / CACHE_DIR / folder.name / f"{condition}.{eye}.npz"
        eye_crops, hit = cached_crops(
            folder / name, uv, half, cache if study.cache else None, progress
        )
        crops.append(eye_crops)
        cached += hit
    return SeedFrames(seed, labels, crops[0], crops[1] if stereo else None, touches, cached)


def frames_per_video(study: StudyInputs) -> int:
    """Frames of one kept video (from the first seed's log and truth.json), for progress bars."""
    _, _, fps = read_truth(study.seed_dirs[0])
    log = read_log(study.seed_dirs[0] / seed_log(study.conditions[0]))
    return int(np.floor(log["t"][-1] * fps + 1e-9)) + 1


def datasets(frames: Sequence[SeedFrames], inputs: Sequence[str]) -> dict[str, io_.Dataset]:
    """Per input, the :class:`~endocam.study.ideal_observer.Dataset` of a condition's seeds."""
    labels = np.concatenate([f.labels for f in frames])
    seeds = np.concatenate([np.full(len(f.labels), f.seed, dtype=np.int64) for f in frames])
    truth = {f.seed: f.true_touches for f in frames}
    out = {}
    for name in inputs:
        if name == "mono":
            X = np.concatenate([f.left for f in frames])
        else:
            X = np.concatenate(
                [np.hstack([f.left, f.right]) for f in frames if f.right is not None]
            )
        out[name] = io_.Dataset(io_.hsv_features(X), labels, seeds, truth)
    return out


def seed_auc(data: io_.Dataset, scores: NDArray[np.float64], seed: int) -> float | None:
    """The AUC of one seed's labelled frames (None if they hold one class only)."""
    keep = (data.seeds == seed) & (data.labels != io_.BETWEEN)
    y = data.labels[keep] == io_.CONTACT
    return io_.auc_score(y, scores[keep]) if y.any() and not y.all() else None


def table_row(
    condition: str, name: str, data: io_.Dataset, cv: io_.CrossValidation, est: io_.AucEstimate
) -> dict[str, Any]:
    """One row of the table: AUC and d′ with CIs, frames, seeds, touch counts, per seed."""
    seeds = sorted(data.true_touches)
    return {
        "condition": condition,
        "input": name,
        "auc": est.auc,
        "auc_ci": [est.low, est.high],
        "auc_ci_half_width": est.half_width,
        "d_prime": float(io_.d_prime(est.auc)),
        "d_prime_ci": [float(io_.d_prime(est.low)), float(io_.d_prime(est.high))],
        "n_frames": int((data.labels != io_.BETWEEN).sum()),
        "n_contact_frames": int((data.labels == io_.CONTACT).sum()),
        "n_excluded_frames": int((data.labels == io_.BETWEEN).sum()),
        "n_seeds": len(seeds),
        "n_boot": est.n_boot,
        "counted_touches": sum(cv.counted.values()),
        "true_touches": sum(data.true_touches.values()),
        "mean_abs_count_error": float(
            np.mean([abs(cv.counted[s] - data.true_touches[s]) for s in seeds])
        ),
        "seeds_for_target": io_.seeds_needed(est.half_width, len(seeds), TARGET_HALF_WIDTH),
        "per_seed": [
            {
                "seed": s,
                "auc": seed_auc(data, cv.scores, s),
                "threshold": cv.thresholds[s],
                "counted_touches": cv.counted[s],
                "true_touches": data.true_touches[s],
            }
            for s in seeds
        ],
    }


def evaluate(
    condition: str,
    name: str,
    data: io_.Dataset,
    progress: Callable[[int], object] | None = None,
    seconds: dict[str, float] | None = None,
) -> tuple[dict[str, Any], io_.AucEstimate]:
    """One row of the table (cross-validation, AUC and d′ with CIs, touch counts), its AUC.

    ``progress`` is called with 1 per fold; ``seconds["fit"]``/``["bootstrap"]`` (if given) are
    increased by the wall time of the two stages.
    """
    clock = {} if seconds is None else seconds
    t0 = time.perf_counter()
    cv = io_.cross_validate(data, progress=progress)
    t1 = time.perf_counter()
    est = io_.bootstrap_auc(data.labels, cv.scores, data.seeds, n_boot=io_.N_BOOT)
    t2 = time.perf_counter()
    clock["fit"] = clock.get("fit", 0.0) + t1 - t0
    clock["bootstrap"] = clock.get("bootstrap", 0.0) + t2 - t1
    return table_row(condition, name, data, cv, est), est


@dataclass(frozen=True)
class Measurement:
    """What :func:`measure` found.

    The table's rows; their AUC estimates per (condition, input); the wall time per stage (s:
    ``decode`` (decode + crop, or read the cache), ``fit``, ``bootstrap``); how many of the
    ``videos`` read came from the crop cache (``cached``).
    """

    rows: list[dict[str, Any]]
    estimates: dict[tuple[str, str], io_.AucEstimate]
    seconds: dict[str, float]
    videos: int
    cached: int


def measure(
    study: StudyInputs,
    inputs: Sequence[str],
    decoded: Callable[[int], object],
    folded: Callable[[int], object],
) -> Measurement:
    """Every condition × input of a checked study, one condition's crops in memory at a time.

    ``decoded`` is called with the frames cropped (or read from the cache), ``folded`` with 1 per
    cross-validation fold (``len(conditions) · len(inputs) · len(seed_dirs)`` in all).
    """
    stereo = "stereo" in inputs
    rows: list[dict[str, Any]] = []
    estimates: dict[tuple[str, str], io_.AucEstimate] = {}
    seconds = {"decode": 0.0, "fit": 0.0, "bootstrap": 0.0}
    cached = 0
    for c in study.conditions:
        t0 = time.perf_counter()
        frames = [seed_frames(study, d, c, stereo, decoded) for d in study.seed_dirs]
        seconds["decode"] += time.perf_counter() - t0
        cached += sum(f.cached for f in frames)
        for name, data in datasets(frames, inputs).items():
            row, estimates[(c, name)] = evaluate(c, name, data, folded, seconds)
            rows.append(row)
    videos = len(study.conditions) * len(study.seed_dirs) * (2 if stereo else 1)
    return Measurement(rows, estimates, seconds, videos, cached)


def comparisons(estimates: dict[tuple[str, str], io_.AucEstimate]) -> dict[str, Any]:
    """Per input, the condition with the highest AUC and its paired AUC differences to the rest.

    ``estimates`` : per (condition, input). The conditions share their seeds and the bootstrap
    its generator seed, so the resamples pair up
    (:func:`~endocam.study.ideal_observer.paired_difference`).
    """
    out: dict[str, Any] = {}
    for name in dict.fromkeys(i for _, i in estimates):
        mine = {c: e for (c, i), e in estimates.items() if i == name}
        best = max(mine, key=lambda c: mine[c].auc)
        diffs = []
        for c, e in mine.items():
            if c != best:
                d, lo, hi = io_.paired_difference(mine[best], e)
                diffs.append({"other": c, "auc_difference": d, "ci": [lo, hi]})
        out[name] = {"condition": best, "versus": diffs}
    return out


def document(
    study: StudyInputs,
    rows: Sequence[dict[str, Any]],
    estimates: dict[tuple[str, str], io_.AucEstimate],
) -> dict[str, Any]:
    """``ideal_observer.json``: the method's constants, the rows, the most informative condition."""
    best = comparisons(estimates)
    return {
        "study": str(study.folder),
        "labels": {"contact": "clearance <= 0", "apart_mm": io_.APART_M * 1e3},
        "crop_px": io_.CROP_PX,
        "features": "crop around the projected ring centre, HSV pixels in [0, 1] per eye",
        "model": f"HistGradientBoostingClassifier(max_iter={io_.HGB_ITER}, "
        f"max_bins={io_.HGB_BINS}), training apart "
        f"frames capped at {io_.APART_PER_CONTACT:g} per contact frame",
        "cv": "leave one seed out; thresholds from inner grouped folds of the training seeds",
        "d_prime": "sqrt(2) * Phi^-1(AUC)",
        "ci": f"seed-level bootstrap, {io_.N_BOOT} resamples, percentile {io_.CI_LEVEL:.0%}",
        "target_half_width": TARGET_HALF_WIDTH,
        "most_informative": best,
        "rows": list(rows),
        "endocam_version": __version__,
    }


CSV_FIELDS = (
    "condition",
    "input",
    "auc",
    "auc_low",
    "auc_high",
    "d_prime",
    "d_prime_low",
    "d_prime_high",
    "n_frames",
    "n_seeds",
    "counted_touches",
    "true_touches",
)


def flat(row: dict[str, Any]) -> dict[str, Any]:
    """A row with its intervals split into the ``CSV_FIELDS`` columns."""
    return row | {
        "auc_low": row["auc_ci"][0],
        "auc_high": row["auc_ci"][1],
        "d_prime_low": row["d_prime_ci"][0],
        "d_prime_high": row["d_prime_ci"][1],
    }


def table_csv(rows: Sequence[dict[str, Any]]) -> str:
    """``ideal_observer.csv``: one line per condition × input (``CSV_FIELDS``)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, CSV_FIELDS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(flat(r) for r in rows)
    return buf.getvalue()


def table_md(doc: dict[str, Any]) -> str:
    """``ideal_observer.md``: the table and which condition carries the most information."""
    lines = [
        "| condition | input | AUC [95 % CI] | ± | d′ [95 % CI] | frames | seeds "
        "| counted / true | mean abs. count error per seed |",
        "|---|---|---|---:|---|---:|---:|---:|---:|",
    ]
    for r in doc["rows"]:
        lo, hi = r["auc_ci"]
        dlo, dhi = r["d_prime_ci"]
        lines.append(
            f"| {r['condition']} | {r['input']} | {r['auc']:.3f} [{lo:.3f}, {hi:.3f}] | "
            f"{r['auc_ci_half_width']:.3f} | {r['d_prime']:.2f} [{dlo:.2f}, {dhi:.2f}] | "
            f"{r['n_frames']} | {r['n_seeds']} | {r['counted_touches']} / {r['true_touches']} | "
            f"{r['mean_abs_count_error']:.1f} |"
        )
    lines.append("")
    for name, best in doc["most_informative"].items():
        versus = "; ".join(
            f"{v['other']} {v['auc_difference']:+.3f} [{v['ci'][0]:+.3f}, {v['ci'][1]:+.3f}]"
            for v in best["versus"]
        )
        lines.append(
            f"Most information about contact ({name}): {best['condition']}; its AUC minus the "
            f"others' (paired seed bootstrap, 95 % CI): {versus}."
        )
    return "\n".join(lines) + "\n"
