"""The stereo ring-pose estimator alone, on rendered 640x480 pairs over the paper's six paths.

Episodes of the ``endocam`` tracker on each of the paper's paths (3 ideal, the 3 study paths),
carried by the free camera and by the PSM, give the camera and ring poses; ``--frames`` pairs,
evenly spread over the twelve episodes, are rendered (both eyes, the arm and the instruments
drawn) and estimated with and without the image model (``ImageModelConfig()`` defaults; blur
from the ring's image velocity in the left eye; highlights on the ring's rim; seeded per frame).

Reported per condition: centre error median/p95/max (mm), normal error median/p95/max (deg, up
to sign) over the frames where the ring is at least half visible in both eyes (``HALF``: its
core circle's ``RIM_POINTS`` points inside the image and not hidden from the eye by anything
but the ring, by MuJoCo ray casts), the share of those frames with an estimate, the estimates
off by more than 20 mm or 45° over *all* frames, the reasons for missing estimates, and the
estimator's time per pair (median; wall and thread CPU time, OpenCV on one thread).

The sampling, the errors and the report are ``endocam.runner.perception_experiment``'s (also
``endocam experiment perception``); this bench adds ``--stress`` and prints the JSON.

Run (about 2-3 min on one core):
  MUJOCO_GL=egl OMP_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/perception_estimator.py \
      [--frames 300] [--json out.json]
Issue 26 targets (image model on): centre median <= 1.0 mm, p95 <= 3 mm; normal median <= 4 deg,
p95 <= 10 deg; >= 95 % estimates; none off by > 20 mm or 45 deg; <= 10 ms per pair.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np
from tqdm import tqdm

from endocam.config import ExperimentConfig
from endocam.perception.image_model import ImageModelConfig
from endocam.runner.experiments import paper_paths
from endocam.runner.perception_experiment import (
    CARRIERS,
    CONDITIONS,
    DEFAULT_FRAMES,
    sample_pairs,
    summarise,
    tracker_episodes,
)

os.environ.setdefault("MUJOCO_GL", "egl")
# --stress: one effect strengthened at a time (a fixed blur replaces the ring's own), name ->
# (config, blur velocity px/s along the image's x or None for the ring's own)
_BASE = ImageModelConfig()
STRESS = {
    "noise x3": (ImageModelConfig(read_noise_dn=6.0, shot_noise_dn=12.0), None),
    "gain 0.5-1.5": (ImageModelConfig(gain_range=(0.5, 1.5)), None),
    "10 highlights on the rim": (
        ImageModelConfig(highlight_rate=10.0, highlight_radius_px=(2.0, 6.0)),
        None,
    ),
    "blur 6 px": (_BASE, 6.0 / _BASE.exposure),
    "blur 12 px": (_BASE, 12.0 / _BASE.exposure),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--frames", type=int, default=DEFAULT_FRAMES, help="stereo pairs over all episodes"
    )
    parser.add_argument("--json", default=None, help="write the report here too")
    parser.add_argument(
        "--stress", action="store_true", help="also each STRESS variant of the image model"
    )
    args = parser.parse_args(argv)
    runs_n = len(paper_paths()) * len(CARRIERS)
    if args.frames < runs_n:
        print(f"error: --frames must be at least {runs_n} (one per episode)", file=sys.stderr)
        return 2
    config = ExperimentConfig()
    with tqdm(total=runs_n, desc="episodes", unit="episode", leave=False) as bar:
        runs = tracker_episodes(config, bar.update)
    per = math.ceil(args.frames / runs_n)
    stress = STRESS if args.stress else {}
    with tqdm(total=per * runs_n, desc="pairs", unit="pair", leave=False) as bar:
        rows = sample_pairs(config, runs, per, stress, bar.update)
    report = {key: summarise(rows, key) for key in (*CONDITIONS, *stress)}
    blur = np.array([r["blur_px"] for r in rows])
    report["image_model"]["ring_blur_px_left"] = {
        "median": float(np.median(blur)),
        "p95": float(np.percentile(blur, 95)),
    }
    print(json.dumps(report, indent=2))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"report": report, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
