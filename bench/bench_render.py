"""Rendering one eye at 640x480 and ground-truth touches over a default 60 s trajectory.

Run:
  MUJOCO_GL=egl .venv/bin/pytest bench/bench_render.py --benchmark-enable -o addopts="" \
      -p no:cacheprovider
Targets (issue 3): one eye at 640x480 at >= 30 fps (median <= 33 ms) on a 2-core CPU;
touch_events over a 60 s noisy 71-point trajectory in well under a few seconds.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from endocam.camera import StereoCamera
from endocam.sim.render import WireChaserScene
from endocam.task.config import TaskConfig
from endocam.task.layout import overview_camera_pose
from endocam.task.touches import touch_events
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

os.environ.setdefault("MUJOCO_GL", "egl")
CFG = TaskConfig()


@pytest.fixture(scope="module")
def scene():
    s = WireChaserScene(CFG, StereoCamera())
    yield s
    s.close()


@pytest.mark.parametrize("view", ["overview", "goal"])
def test_render_left_eye_640x480(benchmark, scene, view):
    traj = make_trajectory(CFG, TrajectoryKind.NOISY, 71, seed=1)
    T_ring = traj.pose(30.0)
    scene.set_ring_pose(T_ring)
    if view == "overview":
        scene.set_camera_pose(overview_camera_pose(CFG, scene.camera))
    else:
        n = T_ring[:3, 2] * np.sign(T_ring[2, 2])
        x = np.cross(-n, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, np.cross(-n, x), -n])
        T[:3, 3] = T_ring[:3, 3] + 0.06 * n
        scene.set_camera_pose(T)
    img = benchmark(scene.render, "left")
    assert img.shape == (480, 640, 3)
    median = benchmark.stats.stats.median
    benchmark.extra_info["fps"] = 1.0 / median
    print(f"\n{view}: median {median * 1e3:.2f} ms/frame = {1.0 / median:.0f} fps")


@pytest.mark.parametrize(("kind", "n"), [("ideal", 36), ("noisy", 71)])
def test_touch_events_60s(benchmark, kind, n):
    wire = Wire(CFG.wire)
    traj = make_trajectory(CFG, TrajectoryKind(kind), n, seed=1, wire=wire)
    rep = benchmark.pedantic(
        touch_events,
        args=(traj, wire, CFG.ring, CFG.trajectory.touch_sample_dt),
        rounds=3,
        iterations=1,
    )
    assert rep.count >= 0
    print(f"\n{kind} {n}: {rep.count} touches, {rep.t.size} samples")
