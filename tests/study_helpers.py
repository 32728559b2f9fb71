"""Shared helpers for the study tests: a tiny study folder with real mp4 files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import imageio_ffmpeg
import numpy as np

from endocam.study.counterbalance import presentation_orders

CONDITIONS = ("fixed", "centering", "orientation")  # the condition names of studies before round 9
# trajectory name, difficulty, true touches per condition (fixed, centering, orientation)
TRAJECTORIES = (
    ("t1-36-low", 1, (2, 2, 2)),
    ("t2-36-high", 2, (4, 5, 4)),
    ("t3-71-high", 3, (7, 8, 9)),
)
ATTENTION_ANSWER = 4
VIDEO_W_PX, VIDEO_H_PX, VIDEO_FRAMES, VIDEO_FPS = 64, 48, 10, 10


def write_tiny_mp4(path: Path, shade: int) -> None:
    """Write a 64x48, 10-frame H.264 video (a grey level that brightens over time)."""
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (VIDEO_W_PX, VIDEO_H_PX),
        fps=VIDEO_FPS,
        codec="libx264",
        pix_fmt_out="yuv420p",
        macro_block_size=16,
        ffmpeg_log_level="error",
    )
    writer.send(None)
    for i in range(VIDEO_FRAMES):
        frame = np.full((VIDEO_H_PX, VIDEO_W_PX, 3), (shade + 10 * i) % 256, dtype=np.uint8)
        writer.send(frame)
    writer.close()


def manifest_dict() -> dict:
    """Manifest of the tiny study: ids v01..v09, condition-major."""
    videos = []
    for c_index, condition in enumerate(CONDITIONS):
        for t_index, (name, difficulty, touches) in enumerate(TRAJECTORIES):
            number = 3 * c_index + t_index + 1
            videos.append(
                {
                    "id": f"v{number:02d}",
                    "condition": condition,
                    "trajectory": name,
                    "difficulty": difficulty,
                    "true_touches": touches[c_index],
                    "file": f"videos/v{number:02d}.mp4",
                }
            )
    return {
        "endocam_version": "0.1.0",
        "created": "2024-05-01T12:00:00+00:00",
        "conditions": list(CONDITIONS),
        "videos": videos,
        "orders": [list(order) for order in presentation_orders(CONDITIONS)],
        "attention": {"question": "To show you are paying attention, enter four.", "answer": 4},
    }


PRACTICE_TOUCHES = 3  # true touches of the tiny study's practice video


def make_study(
    root: Path,
    with_videos: bool = True,
    *,
    practice: bool = False,
    name: str = "study",
    **fields: Any,
) -> Path:
    """Create a study folder ``root/name``; returns its path.

    ``practice`` adds ``videos/practice.mp4`` as the practice video; ``fields`` are further
    manifest fields (e.g. ``shuffle_within_set=False``, ``demographics=True``).
    """
    study = root / name
    (study / "videos").mkdir(parents=True)
    manifest = manifest_dict() | fields
    if practice:
        manifest["practice"] = {"file": "videos/practice.mp4", "true_touches": PRACTICE_TOUCHES}
        write_tiny_mp4(study / "videos" / "practice.mp4", 200)
    (study / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    if with_videos:
        for i, video in enumerate(manifest["videos"]):
            write_tiny_mp4(study / video["file"], 20 * i)
    return study
