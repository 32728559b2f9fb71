"""The loop on perception end to end: a short stereo episode whose camera sees no ring holds.

At 32x24 px the ring is a pixel or two, under the segmentation's smallest component, so no
frame gives an estimate: the controller gets no observation and must hold (lost tracking),
the est_* columns are logged empty, and the safety check stays clean. With no estimate, every
frame's estimator prior is the setup's registration normal (it never lapses, unlike a last
estimate's): the PSM's far start view needs it to settle its ambiguous pairs, but not to
pick a one-eye pose, which waits for the track.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam.config import ExperimentConfig
from endocam.runner.episode import EpisodeSpec
from endocam.runner.log_schema import ESTIMATE_COLUMNS
from endocam.task.trajectory import TrajectoryKind

PRIOR_ATOL = 1e-12  # unit vector: a quaternion read back from the CSV and rotated, ~10 eps


def test_a_stereo_run_that_sees_no_ring_holds_and_logs_empty_estimates(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from endocam.runner import ring_source
    from endocam.runner.experiments import run_and_write

    priors = []  # the prior each frame's estimate is given, camera frame
    monos = []  # whether each frame may give a one-eye pose
    estimate = ring_source.estimate_ring_detail

    def recording(*args, **kwargs):  # type: ignore[no-untyped-def]
        priors.append(kwargs.get("prior"))
        monos.append(kwargs.get("mono"))
        return estimate(*args, **kwargs)

    monkeypatch.setattr(ring_source, "estimate_ring_detail", recording)
    # a last estimate's prior lapses after a tenth of the run: the registration's must not
    monkeypatch.setattr(ring_source, "PRIOR_MAX_AGE", 0.1)  # s

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
    n_reg = _rotation(rows[0], "ring")[:, 2]  # the registration, world
    R_cam = _rotation(rows[0], "cam")  # the camera holds throughout
    assert len(priors) == per["frames"]
    for prior in priors:  # the registration, to the last frame
        assert prior is not None
        np.testing.assert_allclose(prior, R_cam.T @ n_reg, atol=PRIOR_ATOL)
    assert monos == [False] * per["frames"]  # no track yet: the registration picks no one-eye pose
    scene = json.loads((tmp_path / "scene.json").read_text(encoding="utf-8"))
    assert scene["log"]["estimates"] is True


def _rotation(row: dict[str, str], prefix: str) -> np.ndarray:
    """(3, 3) rotation of a logged ``<prefix>_qw/qx/qy/qz`` quaternion (scalar first)."""
    return Rotation.from_quat([float(row[f"{prefix}_q{c}"]) for c in "xyzw"]).as_matrix()
