"""Goal poses of the orientation-aware camera (paper Sec. III-B) for a few ring normals.

Run: .venv/bin/python examples/01_goal_pose.py
"""

from __future__ import annotations

import numpy as np

import endocam

p_c = np.array([0.0, 0.0, 0.05])  # ring centre in world, m
for n in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.2], [0.3, -0.5, 0.8]):
    T_world_cam = endocam.goal_pose(p_c, n, d_f=0.05)
    x, y, z = T_world_cam[:3, 0], T_world_cam[:3, 1], T_world_cam[:3, 2]
    print(f"n = {n}")
    print(f"  camera at {np.round(T_world_cam[:3, 3] * 1e3, 1)} mm, looking along {np.round(z, 3)}")
    print(f"  horizon level: x·up = {x[2]:+.1e}; image upright: y·up = {y[2]:+.3f} ≤ 0")
