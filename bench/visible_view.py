"""Does the camera show the touch? The closing gap per touch, for ``endocam`` and its rivals.

For each study seed (the study's three noisy paths, noise seeds ``study_trajectory_seeds``), each
policy runs the path headless (no video); at each ground-truth touch the closing gap is measured
as the study measures it (:func:`endocam.study.visibility.closing_gap`: the first instant in the
``PRE_TOUCH_S`` before the onset at which the clearance is down to ``GAP_SEEN`` = 0.5 mm, MuJoCo
ray casts from both eyes, the image length of 0.5 mm of gap along the contact normal). Per
policy:

- ``left``: share of touches whose gap is in sight from the left eye;
- ``either``: from at least one eye;
- ``resolved``: in sight from an eye where 0.5 mm of gap spans ≥ ``RESOLVED_PX`` (2 px);
- mean orientation error (deg, the episode means averaged), safety violations
  (``runner.check`` on the written run), CPU s per episode (the control loop alone);
- what hides the gap from a viewer with both eyes (touches per hider).

Run (``--seeds`` takes ranges, ``7-26``; ``--visible`` overrides ``VisibleConfig`` fields, for
tuning; ``--touches-csv`` writes one row per touch)::

    MUJOCO_GL=egl PYTHONPATH=src .venv/bin/python bench/visible_view.py --seeds 3-6 \\
        --policies endocam,endocam-visible
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import endocam.control.policies.visible as visible
from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.runner.check import check_run
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.experiments import ground_truth, study_path_config
from endocam.runner.outputs import write_run
from endocam.sim.render import WireChaserScene
from endocam.study.visibility import closing_gap, control_step
from endocam.task.study_paths import STUDY_TRAJECTORIES, study_trajectory_seeds
from endocam.task.trajectory import TrajectoryKind


@dataclass
class Tally:
    """Per-policy counts over every touch and episode."""

    touches: int = 0
    left: int = 0
    either: int = 0
    resolved: int = 0
    orientation_deg: list[float] = field(default_factory=list)
    violations: int = 0
    cpu_s: list[float] = field(default_factory=list)
    hiders: Counter[str] = field(default_factory=Counter)


def parse_seeds(text: str) -> list[int]:
    """``"3,4,7-9"`` → ``[3, 4, 7, 8, 9]``."""
    seeds: list[int] = []
    for part in (p for p in text.split(",") if p):
        lo, _, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi or lo) + 1))
    return seeds


def parse_overrides(text: str) -> dict[str, Any]:
    """``"tilt_cost=0.5,tilt_steps=2"`` → ``VisibleConfig`` field values (degrees for angles
    named ``*_deg``: ``max_tilt_deg=15``)."""
    out: dict[str, Any] = {}
    types = {f.name: f.type for f in dataclasses.fields(visible.VisibleConfig)}
    for item in (p for p in text.split(",") if p):
        key, _, value = item.partition("=")
        if key.endswith("_deg"):
            out[key[:-4]] = math.radians(float(value))
        elif types.get(key) in ("int", int):
            out[key] = int(value)
        elif types.get(key) in ("bool", bool):
            out[key] = value.lower() in ("1", "true", "yes")
        else:
            out[key] = float(value)
    return out


def main() -> None:
    """Parse the arguments, run the episodes, print one row per policy."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", default="1-3", help="study seeds: 3,4 or 7-26")
    parser.add_argument("--policies", default="endocam,endocam-visible")
    parser.add_argument("--arm", default="psm", choices=[a.value for a in ArmKind])
    parser.add_argument("--paths", default="", help="study path names (default: all three)")
    parser.add_argument("--visible", default="", help="VisibleConfig overrides: key=value,...")
    parser.add_argument("--touches-csv", default="", help="write one row per touch here")
    args = parser.parse_args()
    seeds = parse_seeds(args.seeds)
    policies = [p for p in args.policies.split(",") if p]
    wanted = [p for p in args.paths.split(",") if p]
    paths = [t for t in STUDY_TRAJECTORIES if not wanted or t.name in wanted]
    overrides = parse_overrides(args.visible)
    if overrides:  # the registry builds VisiblePolicy() with the module's VisibleConfig()
        base_cfg = visible.VisibleConfig
        setattr(visible, "VisibleConfig", lambda: base_cfg(**overrides))  # noqa: B010
    seen: list[visible.VisiblePolicy] = []  # the episode's endocam-visible, for its counts
    reset = visible.VisiblePolicy.reset

    def recording_reset(self: visible.VisiblePolicy, context: Any) -> None:
        seen.append(self)
        reset(self, context)

    setattr(visible.VisiblePolicy, "reset", recording_reset)  # noqa: B010
    base = ExperimentConfig()
    base = base.model_copy(
        update={"episode": base.episode.model_copy(update={"arm": ArmKind(args.arm)})}
    )
    tallies = {p: Tally() for p in policies}
    rows: list[dict[str, Any]] = []
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
                        for ev in result.touches.events:
                            gap = closing_gap(result, scene, float(ev.t_start))
                            tally.touches += 1
                            tally.left += gap.left.in_sight
                            tally.either += gap.in_sight_either
                            tally.resolved += gap.resolved
                            if gap.hidden_by is not None:
                                tally.hiders[gap.hidden_by] += 1
                            k = control_step(result, gap.t_s)
                            rows.append(
                                {
                                    "seed": seed,
                                    "path": traj.name,
                                    "policy": policy,
                                    "t_s": round(gap.t_s, 3),
                                    "resolved": gap.resolved,
                                    "either": gap.in_sight_either,
                                    "gap_px": round(gap.gap_px, 2),
                                    "hidden_by": gap.hidden_by or "",
                                    "orientation_deg": round(
                                        math.degrees(float(result.orientation_error[k])), 1
                                    ),
                                }
                            )
                    counts = ""
                    if seen and policy == visible.VisiblePolicy.name:
                        v = seen[-1]
                        counts = (
                            f", side changes {v.side_changes}, tilted "
                            f"{v.tilted_steps / len(result.log.t):.0%} of steps"
                        )
                    seen.clear()
                    print(
                        f"  seed {seed} {traj.name} {policy}: {len(result.touches.events)} "
                        f"touches, orientation {tally.orientation_deg[-1]:.1f} deg, "
                        f"CPU {tally.cpu_s[-1]:.2f} s{counts}",
                        flush=True,
                    )
    if args.touches_csv and rows:
        with open(args.touches_csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    print(f"study seeds {args.seeds}, paths {[t.name for t in paths]}, arm {args.arm}")
    if overrides:
        print(f"VisibleConfig overrides: {overrides}")
    print(
        "policy | touches | left | either | resolved | orient. deg | violations | CPU s/ep", end=""
    )
    print(" | hiders")
    for policy, t in tallies.items():
        n = max(t.touches, 1)
        print(
            f"{policy} | {t.touches} | {t.left / n:.0%} | {t.either / n:.0%} | "
            f"{t.resolved / n:.0%} | {np.mean(t.orientation_deg):.1f} | {t.violations} | "
            f"{np.median(t.cpu_s):.2f} | {dict(t.hiders.most_common())}"
        )


if __name__ == "__main__":
    main()
