"""Does the camera show the touch? The closing gap per touch, for ``endocam`` and its rivals.

For each study seed (the study's three noisy paths, noise seeds ``study_trajectory_seeds``), each
policy runs the path headless (no video); at each ground-truth touch the closing gap (the
closest approach at ``GAP_SEEN`` = 0.5 mm before the onset, :func:`gap_hidden_by`) is tested
from the left and the right eye (MuJoCo ray casts through every geom), and the image length of
0.5 mm of gap opening along the contact normal is measured there (``pixel_scales``). Per policy:

- ``left``: share of touches whose gap is in sight from the left eye;
- ``either``: from at least one eye;
- ``resolved``: in sight from either eye and 0.5 mm of gap spans ≥ ``RESOLVED_PX`` there (in
  the eye that sees it; both: the larger span);
- ``resolved_perp``: the same with 0.5 mm perpendicular to the line of sight (``f / Z``);
- mean orientation error (deg, the episode means averaged), safety violations
  (``runner.check`` on the written run), CPU s per episode (the control loop alone);
- what hides the gap from the left eye (touches per hider).

Run::

    MUJOCO_GL=egl PYTHONPATH=src .venv/bin/python bench/visible_view.py --seeds 1,2,3 \\
        --policies endocam,endocam-visible
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.runner.check import check_run
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode
from endocam.runner.experiments import ground_truth, study_path_config
from endocam.runner.outputs import write_run
from endocam.sim.render import WireChaserScene
from endocam.study.observability import (
    GAP_SEEN,
    GAP_SEEN_DT,
    OUTSIDE_IMAGE,
    in_image,
    pixel_scales,
)
from endocam.study.observer import PRE_TOUCH_S
from endocam.task.study_paths import STUDY_TRAJECTORIES, study_trajectory_seeds
from endocam.task.touches import clearances, contact_normal
from endocam.task.trajectory import TrajectoryKind

RESOLVED_PX = 2.0  # px: 0.5 mm of gap must span this many pixels to count as resolved
GAP_M = 0.5e-3  # m, the gap whose image length is measured
EYES = ("left", "right")


@dataclass
class Tally:
    """Per-policy counts over every touch and episode."""

    touches: int = 0
    left: int = 0
    either: int = 0
    resolved: int = 0
    resolved_perp: int = 0
    orientation_deg: list[float] = field(default_factory=list)
    violations: int = 0
    cpu_s: list[float] = field(default_factory=list)
    hiders: Counter[str] = field(default_factory=Counter)


def closing_gap(result: EpisodeResult, t_start: float) -> tuple[int, np.ndarray, np.ndarray]:
    """The step, ring pose (4, 4) and closest-approach point (3,), m, of a touch's closing gap.

    The same instant as :func:`endocam.study.observability.gap_hidden_by`: the first time in the
    ``PRE_TOUCH_S`` before the onset at which the clearance is at most ``GAP_SEEN``.
    """
    t0 = max(t_start - PRE_TOUCH_S, 0.0)
    ts = np.append(np.arange(t0, t_start, GAP_SEEN_DT), t_start)
    T_rings = result.trajectory.poses(ts)
    c, p = clearances(T_rings, result.wire, result.config.task.ring)
    closing = np.flatnonzero(c <= GAP_SEEN)
    i = int(closing[0]) if closing.size else len(ts) - 1
    rate = result.config.episode.control_rate
    k = int(np.clip(round(float(ts[i]) * rate), 0, len(result.log.t) - 1))
    return k, T_rings[i], p[i]


def observe(result: EpisodeResult, scene: WireChaserScene, tally: Tally) -> None:
    """Add every touch of ``result`` to ``tally`` (left / right sight, pixel spans, hiders)."""
    major = result.config.task.ring.major_radius
    for ev in result.touches.events:
        k, T_ring, p = closing_gap(result, float(ev.t_start))
        T_cam = result.log.T_world_cam[k]
        scene.set_psm2_tip(result.log.p_world_tips[k, 1])
        scene.set_ring_pose(T_ring)
        scene.set_camera_pose(T_cam)
        try:
            u = contact_normal(p, T_ring, major)
        except ValueError:
            u = T_cam[:3, 0]
        seen, span, perp = {}, 0.0, 0.0
        for eye in EYES:
            inside = in_image(scene.camera, T_cam, p, eye)
            hider = scene.occluder(p, T_cam, eye) if inside else OUTSIDE_IMAGE
            seen[eye] = hider is None
            if eye == "left" and hider is not None:
                tally.hiders[hider] += 1
            if seen[eye]:
                px_per_m, gap_px_per_m = pixel_scales(scene.camera, T_cam, p, u, eye)
                span = max(span, GAP_M * gap_px_per_m)
                perp = max(perp, GAP_M * px_per_m)
        tally.touches += 1
        tally.left += seen["left"]
        tally.either += seen["left"] or seen["right"]
        tally.resolved += span >= RESOLVED_PX
        tally.resolved_perp += perp >= RESOLVED_PX


def main() -> None:
    """Parse the arguments, run the episodes, print one row per policy."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,2,3", help="study seeds, comma-separated")
    parser.add_argument("--policies", default="endocam,endocam-visible")
    parser.add_argument("--arm", default="psm", choices=[a.value for a in ArmKind])
    parser.add_argument("--paths", default="", help="study path names (default: all three)")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s]
    policies = [p for p in args.policies.split(",") if p]
    wanted = [p for p in args.paths.split(",") if p]
    paths = [t for t in STUDY_TRAJECTORIES if not wanted or t.name in wanted]
    base = ExperimentConfig()
    base = base.model_copy(
        update={"episode": base.episode.model_copy(update={"arm": ArmKind(args.arm)})}
    )
    tallies = {p: Tally() for p in policies}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            noise = study_trajectory_seeds(seed, len(STUDY_TRAJECTORIES))
            for traj, traj_seed in zip(STUDY_TRAJECTORIES, noise, strict=True):
                if traj not in paths:
                    continue
                cfg = study_path_config(base, traj)
                touches = ground_truth(cfg, TrajectoryKind.NOISY, traj.control_points, traj_seed)
                for policy in policies:
                    spec = EpisodeSpec(policy, TrajectoryKind.NOISY, traj.control_points, traj_seed)
                    t0 = time.process_time()
                    result = run_episode(cfg, spec, touches=touches)
                    tally = tallies[policy]
                    tally.cpu_s.append(time.process_time() - t0)
                    tally.orientation_deg.append(
                        math.degrees(float(np.mean(result.orientation_error)))
                    )
                    run_dir = Path(tmp) / f"{policy}-{traj.name}-{seed}"
                    write_run(result, run_dir, video=False)
                    tally.violations += check_run(run_dir).total
                    with WireChaserScene(cfg.task, result.camera) as scene:
                        observe(result, scene, tally)
                    print(
                        f"  seed {seed} {traj.name} {policy}: {len(result.touches.events)} "
                        f"touches, orientation {tally.orientation_deg[-1]:.1f} deg",
                        flush=True,
                    )
    print(f"study seeds {seeds}, paths {[t.name for t in paths]}, arm {args.arm}")
    head = "policy | touches | left | either | resolved | resolved (f/Z) | orient. deg"
    print(head + " | violations | CPU s/episode | left-eye hiders")
    for policy, t in tallies.items():
        n = max(t.touches, 1)
        print(
            f"{policy} | {t.touches} | {t.left / n:.0%} | {t.either / n:.0%} | "
            f"{t.resolved / n:.0%} | {t.resolved_perp / n:.0%} | "
            f"{np.mean(t.orientation_deg):.1f} | {t.violations} | "
            f"{np.median(t.cpu_s):.2f} | {dict(t.hiders.most_common())}"
        )


if __name__ == "__main__":
    main()
