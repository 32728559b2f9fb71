"""Two ``visible_view.py --touches-csv`` files of one policy compared paired, touch by touch.

The touches of a seed's path are the same ground-truth touches in both runs (the path does not
depend on the camera), in the same order, so the k-th row of a (seed, path) in one file is the
k-th in the other. Printed: each run's share resolved, the touches the second run won (resolved
there, not in the first) and lost, and the difference of the shares with a **seed-level**
bootstrap 95 % interval (percentile, 4 000 resamples, numpy generator seeded with 0; the seeds
resampled with replacement, as the study's own intervals: the touches of one episode share one
camera path). The variant tables of docs/study.md are made with it::

    .venv/bin/python bench/visible_paired.py base.csv variant.csv
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict

import numpy as np

RESAMPLES = 4000  # count: bootstrap resamples
CI = (2.5, 97.5)  # percent: the 95 % interval's percentiles


def load(path: str, policy: str) -> dict[tuple[int, str], list[bool]]:
    """Per (seed, path name): the touches' ``resolved``, in the file's order."""
    out: dict[tuple[int, str], list[bool]] = defaultdict(list)
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if row["policy"] == policy:
                out[(int(row["seed"]), row["path"])].append(row["resolved"] == "True")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("base", help="the first run's touches CSV")
    parser.add_argument("variant", help="the second run's touches CSV")
    parser.add_argument("--policy", default="endocam-visible")
    args = parser.parse_args()
    base, variant = load(args.base, args.policy), load(args.variant, args.policy)
    if set(base) != set(variant):
        raise SystemExit(f"the runs cover different episodes: {sorted(set(base) ^ set(variant))}")
    per_seed: dict[int, list[int]] = defaultdict(lambda: [0, 0, 0])  # touches, base, variant
    won = lost = 0
    for key in sorted(base):
        a, b = base[key], variant[key]
        if len(a) != len(b):
            raise SystemExit(f"seed {key[0]} {key[1]}: {len(a)} touches against {len(b)}")
        for x, y in zip(a, b, strict=True):
            won += y and not x
            lost += x and not y
            row = per_seed[key[0]]
            row[0], row[1], row[2] = row[0] + 1, row[1] + x, row[2] + y
    counts = np.array([per_seed[s] for s in sorted(per_seed)], dtype=float)  # (seeds, 3)
    n, r_base, r_var = counts.sum(axis=0)
    rng = np.random.default_rng(0)
    pick = rng.integers(0, len(counts), size=(RESAMPLES, len(counts)))
    sums = counts[pick].sum(axis=1)  # (RESAMPLES, 3)
    diff = 100.0 * (sums[:, 2] - sums[:, 1]) / sums[:, 0]
    lo, hi = np.percentile(diff, CI)
    print(
        f"{int(n)} touches, {len(counts)} seeds: base {100 * r_base / n:.1f} %, variant "
        f"{100 * r_var / n:.1f} %; won / lost {won} / {lost}; difference "
        f"{100 * (r_var - r_base) / n:+.1f} points [{lo:+.1f}, {hi:+.1f}]"
    )


if __name__ == "__main__":
    main()
