"""The figures of docs/perception.md: the segmentation and the estimated pose over two frames.

Two 640x480 left-eye frames of the ring on the ideal 36-point path, the wire through it: a clear
oblique view, and a view with the wire in front of part of the rim, degraded by the image model
(blur, a brightness change, highlights on the rim, noise). Each figure is a crop around the ring,
shown twice as large: left, the segmentation (ring pixels white, wire pixels cyan); right, the
fit and the estimate (silhouette points white, fitted outline green, estimated core circle
magenta, normal cyan), with the errors against the truth in the title bar.

Run:
  MUJOCO_GL=egl PYTHONPATH=src .venv/bin/python bench/perception_frames.py [--out docs/img]
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import cv2
import numpy as np

from endocam.config import ExperimentConfig
from endocam.perception import RingModel, estimate_ring_detail, segment
from endocam.perception.estimator import draw_estimate
from endocam.perception.image_model import ImageModelConfig, degrade
from endocam.sim.render import WireChaserScene
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.view import look_at_pose

os.environ.setdefault("MUJOCO_GL", "egl")
CROP = (180, 120)  # px, the crop around the ring per panel
ZOOM = 2  # the crops are shown this many times larger (nearest pixel)
DISTANCE = 0.055  # m, camera to ring


def camera_pose(T_ring: np.ndarray, side: float) -> np.ndarray:
    """A camera DISTANCE away, its line of sight ``side`` (unitless) off the ring's normal."""
    n = T_ring[:3, 2]
    s = np.cross(n, [0.0, 0.0, 1.0])
    sight = n + side * s / np.linalg.norm(s)
    return look_at_pose(T_ring[:3, 3] + DISTANCE * sight / np.linalg.norm(sight), T_ring[:3, 3])


def panel(image: np.ndarray, centre: np.ndarray) -> tuple[int, int]:
    """Top-left corner of the CROP around ``centre`` (u, v), inside the image."""
    h, w = image.shape[:2]
    u0 = int(np.clip(centre[0] - CROP[0] / 2, 0, w - CROP[0]))
    v0 = int(np.clip(centre[1] - CROP[1] / 2, 0, h - CROP[1]))
    return u0, v0


def figure(
    left: np.ndarray, right: np.ndarray, model: RingModel, p_cam: np.ndarray, n_cam: np.ndarray
) -> np.ndarray:
    """The two panels side by side with a title bar (H, 2W, 3) uint8 RGB."""
    ring, wire = segment(left, model.keys)
    seg = left.copy()
    seg[wire] = (0.5 * seg[wire] + 0.5 * np.array([0, 255, 255])).astype(np.uint8)
    seg[ring] = (255, 255, 255)
    res = estimate_ring_detail(left, right, model)
    if res.estimate is None:
        raise SystemExit(f"no estimate for this frame ({res.status.value})")
    est = res.estimate
    drawn = draw_estimate(left, est, model)
    centre_err = float(np.linalg.norm(est.p_cam_ring - p_cam)) * 1e3
    normal_err = math.degrees(math.acos(min(1.0, abs(float(est.n_cam @ n_cam)))))
    u0, v0 = panel(left, est.left.centre)
    crops = [img[v0 : v0 + CROP[1], u0 : u0 + CROP[0]] for img in (seg, drawn)]
    out = np.hstack(crops).repeat(ZOOM, axis=0).repeat(ZOOM, axis=1)
    bar = np.full((22, out.shape[1], 3), 255, np.uint8)
    text = f"centre error {centre_err:.2f} mm, normal error {normal_err:.1f} deg"
    cv2.putText(bar, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([bar, out])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img", help="folder for the PNGs")
    args = parser.parse_args()
    config = ExperimentConfig()
    camera = config.camera.stereo()
    model = RingModel.from_task(config.task, camera)
    traj = make_trajectory(config.task, TrajectoryKind.IDEAL, 36, 0)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    with WireChaserScene(config.task, camera) as scene:
        for name, t, side, degraded in (
            ("perception_clear.png", 12.0, 0.6, False),
            ("perception_wire_degraded.png", 20.0, 0.35, True),
        ):
            T_ring = traj.pose(t)
            T_cam = camera_pose(T_ring, side)
            scene.set_ring_pose(T_ring)
            scene.set_camera_pose(T_cam)
            pair = [scene.render("left"), scene.render("right")]
            if degraded:
                phi = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
                R = config.task.ring.major_radius + config.task.ring.minor_radius
                rim = T_ring[:3, 3] + R * (
                    np.outer(np.cos(phi), T_ring[:3, 0]) + np.outer(np.sin(phi), T_ring[:3, 1])
                )
                pair = [
                    degrade(
                        img, ImageModelConfig(), rng, (150.0, 60.0), camera.project(T_cam, rim, eye)
                    )
                    for img, eye in zip(pair, ("left", "right"), strict=True)
                ]
            p_cam = T_cam[:3, :3].T @ (T_ring[:3, 3] - T_cam[:3, 3])
            n_cam = T_cam[:3, :3].T @ T_ring[:3, 2]
            img = figure(pair[0], pair[1], model, p_cam, n_cam)
            bgr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
            cv2.imwrite(str(out / name), bgr, [cv2.IMWRITE_PNG_COMPRESSION, 9])
            print(f"{out / name}: {(out / name).stat().st_size / 1e3:.0f} kB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
