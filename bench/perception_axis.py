"""The estimator's normal error against the view angle off the ring's normal, clean renders.

The ring at ``--distance`` mm, the camera turned off its normal by each angle in six directions,
rendered at the loop's size (640x480, no image model) and estimated three ways: the eyes'
ellipses alone (``plane_tilt`` ~0), the disparity plane alone
(:func:`endocam.perception.disparity.plane_normal` on the estimate's core ellipses), and the
blend (the defaults). Prints the normal error's median / max (deg) per angle and the
estimator's median wall time per pair.

Run (about 20 s on one core):
  MUJOCO_GL=egl OMP_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python bench/perception_axis.py \\
      [--distance 55]
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from endocam.config import CameraConfig
from endocam.perception.disparity import plane_normal
from endocam.perception.ellipse import core_ellipse, normalised_conic
from endocam.perception.estimator import EstimatorConfig, RingModel, estimate_ring_detail
from endocam.sim.render import WireChaserScene
from endocam.task.config import TaskConfig
from endocam.view import look_at_pose

os.environ.setdefault("MUJOCO_GL", "egl")
ANGLES_DEG = (0, 1, 2, 3, 5, 7, 10, 20, 35, 50)
DIRECTIONS = 6  # directions of the tilt per angle
P_WORLD_RING = np.array([-0.06, -0.045, 0.05])  # m, 6 cm in front of the wire
R_WORLD_RING = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # normal -y
ELLIPSES_ONLY = EstimatorConfig(plane_tilt=1e-9)  # rad: the plane's weight sin² ~ 1e-18


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between unit vectors up to sign, deg."""
    return math.degrees(math.acos(min(1.0, abs(float(a @ b)))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--distance", type=float, default=55.0, help="camera to ring, mm")
    args = parser.parse_args()
    task = TaskConfig()
    camera = CameraConfig().stereo()
    model = RingModel.from_task(task, camera)
    scene = WireChaserScene(task, camera)
    T_ring = np.eye(4)
    T_ring[:3, :3], T_ring[:3, 3] = R_WORLD_RING, P_WORLD_RING
    n_world = R_WORLD_RING[:, 2]
    side_a, side_b = R_WORLD_RING[:, 0], R_WORLD_RING[:, 1]
    tube_m = task.ring.minor_radius
    print("angle | ellipses median / max | plane alone | blended | ms per pair (blended)")
    for angle_deg in ANGLES_DEG:
        errs: dict[str, list[float]] = {"ellipses": [], "plane": [], "blended": []}
        times = []
        for az in np.linspace(0.0, 2.0 * math.pi, DIRECTIONS, endpoint=False):
            a = math.radians(angle_deg)
            sight = math.cos(a) * n_world + math.sin(a) * (
                math.cos(az) * side_a + math.sin(az) * side_b
            )
            T_cam = look_at_pose(P_WORLD_RING + 1e-3 * args.distance * sight, P_WORLD_RING)
            scene.set_ring_pose(T_ring)
            scene.set_camera_pose(T_cam)
            left, right = scene.render("left"), scene.render("right")
            n_cam = T_cam[:3, :3].T @ n_world
            old = estimate_ring_detail(left, right, model, ELLIPSES_ONLY).estimate
            t0 = time.perf_counter()
            new = estimate_ring_detail(left, right, model).estimate
            times.append(time.perf_counter() - t0)
            if old is None or new is None:
                continue
            errs["ellipses"].append(_angle_deg(old.n_cam, n_cam))
            errs["blended"].append(_angle_deg(new.n_cam, n_cam))
            K = camera.intrinsics.K
            half = np.array([0.5 * camera.baseline, 0.0, 0.0])  # the eyes at ∓B/2 along x
            cores = [
                core_ellipse(f, K, tube_m, new.p_cam_ring + s * half, new.n_cam)
                for f, s in ((new.left, 1.0), (new.right, -1.0))
            ]
            if cores[0] is None or cores[1] is None:
                continue
            n_plane = plane_normal(*(normalised_conic(c, K) for c in cores))
            if n_plane is not None:
                errs["plane"].append(_angle_deg(n_plane, n_cam))
        cells = [f"{np.median(e):5.2f} / {np.max(e):5.2f}" if e else "--" for e in errs.values()]
        print(f"{angle_deg:3d}° | " + " | ".join(cells) + f" | {1e3 * np.median(times):.1f}")
    scene.close()


if __name__ == "__main__":
    main()
