"""The three policies on a synthetic ring motion, without the simulator: writes a plot.

The ring circles while its normal tilts; an ideal camera follows every command. The plot shows
each policy's orientation error, the quantity the paper's method is designed to drive to zero.
Run: .venv/bin/python examples/02_controller_demo.py [OUT.png]
"""

from __future__ import annotations

import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import endocam
from endocam.geometry import make_pose

DT = 0.01  # s, control period
DURATION = 10.0  # s


def ring_pose(t: float) -> np.ndarray:
    """Ring on a 2 cm circle, its normal tilting 40° about a rotating horizontal axis."""
    p = [0.02 * math.cos(0.5 * t), 0.02 * math.sin(0.5 * t), 0.04]
    n = np.array(
        [math.sin(0.7) * math.cos(0.8 * t), math.sin(0.7) * math.sin(0.8 * t), math.cos(0.7)]
    )
    x = np.cross([0.0, 0.0, 1.0], n)
    x /= np.linalg.norm(x)
    return make_pose(np.column_stack([x, np.cross(n, x), n]), p)


def main(out: str) -> None:
    camera = endocam.StereoCamera()
    ts = np.arange(0.0, DURATION, DT)
    T0 = endocam.look_at_pose([0.0, -0.12, 0.15], [0.0, 0.0, 0.04])
    config = endocam.ControllerConfig(cone_height=0.5, cone_base_radius=0.5)
    fig, ax = plt.subplots(figsize=(7, 3.5), layout="constrained")
    for name in ("fixed", "centering", "orientation"):  # the paper's three conditions
        policy = endocam.make_policy(name, config)
        policy.reset(endocam.PolicyContext(camera, T0, ring_pose(0.0), np.array([0, 0, 0.3]), DT))
        T_cam, errors = T0, []
        for t in ts:
            ring = ring_pose(t)
            T_cam = policy.step(endocam.Observation(t, ring, T_cam)).T_world_cam
            errors.append(np.degrees(endocam.orientation_error(T_cam, ring[:3, 2])[0]))
        ax.plot(ts, errors, label=name)
        print(f"{name:12s} mean orientation error {np.mean(errors[100:]):6.2f} deg")
    ax.set_xlabel("Time (s)")
    ax.set_ylabel("Orientation error (deg)")
    ax.legend()
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "controller_demo.png")
