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

``--diagnose`` adds, per ``endocam-visible`` touch, what decides a miss: the camera's lag
(deg) to the arm's command and to the view the policy was turned to (its target axis), and an
**oracle on the candidate set**: ideal cameras (at the logged working distance, level) placed
on the policy's own candidate axes about the true normal at the closing instant, on the camera's
side and on both, and on a denser set (5–25° every 5°, 12 azimuths), each measured as the study
measures the gap. A miss whose target view resolves is a lag; one whose best candidate does is a
choice; one no candidate resolves is a candidate-set problem.

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
from endocam.control.occlusion import (
    RingShape,
    direction_table,
    eye_positions,
    gap_points,
    view_directions,
    view_scores,
    wire_window,
)
from endocam.control.types import TrackingState
from endocam.robot.actuator import ArmKind
from endocam.runner.check import check_run
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.experiments import ground_truth, study_path_config
from endocam.runner.outputs import write_run
from endocam.sim.render import WireChaserScene
from endocam.study.visibility import (
    ClosingGap,
    closing_gap,
    closing_moment,
    control_step,
    view_gap,
)
from endocam.task.study_paths import STUDY_TRAJECTORIES, study_trajectory_seeds
from endocam.task.trajectory import TrajectoryKind
from endocam.view import look_at_pose


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
    lost: list[float] = field(default_factory=list)  # per episode: share of lost-tracking steps


LOST = TrackingState.LOST_TRACKING.value  # the log's state while the tracker holds
DENSE_TILTS_RAD = np.radians([5.0, 10.0, 15.0, 20.0, 25.0])  # the oracle's denser set
DENSE_AZIMUTHS = 12


