"""The free camera's tracking errors: ``endocam``, each of its ingredients off, and ``orientation``.

Runs the free 6-DoF camera (``episode.arm = free``) over three trajectory groups:

* ``ideal``: the ideal trajectories with 36, 54 and 71 control points (paper Fig. 5);
* ``study``: the three study trajectories (``endocam study make`` with its default seed:
  ``t1-36-low``, ``t2-36-high``, ``t3-71-high``), the paper's noisy set (Fig. 6);
* ``noisy71``: noisy 71-point trajectories, seeds 1-3 (a check).

Rows: ``endocam`` with every ingredient, then with one ingredient switched off at a time
(``TrackerConfig`` switches; ``centre_left_eye`` in ``ControllerConfig``; ``carrier lead
0.01 s`` is the lead before it was measured), ``endocam`` in the world where the idle PSM2
waits at its fixed tip (``psm2_idle = fixed``), and the paper-faithful ``orientation`` policy
in both worlds. Columns (means over the group's episodes): image centring error in the left
eye (px, a ring out of view counted as the farthest corner), left-eye 3D centring error
(mm, ``EpisodeResult.center_error``), orientation error (deg), ring out of view (% of steps),
mean working distance d_f (mm) and the share of steps with a tool tip outside the outer image
window (%). The paper's figures (Sec. V) are printed for reference.

Usage::

    PYTHONPATH=src MUJOCO_GL=egl .venv/bin/python examples/free_tracking.py [--jobs 2]
        [--groups ideal study noisy71] [--rows endocam orientation ...] [--duration 60]
"""

from __future__ import annotations

import argparse
import math
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from endocam.config import ExperimentConfig
from endocam.control.windows import WindowGeometry, WindowStatus, window_status_rows
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode
from endocam.runner.experiments import study_path_config
from endocam.task.study_paths import (
    DEFAULT_STUDY_SEED,
    STUDY_TRAJECTORIES,
    study_trajectory_seeds,
)
from endocam.task.trajectory import TrajectoryKind

# row name -> (policy, config overrides); every row runs the free camera
ROWS: dict[str, tuple[str, dict[str, Any]]] = {
    "endocam": ("endocam", {}),
    "- keep side": ("endocam", {"controller": {"tracker": {"keep_side": False}}}),
    "- orbit (way-points)": (
        "endocam",
        {"controller": {"tracker": {"side_transfer": "waypoints"}}},
    ),
    "- prediction": ("endocam", {"controller": {"tracker": {"predict": False}}}),
    "- feedforward": ("endocam", {"controller": {"tracker": {"feedforward": False}}}),
    "- carrier lead 0.01 s": ("endocam", {"controller": {"tracker": {"carrier_lead": 0.01}}}),
    "- left-eye centring": ("endocam", {"controller": {"centre_left_eye": False}}),
    "- direct approach (way-points)": (
        "endocam",
        {"controller": {"tracker": {"first_approach": "waypoints"}}},
    ),
    "- shorter look when low": (
        "endocam",
        {"controller": {"tracker": {"shorten_when_low": False}}},
    ),
    "endocam, PSM2 fixed": ("endocam", {"task": {"instruments": {"psm2_idle": "fixed"}}}),
    "orientation": ("orientation", {}),
    "orientation, PSM2 fixed": ("orientation", {"task": {"instruments": {"psm2_idle": "fixed"}}}),
}
GROUPS = ("ideal", "study", "noisy71")
PAPER = {"ideal": (35.0, 3.41, 5.45), "study": (36.0, 3.33, 4.30)}  # px, mm, deg (Sec. V)


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in extra.items():
        out[key] = _merge(out.get(key, {}), value) if isinstance(value, dict) else value
    return out


def episodes(group: str) -> list[tuple[str, TrajectoryKind, int, int]]:
    """(study trajectory name or "", kind, control points, seed) of a group's episodes."""
    if group == "ideal":
        return [("", TrajectoryKind.IDEAL, k, 0) for k in (36, 54, 71)]
    if group == "study":
        seeds = study_trajectory_seeds(DEFAULT_STUDY_SEED, len(STUDY_TRAJECTORIES))
        return [
            (st.name, TrajectoryKind.NOISY, st.control_points, s)
            for st, s in zip(STUDY_TRAJECTORIES, seeds, strict=True)
        ]
    return [("", TrajectoryKind.NOISY, 71, s) for s in (1, 2, 3)]


def tool_outside_fraction(result: EpisodeResult) -> float:
    """Fraction of steps with a tool tip outside the outer window (the window rule's trigger)."""
    g = WindowGeometry.of(result.camera, result.config.controller.windows)
    log = result.log
    out = sum(
        window_status_rows(g, T.tolist(), tips.tolist()) is WindowStatus.OUTSIDE_OUTER
        for T, tips in zip(log.T_world_cam, log.p_world_tips, strict=True)
    )
    return out / len(log.t)


def run_one(job: tuple[str, str, str, TrajectoryKind, int, int, float]) -> tuple[str, str, list]:
    """One episode: (row, group, [image px, 3D mm, orientation deg, out %, d_f mm, tool out %])."""
    row, group, name, kind, points, seed, duration = job
    policy, overrides = ROWS[row]
    data = _merge({"episode": {"arm": "free"}}, overrides)
    if duration > 0:
        data = _merge(data, {"task": {"trajectory": {"duration": duration}}})
    config = ExperimentConfig.model_validate(data)
    if name:
        config = study_path_config(config, next(s for s in STUDY_TRAJECTORIES if s.name == name))
    r = run_episode(config, EpisodeSpec(policy, kind, points, seed))
    return (
        row,
        group,
        [
            float(np.mean(r.image_error_saturated)),
            1e3 * float(np.mean(r.center_error)),
            math.degrees(float(np.mean(r.orientation_error))),
            100.0 * float(np.mean(r.ring_out_of_view)),
            1e3 * float(np.mean(r.log.d_f)),
            100.0 * tool_outside_fraction(r),
        ],
    )


def main() -> None:
    """Run the rows over the groups and print one Markdown table per group."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--groups", nargs="+", choices=GROUPS, default=list(GROUPS))
    parser.add_argument("--rows", nargs="+", choices=list(ROWS), default=list(ROWS))
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument(
        "--duration", type=float, default=0.0, help="trajectory duration, s (0: the config's)"
    )
    args = parser.parse_args()
    jobs = [
        (row, group, *ep, args.duration)
        for row in args.rows
        for group in args.groups
        for ep in episodes(group)
    ]
    results: dict[tuple[str, str], list[list[float]]] = {}
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for row, group, values in pool.map(run_one, jobs):
            results.setdefault((row, group), []).append(values)
    for group in args.groups:
        paper = PAPER.get(group)
        ref = f" (paper: {paper[0]:.0f} px, {paper[1]:.2f} mm, {paper[2]:.2f}°)" if paper else ""
        print(f"\n### {group}{ref}\n")
        print(
            "| free camera | image (px) | 3D left eye (mm) | orientation (deg) "
            "| ring out of view (%) | mean d_f (mm) | tool outside outer window (%) |"
        )
        print("|---|---|---|---|---|---|---|")
        for row in args.rows:
            m = np.mean(results[(row, group)], axis=0)
            print(
                f"| {row} | {m[0]:.1f} | {m[1]:.2f} | {m[2]:.2f} | {m[3]:.1f} | {m[4]:.1f} "
                f"| {m[5]:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
