"""Compare the camera carried by the dVRK PSM and by the ECM on the paper's trajectories.

Runs ``endocam`` and the paper-faithful ``orientation`` (free camera and PSM) and
``orientation-ecm`` (the paper-faithful goal on the ECM) on the six episodes of ``endocam
experiment paper`` (3 ideal trajectories with 36/54/71 control points, the study's 3 noisy
paths) and prints a Markdown table of the means: image centring
error (px, a ring out of view counted as the farthest image corner), 3D centring error (mm),
orientation error (deg), the view the arm conceded (deg: the angle between the goal and the
nearest feasible view, averaged over all steps), the share of steps with the ring out of view,
and the fraction of control steps the arm could not reach the goal (``unreachable``) or the
goal left the cone (``frozen``).

Usage::

    MUJOCO_GL=egl .venv/bin/python examples/compare_arms.py [--arms free psm ecm]
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from endocam.config import ExperimentConfig
from endocam.runner.episode import run_episode, state_fractions
from endocam.runner.experiments import paper_episodes

ROWS = {
    "free-endocam": ("endocam", "free"),
    "psm-endocam": ("endocam", "psm"),
    "free": ("orientation", "free"),
    "psm": ("orientation", "psm"),
    "ecm": ("orientation-ecm", "free"),
}


def main() -> None:
    """Run the comparison and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="+", choices=list(ROWS), default=list(ROWS))
    args = parser.parse_args()
    print(
        "| camera | trajectories | image error (px) | 3D error (mm) | orientation error (deg) "
        "| view conceded (deg) | ring out of view | unreachable | frozen |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for arm in args.arms:
        policy, episode_arm = ROWS[arm]
        config = ExperimentConfig.model_validate({"episode": {"arm": episode_arm}})
        results = [run_episode(e.config, e.spec) for e in paper_episodes(config, policy)]
        for kind in ("ideal", "noisy"):
            group = [r for r in results if r.spec.trajectory.value == kind]
            img = np.mean([np.mean(r.image_error_saturated) for r in group])
            mm = 1e3 * np.mean([np.mean(r.center_error) for r in group])
            deg = math.degrees(np.mean([np.mean(r.orientation_error) for r in group]))
            conceded = [r.log.goal_orientation_error for r in group]
            ceded = "–" if conceded[0] is None else f"{math.degrees(np.mean(conceded)):.1f}"
            out = 100 * np.mean([np.mean(r.ring_out_of_view) for r in group])
            fr = [state_fractions(r.log) for r in group]
            unreach = 100 * np.mean([f["unreachable"] for f in fr])
            frozen = 100 * np.mean([f["frozen_outside_cone"] for f in fr])
            carrier = "ecm" if arm == "ecm" else episode_arm
            print(
                f"| {carrier} ({policy}) | {kind} | {img:.0f} | {mm:.1f} | {deg:.1f} | {ceded} | "
                f"{out:.1f} % | {unreach:.0f} % | {frozen:.0f} % |",
                flush=True,
            )


if __name__ == "__main__":
    main()
