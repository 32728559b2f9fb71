"""What the observer reads frame by frame on a study's videos, against the simulator's clearance.

For every video of a study folder (the nine, and the extra seeds' kept with
``--keep-seed-videos``), decodes the left eye and reads the observer's per-frame gap
(``study.observer.observe_video``), rebuilds the ring's trajectory to get the true clearance at
each frame, and prints per condition:

- frames in true contact (clearance ≤ 0) and frames clearly apart (clearance ≥ 1 mm): the share
  the observer reads as nothing seen (NaN), as contact (gap ≤ 1 px) and as open (gap > 3 px);
- the touches it counts that match no true touch, by where they are (first 3 s, last 2.5 s,
  between) and the true clearance nearest them (median; share under 1.5 mm).

Usage (``MUJOCO_GL=egl``; ~12 min for 69 videos on 2 loaded workers)::

    .venv/bin/python examples/observer_frames.py --study out/study [--workers 2]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
from pathlib import Path

import numpy as np

from endocam.config import ExperimentConfig
from endocam.study.hypothesis import SEEDS_DIR, kept_seeds, load_records
from endocam.study.make import trajectory_config
from endocam.study.manifest import STUDY_CONDITIONS, load_manifest
from endocam.study.observer import (
    CONTACT_GAP_PX,
    OPEN_GAP_PX,
    count_touches,
    keys_for_study,
    observe_video,
)
from endocam.task.study_paths import STUDY_TRAJECTORIES, StudyTrajectory
from endocam.task.touches import clearances
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

APART_M = 1.0e-3  # m, "clearly apart": the study's legible pass
NEAR_M = 1.5e-3  # m, a false touch this close to the wire is a near pass
START_S, END_S = 3.0, 2.5  # s, the fly-in and the end of the path (near the post)
PAD_FRAMES = 8  # frames searched either side of a false touch for the nearest clearance


def _clearance(path: StudyTrajectory, seed: int, frames: int, fps: float) -> np.ndarray:
    """True clearance (m) at each frame of ``path`` drawn with ``seed``."""
    task = trajectory_config(ExperimentConfig(), path).task
    wire = Wire(task.wire)
    trajectory = make_trajectory(task, TrajectoryKind.NOISY, path.control_points, seed, wire)
    return clearances(trajectory.poses(np.arange(frames) / fps), wire, task.ring)[0]


def main() -> None:
    """Parse the arguments, read every video and print the two tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", type=Path, required=True, help="study folder")
    parser.add_argument("--workers", type=int, default=2, help="decoding processes")
    args = parser.parse_args()
    root: Path = args.study
    manifest = load_manifest(root)
    keys = keys_for_study(root)
    by_name = {t.name: t for t in STUDY_TRAJECTORIES}
    records = load_records(root / "observability.json")
    design = json.loads((root / "design.json").read_text("utf-8"))
    noise_seed = {t["name"]: int(t["noise_seed"]) for t in design["trajectories"]}
    jobs: dict[tuple[str, StudyTrajectory, int, tuple[tuple[float, float], ...]], Path] = {}
    for v in manifest.videos:
        events = tuple((r.t_start_s, r.t_end_s) for r in records if r.video_id == v.id)
        key = (v.condition.value, by_name[v.trajectory], noise_seed[v.trajectory], events)
        jobs[key] = root / v.file
    for seed, events, _ in kept_seeds(root):
        for c in STUDY_CONDITIONS:
            key = (c.value, by_name["t3-71-high"], seed, tuple(events))
            jobs[key] = root / SEEDS_DIR / str(seed) / f"{c.value}.mp4"
    frames: dict[str, np.ndarray] = {}
    false: dict[str, list[tuple[str, float]]] = {}
    with concurrent.futures.ProcessPoolExecutor(args.workers) as pool:
        futures = {pool.submit(observe_video, path, keys): key for key, path in jobs.items()}
        for fut in concurrent.futures.as_completed(futures):
            condition, path, seed, events = futures[fut]
            obs = fut.result()
            c = _clearance(path, seed, obs.gaps_px.size, obs.fps)
            g = obs.gaps_px
            for mask, name in ((c <= 0.0, "in contact"), (c >= APART_M, "apart ≥ 1 mm")):
                gm = g[mask]
                row = [
                    gm.size,
                    np.isnan(gm).sum(),
                    (gm <= CONTACT_GAP_PX).sum(),
                    (gm > OPEN_GAP_PX).sum(),
                ]
                key = f"{condition}|{name}"
                frames[key] = frames.get(key, np.zeros(4)) + np.array(row, dtype=float)
            slack = 1.0 / obs.fps
            for seen in count_touches(g, obs.fps):
                if any(seen.t_start <= b + slack and a <= seen.t_end + slack for a, b in events):
                    continue
                lo, hi = max(seen.frame_start - PAD_FRAMES, 0), seen.frame_end + PAD_FRAMES + 1
                duration = obs.gaps_px.size / obs.fps
                where = "start" if seen.t_start < START_S else "mid"
                where = "end" if seen.t_end > duration - END_S else where
                false.setdefault(condition, []).append((where, float(c[lo:hi].min())))
    print("| condition | frames | nothing seen | read as contact | read as open |")
    print("|---|---|---|---|---|")
    for key in sorted(frames):
        n, nan, contact, open_ = frames[key]
        condition, name = key.split("|")
        shares = " | ".join(f"{x / n:.0%}" for x in (nan, contact, open_))
        print(f"| {condition}, {name} | {n:.0f} | {shares} |")
    print()
    print(
        "| condition | false touches | first 3 s / mid / last 2.5 s "
        "| nearest clearance (median) | under 1.5 mm |"
    )
    print("|---|---|---|---|---|")
    for condition in sorted(false):
        rows = false[condition]
        where = [w for w, _ in rows]
        near = np.array([m for _, m in rows])
        split = " / ".join(str(where.count(w)) for w in ("start", "mid", "end"))
        print(
            f"| {condition} | {len(rows)} | {split} | {np.median(near) * 1e3:.2f} mm "
            f"| {np.mean(near < NEAR_M):.0%} |"
        )


if __name__ == "__main__":
    main()
