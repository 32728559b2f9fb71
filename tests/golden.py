"""Stored small episode logs: the refactor-safety net for ``episode.csv`` and ``metrics.json``.

``tests/data/golden_episodes.json`` holds, for a few short episodes (every carrier and policy),
every ``GOLDEN_STRIDE``-th row of ``episode.csv`` and the scalar summaries of ``metrics.json``.
``test_golden_episodes.py`` reruns them and compares: the world's columns exactly, the camera's
behaviour through the episode's summaries within named tolerances. A deliberate change of
behaviour (a new world or controller) regenerates the file with ``python tests/golden.py`` and
says why in the commit; a refactor must stay within the tolerances.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from endocam.config import ExperimentConfig
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.outputs import episode_columns, metrics_dict
from endocam.task.trajectory import TrajectoryKind

GOLDEN_PATH = Path(__file__).parent / "data" / "golden_episodes.json"
GOLDEN_STRIDE = 25  # count: every 25th control step is stored
GOLDEN_DURATION_S = 10.0  # s: short episodes keep the test fast
# (policy, arm, trajectory, control points, seed)
GOLDEN_RUNS: tuple[tuple[str, str, str, int, int], ...] = (
    ("orientation", "free", "noisy", 36, 1),
    ("orientation", "psm", "noisy", 36, 1),
    ("centering", "psm", "ideal", 36, 0),
    ("orientation-ecm", "ecm", "ideal", 36, 0),
    ("fixed", "free", "ideal", 36, 0),
    ("endocam", "free", "noisy", 36, 1),
    ("endocam", "psm", "noisy", 36, 1),
)


def run_name(run: tuple[str, str, str, int, int]) -> str:
    """Key of one golden run."""
    policy, arm, kind, n, seed = run
    return f"{policy}-{arm}-{kind}-{n}-s{seed}"


def golden_config(arm: str) -> ExperimentConfig:
    """The default config with a short trajectory and the given carrier."""
    data = ExperimentConfig().model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = GOLDEN_DURATION_S
    data["episode"]["arm"] = arm
    return ExperimentConfig.model_validate(data)


def _plain(value: Any) -> Any:
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    return str(value) if isinstance(value, np.str_) else value


def record(run: tuple[str, str, str, int, int]) -> dict[str, Any]:
    """Rows of ``episode.csv`` (every ``GOLDEN_STRIDE``-th) and metric summaries of one run."""
    policy, arm, kind, n, seed = run
    result = run_episode(golden_config(arm), EpisodeSpec(policy, TrajectoryKind(kind), n, seed))
    cols = episode_columns(result)
    rows = {name: [_plain(v) for v in col[::GOLDEN_STRIDE]] for name, col in cols.items()}
    m = metrics_dict(result)
    summary = {
        key: m[key] for key in ("image_error_px", "center_error_mm", "orientation_error_deg")
    }
    summary["ring_out_of_view_fraction"] = m["ring_out_of_view_fraction"]
    summary["touches"] = m["touches"]
    summary["state_fractions"] = m["state_fractions"]
    return {"columns": rows, "metrics": json.loads(json.dumps(summary))}


def main() -> int:
    """Regenerate the stored logs."""
    data: dict[str, Any] = {run_name(r): record(r) for r in GOLDEN_RUNS}
    GOLDEN_PATH.write_text(json.dumps(data, indent=None, sort_keys=True) + "\n", encoding="utf-8")
    print(f"wrote {GOLDEN_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
