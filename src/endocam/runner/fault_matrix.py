"""``endocam experiment faults``: the fault matrix, and whether the camera stays safe through it.

The orientation camera (condition III, played by the ``endocam`` controller) runs one noisy
trajectory (:data:`MATRIX_PATH`, :data:`MATRIX_DURATION_S` long) on the free camera and on the
PSM: once without faults (the reference), then with each fault of :mod:`endocam.faults` alone
at two severities (:data:`SEVERITIES`; the ring outlier also 1, 2 and 5 cm off and turned 5°
and 15°, :data:`SMALL_OUTLIERS`), then with all of them at once (``high``). Arm faults
(a stalled joint, a goal beyond reach) run on the PSM only.

Written (atomically)::

    <carrier>-<fault>-<severity>/   each episode as ``endocam run`` writes it (no video), with
                                    the fault column in episode.csv and check.json
    faults.json   {"rows": [{"fault", "severity", "carrier", "episode", "violations", ...}]}
    faults.md     the table
    faults.html   the same, for a browser

Per row: the safety check's violations (the target: zero everywhere), the time the camera took
to recover after each burst ended (back within :data:`~endocam.runner.tracking.ARRIVED_M` and
:data:`~endocam.runner.tracking.ARRIVED_RAD` of the reference run's camera at the same time),
and the tracking errors beside the reference's.
"""

from __future__ import annotations

import concurrent.futures
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from endocam.config import ExperimentConfig
from endocam.faults import ARM_FAULTS, FAULT_NAMES, FaultsConfig, fault_names
from endocam.progress import progress_bar
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode
from endocam.runner.experiments import CONDITION_POLICY
from endocam.runner.outputs import (
    atomic_dir,
    fmt,
    json_safe,
    render_template,
    write_json,
    write_run,
    written_check,
)
from endocam.runner.pool import DEFAULT_WORKERS, executor
from endocam.runner.tracking import ARRIVED_M, ARRIVED_RAD
from endocam.task.trajectory import TrajectoryKind

POLICY = CONDITION_POLICY["orientation"]  # the orientation camera: condition III
CARRIERS = (ArmKind.FREE, ArmKind.PSM)
MATRIX_PATH = (TrajectoryKind.NOISY, 36, 1)  # kind, control points, seed
MATRIX_DURATION_S = 20.0  # s: the ring's trip (3× the paper's pace; keeps the matrix < 5 min)
FAULTS_SEED = 7  # seed of every row's fault schedule
NONE, ALL = "none", "all"
# Each fault at two severities: the section of FaultsConfig that switches it on.
SEVERITIES: dict[str, dict[str, dict[str, float]]] = {
    "low": {
        "ring_dropout": {"rate": 0.2, "burst": 0.1},
        "ring_nan": {"rate": 0.2, "burst": 0.05},
        "ring_inf": {"rate": 0.2, "burst": 0.05},
        "ring_outlier": {"rate": 0.2, "burst": 0.05, "distance": 0.1, "angle": math.pi / 2},
        "tracker_frozen": {"rate": 0.2, "burst": 0.2},
        "latency_spike": {"rate": 0.2, "burst": 0.2, "extra_delay": 0.1},
        "tip_dropout": {"rate": 0.2, "burst": 0.5},
        "step_overrun": {"rate": 1.0, "burst": 0.01},
        "joint_stall": {"rate": 0.1, "burst": 0.2},
        "goal_beyond_reach": {"rate": 0.1, "burst": 0.1, "overshoot": 0.1},
    },
    "high": {
        "ring_dropout": {"rate": 0.5, "burst": 0.5},
        "ring_nan": {"rate": 1.0, "burst": 0.2},
        "ring_inf": {"rate": 1.0, "burst": 0.2},
        "ring_outlier": {"rate": 0.5, "burst": 0.3, "distance": 1.0, "angle": math.pi},
        "tracker_frozen": {"rate": 0.5, "burst": 1.0},
        "latency_spike": {"rate": 0.5, "burst": 0.5, "extra_delay": 0.3},
        "tip_dropout": {"rate": 0.5, "burst": 2.0},
        "step_overrun": {"rate": 5.0, "burst": 0.05},
        "joint_stall": {"rate": 0.3, "burst": 0.5},
        "goal_beyond_reach": {"rate": 0.3, "burst": 0.3, "overshoot": 0.5},
    },
}
# Small ring outliers beside the large ones: each alone, as often and as long as the high
# severity's (a tracker locked onto a nearby feature), a centre offset or a turned normal.
SMALL_OUTLIERS: dict[str, dict[str, float]] = {
    "1cm": {"rate": 0.5, "burst": 0.3, "distance": 0.01, "angle": 0.0},
    "2cm": {"rate": 0.5, "burst": 0.3, "distance": 0.02, "angle": 0.0},
    "5cm": {"rate": 0.5, "burst": 0.3, "distance": 0.05, "angle": 0.0},
    "5deg": {"rate": 0.5, "burst": 0.3, "distance": 0.0, "angle": math.radians(5.0)},
    "15deg": {"rate": 0.5, "burst": 0.3, "distance": 0.0, "angle": math.radians(15.0)},
}
FAULTS_JSON = "faults.json"
FAULTS_MD = "faults.md"
FAULTS_HTML = "faults.html"


