"""How close the camera comes to the wire (the controllers keep `controller.wire_clearance`).

Reads finished runs (what ``endocam run`` writes: ``scene.json`` with the wire's dense centre
line and radius, ``episode.csv`` with the camera's optical centre) and prints, per run, the
distance from the camera's optical centre to the wire's surface: minimum, 5th percentile and
the share of steps closer than 10 mm. A negative distance is a camera centre inside the wire.
It recomputes from the logged files what ``metrics.json["camera_wire_clearance_mm"]`` reports.

    .venv/bin/endocam run --no-video --policy endocam --arm free --trajectory noisy \\
        --control-points 71 --seed 1 --out /tmp/run
    .venv/bin/python examples/camera_wire_clearance.py /tmp/run
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from endocam.runner.outputs import NEAR_WIRE_M


def clearance_m(run: Path) -> np.ndarray:
    """(N,) distance from the camera's optical centre to the wire's surface per step, m."""
    scene = json.loads((run / "scene.json").read_text(encoding="utf-8"))
    wire = np.asarray(scene["wire"]["points"], dtype=float)
    with (run / "episode.csv").open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    cam = np.array([[float(r["cam_x"]), float(r["cam_y"]), float(r["cam_z"])] for r in rows])
    d, _ = cKDTree(wire).query(cam)
    return np.asarray(d, dtype=float) - float(scene["wire"]["wire_radius"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="folders written by endocam run")
    args = parser.parse_args()
    print("| run | min (mm) | p5 (mm) | steps closer than 10 mm |")
    print("|---|---|---|---|")
    for run in args.runs:
        d = clearance_m(run)
        near = 100.0 * float(np.mean(d < NEAR_WIRE_M))
        print(f"| {run} | {1e3 * d.min():.1f} | {1e3 * np.percentile(d, 5):.1f} | {near:.1f} % |")


if __name__ == "__main__":
    main()
