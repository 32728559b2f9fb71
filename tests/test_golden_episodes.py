"""The same config and seed give the same ``episode.csv`` and ``metrics.json`` as stored.

The stored logs (``tests/data/golden_episodes.json``, written by ``tests/golden.py``) were made
before the layout refactor; any change of behaviour shows up here as a named column and step.
"""

from __future__ import annotations

import json
import math

import pytest

from golden import GOLDEN_PATH, GOLDEN_RUNS, GOLDEN_STRIDE, record, run_name

# Float round-off between library versions is far below these; a behaviour change is far above.
ATOL_M = 1e-9  # m, positions and clearances
ATOL_MM = 1e-6  # mm, columns in millimetres
ATOL_RAD = 1e-9  # rad, joint angles and quaternion components (unitless)
ATOL_DEG = 1e-6  # deg
ATOL_PX = 1e-5  # px


def _tolerance(column: str) -> float:
    if column.endswith("_mm"):
        return ATOL_MM
    if column.endswith("_deg"):
        return ATOL_DEG
    if column.endswith("_px"):
        return ATOL_PX
    return max(ATOL_M, ATOL_RAD)


STORED = json.loads(GOLDEN_PATH.read_text(encoding="utf-8"))


@pytest.mark.parametrize("run", GOLDEN_RUNS, ids=run_name)
def test_episode_matches_stored_log(run: tuple[str, str, str, int, int]) -> None:
    stored = STORED[run_name(run)]
    fresh = record(run)
    assert sorted(fresh["columns"]) == sorted(stored["columns"]), "episode.csv columns changed"
    for column, values in stored["columns"].items():
        new = fresh["columns"][column]
        assert len(new) == len(values), column
        for i, (a, b) in enumerate(zip(values, new, strict=True)):
            step = i * GOLDEN_STRIDE
            if isinstance(a, float) and isinstance(b, float):
                assert math.isclose(a, b, rel_tol=0.0, abs_tol=_tolerance(column)), (
                    f"{column} at step {step}: stored {a}, now {b}"
                )
            else:
                assert a == b, f"{column} at step {step}: stored {a!r}, now {b!r}"
    _compare(stored["metrics"], fresh["metrics"], "metrics")


def _compare(a: object, b: object, where: str) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and sorted(a) == sorted(b), where
        for key in a:
            _compare(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, float) and isinstance(b, float):
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=ATOL_PX), f"{where}: {a} != {b}"
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"
