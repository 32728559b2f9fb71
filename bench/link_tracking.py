"""Tracking errors of an episode over the Zenoh link against the same episode in-process.

For each carrier and policy: the episode in this process (``run_episode``), then the same
episode (same options and seed) with the arm in a second process (``endocam robot serve``) and
the policy here (``run_remote``, lock-stepped: one control period per command). Prints, per
episode, the mean image-centring error (px), 3-D centre error (mm) and orientation error (deg)
of both runs, their relative difference (%), the steps over the link, and the largest camera
position difference between the two logs (mm: where round-off made them part).

Run (60 s at 100 Hz; the issue's target: every tracking error within 5 %)::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/link_tracking.py \\
        --duration 60 --arms free psm --policies endocam orientation
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from endocam.config import ExperimentConfig, load_config
from endocam.link.client import ZenohArm, run_remote
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind
from link_latency import serve_robot  # bench/: the robot process, as there

WAIT_S = 180.0  # s: the robot's start-up on a loaded machine
TIMEOUT_S = 5.0  # s: the robot answers within this (a loaded machine: no false silences)
CONTROL_POINTS = 71
SEED = 1


def errors(r: EpisodeResult) -> dict[str, float]:
    """Mean tracking errors of a run: image px, centre mm, orientation deg (finite samples)."""
    return {
        "image_px": float(np.nanmean(r.image_error)),
        "center_mm": float(np.nanmean(r.center_error) * 1e3),
        "orient_deg": float(np.degrees(np.nanmean(r.orientation_error))),
    }


def over_link(config_file: Path, cfg: ExperimentConfig, spec: EpisodeSpec) -> tuple[Any, str]:
    """The episode with the arm served by a second process; (RemoteRun, the robot's last line)."""
    arm_name, points = cfg.episode.arm.value, spec.control_points
    robot, endpoint = serve_robot(arm_name, config_file, points, spec.seed, (WAIT_S, TIMEOUT_S))
    arm = ZenohArm(cfg.episode.arm, endpoint, 1.0 / cfg.episode.control_rate, TIMEOUT_S)
    try:
        remote = run_remote(cfg, spec, arm, WAIT_S)
    finally:
        arm.close()
        out, _ = robot.communicate(timeout=120)
    return remote, (out.strip().splitlines() or [""])[-1]


def _cells(a: dict[str, float], b: dict[str, float]) -> str:
    return " | ".join(f"{a[k]:.3f} {b[k]:.3f} {100 * (b[k] - a[k]) / a[k]:+.2f}" for k in a)


def main() -> None:
    """Parse the options, run each pair, print the table."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=60.0, help="s (default 60)")
    p.add_argument("--rate", type=float, default=100.0, help="control rate, Hz (default 100)")
    p.add_argument("--arms", nargs="+", default=["free", "psm"], choices=[k.value for k in ArmKind])
    p.add_argument("--policies", nargs="+", default=["endocam", "orientation"])
    p.add_argument("--seeds", type=int, nargs="+", default=[SEED], help="noise seeds (default 1)")
    args = p.parse_args()
    folder = Path(tempfile.mkdtemp())
    print(
        "arm policy steps | image_px in link % | center_mm in link % | orient_deg in link % "
        "| max_dpos_mm"
    )
    for arm_name in args.arms:
        config_file = folder / f"{arm_name}.toml"
        config_file.write_text(
            f"[task.trajectory]\nduration = {args.duration}\n[episode]\n"
            f'control_rate = {args.rate}\narm = "{arm_name}"\n',
            encoding="utf-8",
        )
        cfg = load_config(config_file)
        for policy in args.policies:
            both: list[tuple[dict[str, float], dict[str, float]]] = []
            for seed in args.seeds:
                spec = EpisodeSpec(policy, TrajectoryKind.NOISY, CONTROL_POINTS, seed)
                local = run_episode(cfg, spec)
                remote, robot_line = over_link(config_file, cfg, spec)
                a, b = errors(local), errors(remote.result)
                both.append((a, b))
                m = remote.steps
                dpos = np.linalg.norm(
                    remote.result.log.T_world_cam[:m, :3, 3] - local.log.T_world_cam[:m, :3, 3],
                    axis=1,
                )
                name = f"{arm_name} {policy} seed {seed} {m}"
                print(f"{name} | {_cells(a, b)} | {dpos.max() * 1e3:.3g}", flush=True)
                if remote.lost:
                    print(f"  link lost: {remote.lost}", flush=True)
                print(f"  {robot_line}", flush=True)
            if len(both) > 1:
                a = {k: float(np.mean([x[0][k] for x in both])) for k in both[0][0]}
                b = {k: float(np.mean([x[1][k] for x in both])) for k in both[0][0]}
                print(f"{arm_name} {policy} mean of {len(both)} | {_cells(a, b)} |", flush=True)


if __name__ == "__main__":
    main()
