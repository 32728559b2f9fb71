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


def k_conditions(k: int) -> tuple[str, ...]:
    """``k`` condition names: the tiny study's three, then ``extra4``, ``extra5``, ..."""
    return (*CONDITIONS, *(f"extra{i}" for i in range(4, k + 1)))[:k]


def manifest_dict(conditions: tuple[str, ...] = CONDITIONS) -> dict:
    """Manifest of the tiny study: ids v01..v09 (v01..v{3k} for k conditions), condition-major.

    A condition beyond the third reuses the true touches of the third.
    """
    videos = []
    for c_index, condition in enumerate(conditions):
        for t_index, (name, difficulty, touches) in enumerate(TRAJECTORIES):
            number = 3 * c_index + t_index + 1
            videos.append(
                {
                    "id": f"v{number:02d}",
                    "condition": condition,
                    "trajectory": name,
                    "difficulty": difficulty,
                    "true_touches": touches[min(c_index, len(touches) - 1)],
                    "file": f"videos/v{number:02d}.mp4",
                }
            )
    return {
        "endocam_version": "0.1.0",
        "created": "2024-05-01T12:00:00+00:00",
        "conditions": list(conditions),
        "videos": videos,
        "orders": [list(order) for order in presentation_orders(conditions)],
        "attention": {"question": "To show you are paying attention, enter four.", "answer": 4},
    }


PRACTICE_TOUCHES = 3  # true touches of the tiny study's practice video


def make_study(
    root: Path,
    with_videos: bool = True,
    *,
    practice: bool = False,
    name: str = "study",
    conditions: tuple[str, ...] = CONDITIONS,
    stub_videos: bool = False,
    **fields: Any,
) -> Path:
    """Create a study folder ``root/name``; returns its path.

    ``practice`` adds ``videos/practice.mp4`` as the practice video; ``conditions`` names the
    study's conditions (orders: their Williams design); ``stub_videos`` writes a few bytes per
    video file instead of an mp4 (the app only checks that the files exist; cheap for tests
    that never play them); ``fields`` are further manifest fields (e.g.
    ``shuffle_within_set=False``, ``demographics=True``).
    """
    study = root / name
    (study / "videos").mkdir(parents=True)
    manifest = manifest_dict(conditions) | fields
    if practice:
        manifest["practice"] = {"file": "videos/practice.mp4", "true_touches": PRACTICE_TOUCHES}
        write_tiny_mp4(study / "videos" / "practice.mp4", 200)
    (study / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    if with_videos:
        for i, video in enumerate(manifest["videos"]):
            if stub_videos:
                (study / video["file"]).write_bytes(b"not a video")
            else:
                write_tiny_mp4(study / video["file"], 20 * i)
    return study
