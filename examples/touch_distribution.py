"""Distribution of ring-wire touches on noisy trajectories (docs/world.md, "Trajectories").

For each number of control points, runs the exact touch detection on the noisy trajectories of
seeds 0..S-1 and prints a Markdown table of the median, min and max over the seeds of the touch
count, the contact fraction (time in contact / duration, %) and the minimum clearance (mm).

Usage::

    .venv/bin/python examples/touch_distribution.py [--seeds 20] [--points 36 71]
"""

from __future__ import annotations

import argparse

import numpy as np

from endocam.task.config import TaskConfig
from endocam.task.touch_stats import touch_stats


def _cell(values: np.ndarray, fmt: str) -> str:
    return f"{np.median(values):{fmt}} ({values.min():{fmt}} – {values.max():{fmt}})"


def main() -> None:
    """Parse the arguments and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="seeds 0..S-1 (default 20)")
    parser.add_argument(
        "--points", type=int, nargs="+", default=[36, 71], help="control points (default 36 71)"
    )
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error("--seeds must be ≥ 1")
    cfg = TaskConfig()
    print(f"Noisy trajectories, seeds 0-{args.seeds - 1}: median (min – max)\n")
    print("| control points | touches | contact (% of time) | min clearance (mm) |")
    print("|---:|---:|---:|---:|")
    for n in args.points:
        st = touch_stats(cfg, n, range(args.seeds))
        print(
            f"| {n} | {_cell(st.count.astype(float), '.1f')} "
            f"| {_cell(100.0 * st.contact_fraction, '.1f')} "
            f"| {_cell(1e3 * st.min_clearance, '.2f')} |"
        )


if __name__ == "__main__":
    main()