def matrix_rows(carriers: Sequence[ArmKind] = CARRIERS) -> list[tuple[ArmKind, str, str]]:
    """(carrier, fault, severity) of every row: the reference, each fault, all at once.

    Each fault at both :data:`SEVERITIES`, the ring outlier also at each of
    :data:`SMALL_OUTLIERS`.
    """
    rows = []
    for carrier in carriers:
        rows.append((carrier, NONE, ""))
        for fault in FAULT_NAMES:
            if fault in ARM_FAULTS and carrier is ArmKind.FREE:
                continue
            rows += [(carrier, fault, sev) for sev in SEVERITIES]
            if fault == "ring_outlier":
                rows += [(carrier, fault, sev) for sev in SMALL_OUTLIERS]
        rows.append((carrier, ALL, "high"))
    return rows


def row_faults(fault: str, severity: str) -> FaultsConfig:
    """The faults section of one row."""
    if fault == NONE:
        return FaultsConfig()
    names = FAULT_NAMES if fault == ALL else (fault,)
    data: dict[str, Any] = {"seed": FAULTS_SEED}
    if severity in SMALL_OUTLIERS:
        data["ring_outlier"] = SMALL_OUTLIERS[severity]
    else:
        data.update({name: SEVERITIES[severity][name] for name in names})
    return FaultsConfig.model_validate(data)


def folder(carrier: ArmKind, fault: str, severity: str) -> str:
    """``<carrier>-<fault>[-<severity>]``."""
    return "-".join(p for p in (carrier.value, fault, severity) if p)


def matrix_config(
    config: ExperimentConfig, carrier: ArmKind, faults: FaultsConfig
) -> ExperimentConfig:
    """``config`` on the matrix's trajectory length, ``carrier`` and ``faults`` (validated)."""
    data = config.model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = MATRIX_DURATION_S
    data["episode"]["arm"] = carrier.value
    data["faults"] = faults.model_dump(mode="json")
    return ExperimentConfig.model_validate(data)


def _episode(
    config: ExperimentConfig, carrier: ArmKind, fault: str, severity: str, out_dir: Path
) -> dict[str, Any]:
    """Run and write one row's episode (in a worker); returns its per-step summary."""
    cfg = matrix_config(config, carrier, row_faults(fault, severity))
    kind, points, seed = MATRIX_PATH
    result = run_episode(cfg, EpisodeSpec(POLICY, kind, points, seed))
    write_run(result, out_dir, video=False)
    return _summary(result, written_check(out_dir))


def _summary(result: EpisodeResult, check: dict[str, Any]) -> dict[str, Any]:
    log = result.log
    return {
        "violations": int(check["violations"]),
        "counts": check["counts"],
        "t": log.t,
        "T_world_cam": log.T_world_cam,
        "fault": log.fault if log.fault is not None else np.full(len(log.t), "", dtype=object),
        "image_error_px": float(np.mean(result.image_error_saturated)),
        "center_error_mm": 1e3 * float(np.mean(result.center_error)),
        "orientation_error_deg": math.degrees(float(np.mean(result.orientation_error))),
        "lost_fraction": float(np.mean(log.state == "lost_tracking")),
    }


def recovery_times(
    t: np.ndarray, fault: np.ndarray, T_world_cam: np.ndarray, T_world_ref: np.ndarray
) -> list[float]:
    """Time from the end of each fault burst until the camera is back with the reference, s.

    Parameters
    ----------
    t : (N,)
        Time, s.
    fault : (N,)
        The ``fault`` column.
    T_world_cam, T_world_ref : (N, 4, 4)
        The camera with faults and without (the reference run), m.

    Returns
    -------
    list of float
        One per burst end (a step with a fault followed by one without that fault); ``inf``
        when the camera was not back by the end of the episode.
    """
    gap = np.linalg.norm(T_world_cam[:, :3, 3] - T_world_ref[:, :3, 3], axis=1)
    cos = np.einsum("ni,ni->n", T_world_cam[:, :3, 2], T_world_ref[:, :3, 2])
    back = (gap <= ARRIVED_M) & (cos >= math.cos(ARRIVED_RAD))
    names = [fault_names(f) for f in fault]
    times = []
    for k in range(len(t) - 1):
        for _ended in names[k] - names[k + 1]:
            after = np.flatnonzero(back[k + 1 :])
            times.append(float(t[k + 1 + after[0]] - t[k + 1]) if len(after) else math.inf)
    return times


