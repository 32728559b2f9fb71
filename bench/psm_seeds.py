"""Per-seed tracking of one policy on one carrier over noise seeds: the stuck-arm benchmark.

For each seed, runs ``endocam run --no-video`` in-process (``run_and_write``: the episode, its
files and the safety check) and prints the mean image error (px, saturated), the mean 3D
centring error (mm), the mean orientation error (deg), the ring's out-of-view share, the longest
frozen span (s: consecutive steps whose joints do not move while the command is more than
``FROZEN_CMD_GAP_M`` from the camera), the state logged most over that span and the safety
check; then the medians and means. Run::

    MUJOCO_GL=egl PYTHONPATH=src .venv/bin/python bench/psm_seeds.py --seeds 1-20 --arm psm
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

FROZEN_CMD_GAP_M = 2e-3  # m: the command this far from the camera, the arm should move
FROZEN_JOINT_TOL = 1e-7  # rad / m: joints that moved less than this did not move


def frozen_span(t: np.ndarray, q: np.ndarray, gap: np.ndarray) -> tuple[float, int, int]:
    """Longest run (s) of steps with frozen joints and a far command; its first and last step."""
    if q.shape[1] == 0:
        return 0.0, 0, 0
    still = np.zeros(len(t), dtype=bool)
    still[1:] = np.max(np.abs(np.diff(q, axis=0)), axis=1) < FROZEN_JOINT_TOL
    bad = still & (gap > FROZEN_CMD_GAP_M)
    best, start, i0, i1 = 0, 0, 0, 0
    for k, b in enumerate(bad):
        if not b:
            start = k + 1
        elif k - start + 1 > best:
            best, i0, i1 = k - start + 1, start, k
    dt = float(t[1] - t[0])
    return best * dt, i0, i1


def one_seed(policy: str, arm: str, trajectory: str, points: int, seed: int, out: Path) -> dict:
    """Run one seed into ``out``; its figures."""
    from endocam.config import ExperimentConfig
    from endocam.robot.actuator import ArmKind
    from endocam.runner.episode import EpisodeSpec, run_episode
    from endocam.runner.outputs import metrics_dict, write_run, written_check
    from endocam.task.trajectory import TrajectoryKind

    base = ExperimentConfig()
    episode = base.episode.model_copy(update={"arm": ArmKind(arm)})
    config = base.model_copy(update={"episode": episode})
    spec = EpisodeSpec(policy, TrajectoryKind(trajectory), points, seed)
    result = run_episode(config, spec)
    write_run(result, out, video=False)
    m = metrics_dict(result)
    log = result.log
    q = log.joints if log.joints is not None else np.empty((len(log.t), 0))
    gap = np.linalg.norm(log.T_world_cmd[:, :3, 3] - log.T_world_cam[:, :3, 3], axis=1)
    span, i0, i1 = frozen_span(log.t, q, gap)
    states = Counter(log.state[i0 : i1 + 1].tolist()) if span > 0 else Counter()
    return {
        "seed": seed,
        "px": m["image_error_px"]["mean"],
        "mm": m["center_error_mm"]["mean"],
        "deg": m["orientation_error_deg"]["mean"],
        "oov": m["ring_out_of_view_fraction"],
        "frozen_s": span,
        "frozen_at": float(log.t[i0]) if span > 0 else math.nan,
        "frozen_state": states.most_common(1)[0][0] if states else "-",
        "check": written_check(out)["violations"],
        "states": {s: float(np.mean(log.state == s)) for s in np.unique(log.state)},
    }


def seeds_arg(text: str) -> list[int]:
    """``1-20`` or ``4,7``: the seeds."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def main() -> None:
    """Parse the arguments, run every seed, print the table."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=seeds_arg, default=seeds_arg("1-20"))
    p.add_argument("--policy", default="endocam")
    p.add_argument("--arm", default="psm")
    p.add_argument("--trajectory", default="noisy")
    p.add_argument("--control-points", type=int, default=71)
    p.add_argument("--out", type=Path, default=None, help="keep the runs here (default: temp)")
    p.add_argument("--states", action="store_true", help="print each seed's state shares")
    args = p.parse_args()
    root = args.out or Path(tempfile.mkdtemp(prefix="psm_seeds_"))
    print(
        f"{args.policy} on {args.arm}, {args.trajectory} {args.control_points} points; "
        f"runs in {root}"
    )
    print(
        f"{'seed':>4} {'img px':>8} {'3D mm':>7} {'ori deg':>8} {'oov':>6} "
        f"{'frozen s':>8} {'at s':>6} {'state':>12} {'check':>5}"
    )
    rows = []
    for seed in args.seeds:
        r = one_seed(
            args.policy, args.arm, args.trajectory, args.control_points, seed, root / f"seed{seed}"
        )
        rows.append(r)
        print(
            f"{seed:>4} {r['px']:8.1f} {r['mm']:7.1f} {r['deg']:8.1f} {r['oov']:6.3f} "
            f"{r['frozen_s']:8.2f} {r['frozen_at']:6.2f} {r['frozen_state']:>12} "
            f"{r['check']:>5}",
            flush=True,
        )
        if args.states:
            print("      " + "  ".join(f"{k} {v:.3f}" for k, v in r["states"].items()))
    for name, f in (("median", statistics.median), ("mean", statistics.fmean)):
        print(
            f"{name:>6} {f([r['px'] for r in rows]):6.1f} {f([r['mm'] for r in rows]):7.1f} "
            f"{f([r['deg'] for r in rows]):8.1f} {f([r['oov'] for r in rows]):6.3f} "
            f"{f([r['frozen_s'] for r in rows]):8.2f}"
        )
    print(
        f"max frozen span {max(r['frozen_s'] for r in rows):.2f} s; "
        f"check violations {sum(r['check'] for r in rows)}"
    )


if __name__ == "__main__":
    main()
