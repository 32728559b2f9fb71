"""The fixed camera's view at a touch, and its image scale at the ring (docs/study.md).

Runs the study's fixed-camera episode on ``t3-71-high`` (default config and seed), saves the left
eye's image at the onset of the trajectory's second touch as a PNG, and prints the median image
scale at the touches (px per mm at the contact's depth, ``endocam.study.observability``) and
the share of the task's points inside the image.

    MUJOCO_GL=egl .venv/bin/python examples/fixed_view.py out/fixed_view.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from endocam.config import ExperimentConfig
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.experiments import study_path_config
from endocam.sim.render import WireChaserScene
from endocam.study.make import trajectory_seeds
from endocam.study.observability import observe_episode
from endocam.task.layout import task_points
from endocam.task.study_paths import DEFAULT_STUDY_SEED, STUDY_TRAJECTORIES
from endocam.task.trajectory import TrajectoryKind

PATH = "t3-71-high"
TOUCH = 1  # the second touch (index)


def main(out: Path) -> None:
    """Render and measure the fixed view; write ``out`` (PNG)."""
    i = [t.name for t in STUDY_TRAJECTORIES].index(PATH)
    path = STUDY_TRAJECTORIES[i]
    seed = trajectory_seeds(DEFAULT_STUDY_SEED, len(STUDY_TRAJECTORIES))[i]
    cfg = study_path_config(ExperimentConfig(), path)
    result = run_episode(cfg, EpisodeSpec("fixed", TrajectoryKind.NOISY, path.control_points, seed))
    T_cam = result.log.T_world_cam[0]
    uv = result.camera.project(T_cam, task_points(cfg.task), "left")
    k = result.camera.intrinsics
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < k.width) & (uv[:, 1] >= 0) & (uv[:, 1] < k.height)
    with WireChaserScene(cfg.task, result.camera, arm=cfg.episode.arm) as scene:
        records = observe_episode(
            result, scene, video_id="fixed", condition="fixed", trajectory=PATH
        )
        t = result.touches.events[TOUCH].t_start
        step = round(t * cfg.episode.control_rate)
        scene.set_ring_pose(result.trajectory.pose(t))
        scene.set_psm2_tip(result.log.p_world_tips[step, 1])
        scene.set_camera_pose(result.log.T_world_cam[step])
        image = scene.render("left")
        wire = result.wire.polyline()
        seen = [scene.ray_visible(p, result.log.T_world_cam[step]) for p in wire]
    out.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(out, image)
    scale = np.median([r.px_per_mm for r in records])
    print(f"{out}: touch {TOUCH} at t = {t:.2f} s")
    print(f"task points inside the left image: {inside.mean():.1%}")
    print(f"wire points unoccluded in that image: {np.mean(seen):.1%}; ends: {seen[0]}, {seen[-1]}")
    print(f"median scale at the touches: {scale:.2f} px/mm ({len(records)} touches)")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "out/fixed_view.png"))