def run_fault_matrix(
    config: ExperimentConfig,
    out_dir: Path,
    *,
    workers: int = DEFAULT_WORKERS,
    carriers: Sequence[ArmKind] = CARRIERS,
) -> str:
    """Run the fault matrix and write its folder atomically; returns the Markdown table.

    Parameters
    ----------
    config : ExperimentConfig
        Everything but the trajectory length, the carrier and the faults (set per row).
    out_dir : Path
        Output folder, replaced when everything is written.
    workers : int
        Worker processes (1: run in this process).
    carriers : sequence of ArmKind
        The carriers (default: free and PSM).
    """
    if workers < 1:
        raise ValueError(f"workers must be ≥ 1, got {workers}")
    jobs = matrix_rows(carriers)
    done: dict[str, dict[str, Any]] = {}
    with atomic_dir(Path(out_dir)) as tmp:
        bar = progress_bar(total=len(jobs), desc="fault matrix", unit="episode")
        with bar, executor(workers) as pool:
            futures = {
                pool.submit(_episode, config, c, f, s, tmp / folder(c, f, s)): folder(c, f, s)
                for c, f, s in jobs
            }
            for fut in concurrent.futures.as_completed(futures):
                done[futures[fut]] = fut.result()
                bar.update(1)
        rows = []
        for c, f, s in jobs:
            ep, ref = done[folder(c, f, s)], done[folder(c, NONE, "")]
            rec = recovery_times(ep["t"], ep["fault"], ep["T_world_cam"], ref["T_world_cam"])
            finite = [r for r in rec if math.isfinite(r)]
            row: dict[str, Any] = {
                "fault": f,
                "severity": s,
                "carrier": c.value,
                "episode": folder(c, f, s),
                "violations": ep["violations"],
                "violation_counts": ep["counts"],
                "bursts": len(rec),
                "recover_s_mean": float(np.mean(finite)) if finite else None,
                "recover_s_max": float(max(rec)) if rec else None,
                "not_recovered": len(rec) - len(finite),
                "lost_fraction": ep["lost_fraction"],
            }
            for key in ("image_error_px", "center_error_mm", "orientation_error_deg"):
                row[key] = ep[key]
                row[f"reference_{key}"] = ref[key]
            rows.append(row)
        write_json(tmp / FAULTS_JSON, json_safe({"policy": POLICY, "rows": rows}))
        table = fault_table(rows)
        (tmp / FAULTS_MD).write_text(table + "\n", encoding="utf-8")
        html = render_template(
            "faults.html",
            rows=rows,
            policy=POLICY,
            duration=MATRIX_DURATION_S,
            path=MATRIX_PATH,
            severities=SEVERITIES,
            small_outliers=SMALL_OUTLIERS,
            total=sum(r["violations"] for r in rows),
            arrived_mm=ARRIVED_M * 1e3,
            arrived_deg=math.degrees(ARRIVED_RAD),
        )
        (tmp / FAULTS_HTML).write_text(html, encoding="utf-8")
    return table


def _seconds(x: float | None) -> str:
    if x is None:
        return "–"
    return "never" if not math.isfinite(x) else f"{x:.2f}"


def fault_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown: per row the violations, recovery times and errors beside the reference's."""
    lines = [
        "| carrier | fault | severity | violations | bursts | recovery mean / max (s) "
        "| lost (%) | image (px) | 3D (mm) | orientation (deg) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['carrier']} | {r['fault']} | {r['severity'] or '–'} | {r['violations']} | "
            f"{r['bursts']} | {_seconds(r['recover_s_mean'])} / {_seconds(r['recover_s_max'])} | "
            f"{fmt(100 * r['lost_fraction'], 1)} | "
            f"{fmt(r['image_error_px'], 1)} ({fmt(r['reference_image_error_px'], 1)}) | "
            f"{fmt(r['center_error_mm'])} ({fmt(r['reference_center_error_mm'])}) | "
            f"{fmt(r['orientation_error_deg'])} ({fmt(r['reference_orientation_error_deg'])}) |"
        )
    return "\n".join(lines)
