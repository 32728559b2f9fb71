"""The loop on perception end to end: a short stereo episode whose camera sees no ring holds.

At 32x24 px the ring is a pixel or two, under the segmentation's smallest component, so no
frame gives an estimate: the controller gets no observation and must hold (lost tracking),
the est_* columns are logged empty, and the safety check stays clean.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from endocam.config import ExperimentConfig
from endocam.runner.episode import EpisodeSpec
from endocam.runner.log_schema import ESTIMATE_COLUMNS
from endocam.task.trajectory import TrajectoryKind


def test_a_stereo_run_that_sees_no_ring_holds_and_logs_empty_estimates(tmp_path: Path) -> None:
    from endocam.runner.experiments import run_and_write

    cfg = ExperimentConfig.model_validate(
        {
            "task": {"trajectory": {"duration": 1.0}},
            "episode": {"arm": "free"},
            "camera": {"width": 32, "height": 24},
            "perception": {"source": "stereo"},
        }
    )
    metrics = run_and_write(
        cfg, EpisodeSpec("endocam", TrajectoryKind.IDEAL, 36), tmp_path, video=False
    )
    assert metrics["check"]["ok"], metrics["check"]
    per = metrics["perception"]
    assert per["frames"] == 31 and per["estimate_share"] == 0.0 and per["delivered"] == 0
    lost = per["lost"]  # and says why: lost all along, no frame found the ring
    assert lost["share"] == 1.0 and lost["stretches"] == 1
    assert lost["longest_s"] == cfg.task.trajectory.duration + 1.0 / cfg.episode.control_rate
    assert lost["frame_status"] == {"no_ring": 31}
    with open(tmp_path / "episode.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert set(ESTIMATE_COLUMNS) <= set(rows[0])
    assert all(r["est_ok"] == "0" and r["est_x"] == "" and r["est_age_s"] == "" for r in rows)
    assert {r["state"] for r in rows} == {"lost_tracking"}  # no observation: the camera holds
    assert len({(r["cam_x"], r["cam_y"], r["cam_z"], r["cam_qw"]) for r in rows}) == 1
    scene = json.loads((tmp_path / "scene.json").read_text(encoding="utf-8"))
    assert scene["log"]["estimates"] is True