def axis_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two directions (3,), deg."""
    c = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12)
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def diagnose(
    result: Any, scene: WireChaserScene, gap: ClosingGap, t_start: float, axes: dict[int, Any]
) -> dict[str, Any]:
    """One touch's lag and candidate-set oracle (module docstring); ``axes`` per control step:
    the policy's (target, applied) axes."""
    vc = visible.VisibleConfig()
    moment = closing_moment(result, t_start)
    k, T_ring, p_gap = moment.k, moment.T_world_ring, moment.p_world_gap
    n = T_ring[:3, 2]
    T_cam, T_cmd = result.log.T_world_cam[k], result.log.T_world_cmd[k]
    u_cam = -T_cam[:3, 2]
    side = 1.0 if float(u_cam @ n) >= 0.0 else -1.0
    d_f = float(result.log.d_f[k])

    def resolved(u: np.ndarray) -> bool:
        T_cam_ideal = look_at_pose(T_ring[:3, 3] + d_f * u, T_ring[:3, 3])
        return view_gap(scene, T_ring, T_cam_ideal, p_gap).resolved

    row: dict[str, Any] = {
        "tilt_deg": round(axis_angle_deg(u_cam, side * n), 1),
        "arm_lag_deg": round(axis_angle_deg(T_cam[:3, 2], T_cmd[:3, 2]), 1),
    }
    target = axes.get(k)
    row["target_lag_deg"] = "" if target is None else round(axis_angle_deg(u_cam, target[0]), 1)
    row["target_resolved"] = "" if target is None else int(resolved(target[0]))
    row["engaged"] = "" if target is None else int(target[2])
    p_cam = T_cam[:3, 3]
    u_line = (p_cam - T_ring[:3, 3]) / np.linalg.norm(p_cam - T_ring[:3, 3])
    row["off_centre_deg"] = round(axis_angle_deg(u_line, u_cam), 1)
    row["line_lag_deg"] = "" if target is None else round(axis_angle_deg(u_line, target[0]), 1)
    row["line_resolved"] = int(resolved(u_line))
    row["normal_resolved"] = int(resolved(side * n))
    own = view_directions(n, direction_table(vc.tilts, vc.azimuths))
    ray = np.array([resolved(side * u) for u in own])
    row["side_cands"] = int(ray.sum())
    # the scorer's own model at the true closing pose: its best view on this side, and whether
    # the ray casts agree with it (a model/prediction problem against a choice rule one)
    window = wire_window(result.wire, T_ring[:3, 3], vc.window)
    shape = RingShape.of(result.config.task.ring)
    gaps = gap_points(T_ring, window, shape, result.wire.radius, vc.rim_points, vc.weight_scale)
    dirs = side * own
    eyes = eye_positions(T_ring[:3, 3], dirs, d_f, float(result.camera.baseline))
    focal = float(result.camera.intrinsics.K[1, 1])
    shares = view_scores(eyes, -dirs, gaps, window, T_ring, shape, result.wire.radius, focal,
                         vc.resolved_px).max(axis=1)  # fmt: skip
    tilt = np.concatenate([[0.0], np.repeat(vc.tilts, vc.azimuths)])
    best = int(np.argmax(shares - vc.tilt_cost * tilt))
    row["model_best_resolved"] = int(ray[best])
    row["model_best_tilt"] = round(math.degrees(float(tilt[best])))
    for h in (0.1, 0.25, 0.5):  # the model's choice on the pose predicted h s ahead
        t_obs = moment.t_s - h - 0.05
        P = result.trajectory.poses(np.array([t_obs - vc.velocity_window, t_obs]))
        T_p = visible.predicted_pose(P[0], P[1], vc.velocity_window, h + 0.05,
                                     vc.max_predicted_turn)  # fmt: skip
        n_p = T_p[:3, 2]
        dirs_p = side * view_directions(n_p, direction_table(vc.tilts, vc.azimuths))
        gaps_p = gap_points(T_p, window, shape, result.wire.radius, vc.rim_points,
                            vc.weight_scale)  # fmt: skip
        eyes_p = eye_positions(T_p[:3, 3], dirs_p, d_f, float(result.camera.baseline))
        sh = view_scores(eyes_p, -dirs_p, gaps_p, window, T_p, shape, result.wire.radius,
                         focal, vc.resolved_px).max(axis=1)  # fmt: skip
        b = int(np.argmax(sh - vc.tilt_cost * tilt))
        row[f"pred{h}_best_resolved"] = int(resolved(dirs_p[b]))
    row["model_agree"] = round(float(np.mean((shares > 0.5) == ray)), 2)
    row["other_cands"] = sum(resolved(-side * u) for u in own)
    row["n_cands"] = len(own)
    dense = view_directions(n, direction_table(DENSE_TILTS_RAD, DENSE_AZIMUTHS))
    row["dense_side"] = sum(resolved(side * u) for u in dense)
    row["dense_both"] = row["dense_side"] + sum(resolved(-side * u) for u in dense)
    row["n_dense"] = len(dense)
    scene.set_psm2_tip(result.log.p_world_tips[k, 1])  # as closing_gap left it
    return row


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
    parser.add_argument(
        "--diagnose", action="store_true", help="lag and candidate oracle per unresolved touch"
    )
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
    axes: dict[int, Any] = {}  # control step → the policy's (target, applied) axes
    step = visible.VisiblePolicy.step
    rate = ExperimentConfig().episode.control_rate

    def recording_step(self: visible.VisiblePolicy, obs: Any) -> Any:
        command = step(self, obs)
        a = self.view_axes(obs.T_world_ring)
        if a is not None:
            axes[round(float(obs.t) * rate)] = (*a, self.engaged)
        return command

    if args.diagnose:
        setattr(visible.VisiblePolicy, "step", recording_step)  # noqa: B010
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
                    tally.lost.append(float(np.mean(result.log.state == LOST)))
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
                            extra = (
                                diagnose(result, scene, gap, float(ev.t_start), axes)
                                if args.diagnose and policy == visible.VisiblePolicy.name
                                else {}
                            )
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
                                    **extra,
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
                    axes.clear()
                    print(
                        f"  seed {seed} {traj.name} {policy}: {len(result.touches.events)} "
                        f"touches, orientation {tally.orientation_deg[-1]:.1f} deg, "
                        f"CPU {tally.cpu_s[-1]:.2f} s, lost {tally.lost[-1]:.1%}{counts}",
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
        "policy | touches | left | either | resolved | orient. deg | violations | lost | CPU s/ep",
        end="",
    )
    print(" | hiders")
    for policy, t in tallies.items():
        n = max(t.touches, 1)
        print(
            f"{policy} | {t.touches} | {t.left / n:.0%} | {t.either / n:.0%} | "
            f"{t.resolved / n:.0%} | {np.mean(t.orientation_deg):.1f} | {t.violations} | "
            f"{np.mean(t.lost):.2%} | {np.median(t.cpu_s):.2f} | {dict(t.hiders.most_common())}"
        )


if __name__ == "__main__":
    main()
