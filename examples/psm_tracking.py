"""The ``endocam`` tracker against ``orientation`` and ``centering`` on the dVRK PSM.

Runs the three policies with the camera on the PSM over six trajectories: the three ideal ones
(36/54/71 control points, seed 0) and the three study trajectories (``STUDY_TRAJECTORIES``,
noisy, seeds ``study_trajectory_seeds(DEFAULT_STUDY_SEED)``, each with its ``trajectory_config``
override), and prints one Markdown row per policy and trajectory plus the means: image error
(px, a ring out of view counted as the farthest image corner), the left eye's 3D centring error
(mm), the orientation error (deg), the share of steps with the ring out of the left image and
the share the arm could not reach the goal exactly (``unreachable``).

Usage (from the repository root)::

    PYTHONPATH=src MUJOCO_GL=egl python examples/psm_tracking.py [--policies ...] [--arm psm]
        [--set controller.tracker.keep_side=false ...]

``--set`` takes dotted config fields with JSON values (an ablation switches one of them off);
``--ablate`` adds rows with one of the PSM carrier's switches off (``CameraArm.camera_path``:
far targets along a camera-space path; ``CameraArm.via_port``: through the port view after a
jump of the wrist's target), in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from typing import Any

import numpy as np

from endocam.config import ExperimentConfig
from endocam.robot.camera_arm import CameraArm
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode, state_fractions
from endocam.runner.experiments import study_path_config
from endocam.task.study_paths import (
    DEFAULT_STUDY_SEED,
    STUDY_TRAJECTORIES,
    study_trajectory_seeds,
)
from endocam.task.trajectory import TrajectoryKind

IDEAL_POINTS = (36, 54, 71)  # count: control points of the ideal trajectories (seed 0)
POLICIES = ("endocam", "orientation", "centering")


def _nested(overrides: list[str]) -> dict[str, Any]:
    data: dict[str, Any] = {}
    for item in overrides:
        key, _, value = item.partition("=")
        node = data
        *parents, leaf = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = json.loads(value)
    return data


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def episodes(
    base: ExperimentConfig,
) -> list[tuple[str, ExperimentConfig, TrajectoryKind, int, int]]:
    """(label, config, kind, control points, seed) of the six trajectories."""
    runs = [(f"ideal-{n}", base, TrajectoryKind.IDEAL, n, 0) for n in IDEAL_POINTS]
    seeds = study_trajectory_seeds(DEFAULT_STUDY_SEED)
    for traj, seed in zip(STUDY_TRAJECTORIES, seeds, strict=True):
        cfg = study_path_config(base, traj)
        runs.append((traj.name, cfg, TrajectoryKind.NOISY, traj.control_points, seed))
    return runs


def row(result: EpisodeResult) -> dict[str, float]:
    """The table's numbers for one episode."""
    fr = state_fractions(result.log)
    return {
        "img_px": float(np.mean(result.image_error_saturated)),
        "mm": 1e3 * float(np.mean(result.center_error)),
        "deg": math.degrees(float(np.mean(result.orientation_error))),
        "out_pct": 100.0 * float(np.mean(result.ring_out_of_view)),
        "unreach_pct": 100.0 * fr["unreachable"],
    }


def main() -> None:
    """Run the episodes and print the table."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--policies", nargs="+", default=list(POLICIES))
    parser.add_argument("--arm", default="psm")
    parser.add_argument("--set", nargs="*", default=[], help="dotted.field=JSON overrides")
    parser.add_argument("--only", nargs="*", default=None, help="trajectory labels to run")
    parser.add_argument(
        "--ablate",
        nargs="*",
        default=[],
        choices=["camera_path", "via_port"],
        help="also run each policy with this CameraArm switch off",
    )
    args = parser.parse_args()
    data = _merge({"episode": {"arm": args.arm}}, _nested(args.set))
    base = ExperimentConfig.model_validate(data)
    print(
        "| policy | trajectory | image (px) | 3D left eye (mm) | orientation (deg) "
        "| ring out of view (%) | unreachable (%) |"
    )
    print("|---|---|---|---|---|---|---|")
    means: dict[str, list[dict[str, float]]] = {}
    variants = [(p, None) for p in args.policies]
    variants += [(p, off) for off in args.ablate for p in args.policies if p != "centering"]
    for policy, off in variants:
        name = policy if off is None else f"{policy} −{off}"
        for label, cfg, kind, n, seed in episodes(base):
            if args.only and label not in args.only:
                continue
            t0 = time.perf_counter()
            if off is not None:
                setattr(CameraArm, off, False)
            try:
                r = row(run_episode(cfg, EpisodeSpec(policy, kind, n, seed)))
            finally:
                CameraArm.camera_path = CameraArm.via_port = True
            means.setdefault(name, []).append(r)
            took = time.perf_counter() - t0
            print(
                f"| {name} | {label} | {r['img_px']:.1f} | {r['mm']:.2f} | {r['deg']:.1f} "
                f"| {r['out_pct']:.2f} | {r['unreach_pct']:.1f} |  ({took:.1f} s)",
                flush=True,
            )
    for policy, rows in means.items():
        m = {key: float(np.mean([r[key] for r in rows])) for key in rows[0]}
        print(
            f"| **{policy}** | mean | {m['img_px']:.1f} | {m['mm']:.2f} | {m['deg']:.1f} "
            f"| {m['out_pct']:.2f} | {m['unreach_pct']:.1f} |",
            flush=True,
        )
    if "centering" in means:
        c = {key: float(np.mean([r[key] for r in means["centering"]])) for key in ("img_px", "deg")}
        for policy, rows in means.items():
            img = float(np.mean([r["img_px"] for r in rows]))
            deg = float(np.mean([r["deg"] for r in rows]))
            print(
                f"{policy}: orientation / centering = {deg / c['deg']:.2f} (target ≤ 0.33), "
                f"image / centering = {img / c['img_px']:.2f} (target ≤ 1.25)"
            )


if __name__ == "__main__":
    main()
