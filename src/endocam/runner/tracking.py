"""``endocam experiment tracking``: the standard tracking protocol, controllers × carriers × paths.

Every controller (``paper`` = the registered ``orientation`` policy, ``endocam``, ``centering``,
``oracle``, ``endocam-visible``: its tilt off the normal, for the view of the touch, shows as its
orientation error) runs on every carrier (``free``, ``psm``) over the same trajectories:

* the **ideal** set: the ideal path with 36, 54 and 71 control points (as ``experiment paper``);
* the **noisy** set: the three study trajectories (``t1-36-low``, ``t2-36-high``,
  ``t3-71-high``, seeded from the study's default seed), plus ``--seeds N`` extra noisy
  71-point trajectories (seeds 1..N).

Written (atomically)::

    <controller>-<carrier>-<trajectory>/   scene.json, episode.csv, metrics.json (no video)
    tracking.json   {"rows": [...]}: per controller × carrier × set, means over its episodes
    tracking.md     the table, with the paper's Sec. V figures and the ratio to the oracle
    tracking.html   the same, with the plots
    image_error.png, center_error.png, orientation_error.png, out_of_view.png

**Phases** (from the logged ``state`` column and poses, :data:`PHASES`): *approach* runs from
t = 0 until the first step in plain ``tracking`` at which the camera has arrived at its command
(within ``ARRIVED_M`` and ``ARRIVED_RAD``): the camera's way from its start view to its first
goal, whatever the controller calls that stretch (way-points, or a direct move logged as
tracking); after it, each step's phase is its state: ``tracking``
→ *tracking*, ``planning`` (way-points, side-change orbits) → *transfer*,
``frozen_outside_cone`` → *frozen*, ``lost_tracking`` → *lost*, ``unreachable`` (the arm concedes
the goal) → *unreachable*, ``blocked`` (the arm's workspace guard braked: no admissible motion
towards the command) → *blocked*, ``holding`` → *holding*.

Rows average the episode means (each episode weighs the same, as the paper averages its three
trials); a phase's errors average the means of the episodes that have that phase.
"""

from __future__ import annotations

import concurrent.futures
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from endocam.config import ExperimentConfig
from endocam.geometry import FloatArray, so3_log
from endocam.progress import progress_bar
from endocam.robot.actuator import ArmKind
from endocam.robot.arm import ECM_MAX_VELOCITY, PSM_MAX_VELOCITY
from endocam.runner.episode import BLOCKED, UNREACHABLE, EpisodeResult, EpisodeSpec, run_episode
from endocam.runner.experiments import PAPER_MEANS, PathSpec, paper_paths
from endocam.runner.outputs import (
    PLOT_DPI,
    atomic_dir,
    fmt,
    json_safe,
    metrics_dict,
    render_template,
    write_json,
    write_run,
    written_check,
)
from endocam.runner.pool import DEFAULT_WORKERS, executor
from endocam.task.touches import TouchReport, touch_events
from endocam.task.trajectory import make_trajectory
from endocam.task.wire import Wire

CONTROLLERS = {"paper": "orientation", "endocam": "endocam", "centering": "centering"}
CONTROLLERS["oracle"] = "oracle"
CONTROLLERS["endocam-visible"] = "endocam-visible"  # turned to show the touch: its tilt costs
"""Controller name in the protocol → registered policy name."""
DEFAULT_CONTROLLERS = ("paper", "endocam", "centering", "oracle", "endocam-visible")
DEFAULT_CARRIERS = (ArmKind.FREE.value, ArmKind.PSM.value)
SETS = ("ideal", "noisy")
PHASES = ("approach", "tracking", "transfer", "frozen", "lost", "unreachable", "blocked", "holding")
_STATE_PHASE = {
    "tracking": "tracking",
    "planning": "transfer",
    "frozen_outside_cone": "frozen",
    "lost_tracking": "lost",
    UNREACHABLE: "unreachable",
    BLOCKED: "blocked",
    "holding": "holding",
}
ERRORS = (  # key in rows, label, PNG
    ("image_error_px", "Image centring error, left eye (px)", "image_error.png"),
    ("center_error_mm", "3D centring error, left eye (mm)", "center_error.png"),
    ("orientation_error_deg", "Orientation error (deg)", "orientation_error.png"),
    ("ring_out_of_view_fraction", "Ring out of view (fraction of time)", "out_of_view.png"),
)
TRACKING_JSON = "tracking.json"
TRACKING_MD = "tracking.md"
TRACKING_HTML = "tracking.html"


ARRIVED_M = 5e-3  # m: a camera this close to its command has arrived (the approach ends)
ARRIVED_RAD = math.radians(5.0)  # rad: and its optical axis this close to the command's


tracking_paths = paper_paths  # the protocol's trajectories (runner.experiments)


def episode_phases(
    state: np.ndarray, T_world_cam: FloatArray | None = None, T_world_cmd: FloatArray | None = None
) -> np.ndarray:
    """(N,) phase name of every control step (see the module docstring).

    Parameters
    ----------
    state : (N,)
        The log's ``state`` column.
    T_world_cam, T_world_cmd : (N, 4, 4), optional
        Logged camera and commanded poses, world, m; without them the approach ends at the
        first plain ``tracking`` step.
    """
    state = np.asarray(state).astype(str)
    phase = np.array([_STATE_PHASE.get(s, s) for s in state], dtype=object)
    arrived = state == "tracking"
    if T_world_cam is not None and T_world_cmd is not None:
        gap = np.linalg.norm(T_world_cam[:, :3, 3] - T_world_cmd[:, :3, 3], axis=1)
        cos = np.einsum("ni,ni->n", T_world_cam[:, :3, 2], T_world_cmd[:, :3, 2])
        arrived &= (gap < ARRIVED_M) & (cos > math.cos(ARRIVED_RAD))
    hits = np.flatnonzero(arrived)
    first = int(hits[0]) if len(hits) else len(state)
    phase[:first] = "approach"
    return phase.astype(str)


def episode_summary(result: EpisodeResult) -> dict[str, Any]:
    """Means of one episode (the ``metrics.json`` means) and its errors by phase."""
    m = metrics_dict(result)
    phase = episode_phases(result.log.state, result.log.T_world_cam, result.log.T_world_cmd)
    img = result.image_error_saturated
    by_phase: dict[str, Any] = {}
    for name in PHASES:
        mask = phase == name
        if not mask.any():
            continue
        by_phase[name] = {
            "fraction": float(np.mean(mask)),
            "image_error_px": _mean(img[mask]),
            "center_error_mm": 1e3 * _mean(result.center_error[mask]),
            "orientation_error_deg": math.degrees(_mean(result.orientation_error[mask])),
        }
    return {
        "image_error_px": m["image_error_px"]["mean"],
        "center_error_mm": m["center_error_mm"]["mean"],
        "center_error_mid_mm": 1e3 * _mean(result.center_error_mid),
        "orientation_error_deg": m["orientation_error_deg"]["mean"],
        "ring_out_of_view_fraction": m["ring_out_of_view_fraction"],
        "speed_ratio": speed_ratio(result),
        "by_phase": by_phase,
    }


def speed_ratio(result: EpisodeResult) -> float:
    """Largest speed between logged steps over its limit (≤ 1: the carrier's limits held).

    Free camera: the larger of the linear speed over ``max_linear_speed`` and the rotation
    rate over ``max_angular_speed`` (``MotionLimits``); a camera on an arm: the largest joint
    speed over its dVRK velocity limit (``robot.arm``). Unitless.
    """
    log = result.log
    dt = 1.0 / result.config.episode.control_rate
    if log.joints is not None and len(log.joint_names) > 0:
        vmax = np.array(PSM_MAX_VELOCITY if log.arm == ArmKind.PSM.value else ECM_MAX_VELOCITY)
        qd = np.abs(np.diff(log.joints, axis=0)) / dt
        return float(np.max(qd / vmax)) if len(qd) else 0.0
    lim = result.config.episode.limits
    T = log.T_world_cam
    v = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1) / dt
    R_rel = np.einsum("nji,njk->nik", T[:-1, :3, :3], T[1:, :3, :3])  # R_k^T R_k+1
    w = np.linalg.norm(so3_log(R_rel), axis=1) / dt if len(R_rel) else np.zeros(0)
    if not len(v):
        return 0.0
    return float(max(np.max(v) / lim.max_linear_speed, np.max(w) / lim.max_angular_speed))


def _mean(values: np.ndarray) -> float:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else math.nan


def _touches(config: ExperimentConfig, path: PathSpec) -> TouchReport:
    cfg = path.config(config)
    wire = Wire(cfg.task.wire)
    traj = make_trajectory(cfg.task, path.kind, path.control_points, path.seed, wire=wire)
    return touch_events(traj, wire, cfg.task.ring, cfg.task.trajectory.touch_sample_dt)


def _episode(
    config: ExperimentConfig,
    path: PathSpec,
    controller: str,
    carrier: str,
    touches: TouchReport,
    out_dir: Path,
) -> dict[str, Any]:
    """Run and write one episode (in a worker process); returns its summary."""
    cfg = path.config(config)
    episode = cfg.episode.model_copy(update={"arm": ArmKind(carrier)})
    cfg = cfg.model_copy(update={"episode": episode})
    spec = EpisodeSpec(CONTROLLERS[controller], path.kind, path.control_points, path.seed)
    result = run_episode(cfg, spec, touches=touches)
    write_run(result, out_dir, video=False)
    summary = episode_summary(result)
    summary["violations"] = written_check(out_dir)["violations"]
    return summary


def folder_name(controller: str, carrier: str, path: PathSpec) -> str:
    """``<controller>-<carrier>-<trajectory>``."""
    return f"{controller}-{carrier}-{path.name}"


def check_choices(controllers: Sequence[str], carriers: Sequence[str]) -> None:
    """Raise ``ValueError`` (one line) for unknown, repeated or missing names."""
    for what, names, known in (
        ("controller", controllers, list(CONTROLLERS)),
        ("carrier", carriers, list(DEFAULT_CARRIERS)),
    ):
        if not names:
            raise ValueError(f"no {what} given; choose from: {', '.join(known)}")
        for name in names:
            if name not in known:
                raise ValueError(f"unknown {what} {name!r}; choose from: {', '.join(known)}")
        if len(set(names)) != len(names):
            raise ValueError(f"{what}s repeated: {', '.join(names)}")


def run_tracking_experiment(
    config: ExperimentConfig,
    out_dir: Path,
    *,
    controllers: Sequence[str] = DEFAULT_CONTROLLERS,
    carriers: Sequence[str] = DEFAULT_CARRIERS,
    extra_seeds: int = 0,
    workers: int = DEFAULT_WORKERS,
    paths: Sequence[PathSpec] | None = None,
) -> str:
    """Run the protocol, write its folder atomically; returns the Markdown table.

    Parameters
    ----------
    config : ExperimentConfig
        Everything but the carrier (set per episode) and the noise overrides of the paths.
    out_dir : Path
        Output folder, replaced when everything is written.
    controllers, carriers : sequence of str
        Names from :data:`CONTROLLERS` and :data:`DEFAULT_CARRIERS`.
    extra_seeds : int
        Extra noisy 71-point trajectories (≥ 0).
    workers : int
        Worker processes (1: run in this process).
    paths : sequence of PathSpec, optional
        Replace the protocol's trajectories (tests).
    """
    check_choices(controllers, carriers)
    if workers < 1:
        raise ValueError(f"workers must be ≥ 1, got {workers}")
    paths = list(paths) if paths is not None else paper_paths(extra_seeds)
    jobs = [(c, a, p) for p in paths for a in carriers for c in controllers]
    summaries: dict[str, dict[str, Any]] = {}
    with atomic_dir(Path(out_dir)) as tmp:
        bar = progress_bar(total=len(paths) + len(jobs), desc="episodes", unit="job")
        with bar, executor(workers) as pool:
            touch_futures = {p.name: pool.submit(_touches, config, p) for p in paths}
            futures = {}
            for p in paths:
                touches = touch_futures[p.name].result()
                bar.update(1)
                for c, a, q in jobs:
                    if q is p:
                        name = folder_name(c, a, p)
                        futures[pool.submit(_episode, config, p, c, a, touches, tmp / name)] = name
            for fut in concurrent.futures.as_completed(futures):
                summaries[futures[fut]] = fut.result()
                bar.update(1)
        rows = tracking_rows(summaries, controllers, carriers, paths)
        write_json(tmp / TRACKING_JSON, json_safe({"phases": list(PHASES), "rows": rows}))
        table = tracking_table(rows)
        (tmp / TRACKING_MD).write_text(table + "\n", encoding="utf-8")
        for key, label, png in ERRORS:
            plot_errors(rows, key, label, tmp / png)
        html = render_template(
            "tracking.html",
            rows=rows,
            ratios=[_ratios(rows, r) for r in rows],
            paper=PAPER_MEANS,
            phases=PHASES,
            plots=[(label, png) for _, label, png in ERRORS],
            n_paths={s: sum(p.set == s for p in paths) for s in SETS},
            duration=config.task.trajectory.duration,
            violations=sum(r["violations"] for r in rows),
            speed_ratios=[
                (c, max(r["speed_ratio"] for r in rows if r["carrier"] == c))
                for c in dict.fromkeys(r["carrier"] for r in rows)
            ],
        )
        (tmp / TRACKING_HTML).write_text(html, encoding="utf-8")
    return table


_ROW_KEYS = (
    "image_error_px",
    "center_error_mm",
    "center_error_mid_mm",
    "orientation_error_deg",
    "ring_out_of_view_fraction",
)


def tracking_rows(
    summaries: dict[str, dict[str, Any]],
    controllers: Sequence[str],
    carriers: Sequence[str],
    paths: Sequence[PathSpec],
) -> list[dict[str, Any]]:
    """One row per controller × carrier × set: means over the set's episodes, and by phase."""
    rows = []
    for carrier in carriers:
        for set_ in SETS:
            group = [p for p in paths if p.set == set_]
            if not group:
                continue
            for controller in controllers:
                names = [folder_name(controller, carrier, p) for p in group]
                eps = [summaries[n] for n in names]
                row: dict[str, Any] = {"controller": controller, "carrier": carrier, "set": set_}
                for key in _ROW_KEYS:
                    row[key] = _mean(np.array([e[key] for e in eps], dtype=float))
                row["episodes"] = names
                row["speed_ratio"] = float(max(e["speed_ratio"] for e in eps))
                row["violations"] = int(sum(e.get("violations", 0) for e in eps))
                by_phase = {}
                for phase in PHASES:
                    have = [e["by_phase"][phase] for e in eps if phase in e["by_phase"]]
                    fractions = [e["by_phase"].get(phase, {}).get("fraction", 0.0) for e in eps]
                    entry: dict[str, Any] = {"fraction": float(np.mean(fractions))}
                    entry["episodes"] = len(have)
                    for key in ("image_error_px", "center_error_mm", "orientation_error_deg"):
                        entry[key] = _mean(np.array([h[key] for h in have], dtype=float))
                    by_phase[phase] = entry
                row["by_phase"] = by_phase
                rows.append(row)
    return rows


def _ratios(rows: Sequence[dict[str, Any]], row: dict[str, Any]) -> dict[str, float | None]:
    """The row's errors divided by the oracle's (same carrier and set); ``None`` without one."""
    ref = next(
        (
            r
            for r in rows
            if r["controller"] == "oracle"
            and r["carrier"] == row["carrier"]
            and r["set"] == row["set"]
        ),
        None,
    )
    out: dict[str, float | None] = {}
    for key in _ROW_KEYS:
        a = row[key]
        b = ref[key] if ref is not None else None
        ok = b is not None and a is not None and math.isfinite(a) and math.isfinite(b) and b > 0
        out[key] = a / b if ok else None
    return out


def tracking_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown: the means with the ratio to the oracle, the paper's figures, and the phases."""

    def cell(row: dict[str, Any], key: str, digits: int, scale: float = 1.0) -> str:
        v = row[key]
        text = fmt(v * scale if v is not None else None, digits)
        r = _ratios(rows, row)[key]
        return f"{text} (×{r:.2f})" if r is not None else text

    lines = [
        "| controller | carrier | set | image error (px) | 3D error, left eye (mm) "
        "| 3D error, mid (mm) | orientation error (deg) | ring out of view (%) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for set_ in SETS:
        for row in (r for r in rows if r["set"] == set_):
            lines.append(
                f"| {row['controller']} | {row['carrier']} | {set_} | "
                f"{cell(row, 'image_error_px', 1)} | {cell(row, 'center_error_mm', 2)} | "
                f"{cell(row, 'center_error_mid_mm', 2)} | "
                f"{cell(row, 'orientation_error_deg', 2)} | "
                f"{cell(row, 'ring_out_of_view_fraction', 1, 100.0)} |"
            )
        if any(r["set"] == set_ for r in rows):
            img, mm, deg = PAPER_MEANS[set_]
            lines.append(
                f"| paper, Sec. V | – | {set_} | {img:.0f} | {mm:.2f} | – | {deg:.2f} | – |"
            )
    lines += [
        "",
        "(×r): ratio to the oracle on the same carrier and set (the non-causal reference with "
        "perfect information; a bound only for controllers of endocam's design).",
        "",
        "Largest speed between logged steps over the carrier's limit (free camera: linear and "
        "angular speed; arm: joint speeds), over every episode: "
        + ", ".join(
            f"{c} {max(r['speed_ratio'] for r in rows if r['carrier'] == c):.3f}"
            for c in dict.fromkeys(r["carrier"] for r in rows)
        )
        + " (≤ 1: the limits held).",
        "",
        "| controller | carrier | set | "
        + " | ".join(f"{p}: time %, px / mm / deg" for p in PHASES if _any_phase(rows, p))
        + " |",
        "|---|---|---|" + "---|" * sum(_any_phase(rows, p) for p in PHASES),
    ]
    for row in rows:
        cells = []
        for phase in PHASES:
            if not _any_phase(rows, phase):
                continue
            e = row["by_phase"][phase]
            if e["episodes"]:
                cells.append(
                    f"{100 * e['fraction']:.1f} %, {fmt(e['image_error_px'], 1)} / "
                    f"{fmt(e['center_error_mm'])} / {fmt(e['orientation_error_deg'])}"
                )
            else:
                cells.append("–")
        lines.append(
            f"| {row['controller']} | {row['carrier']} | {row['set']} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines)


def _any_phase(rows: Sequence[dict[str, Any]], phase: str) -> bool:
    return any(r["by_phase"][phase]["episodes"] for r in rows)


DISPLAY = {"paper": "paper-faithful controller"}  # legend names where the key reads ambiguously


def plot_errors(rows: Sequence[dict[str, Any]], key: str, label: str, path: Path) -> None:
    """Bars of one error: groups carrier × set, one bar per controller; the paper as a tick."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    groups = list(dict.fromkeys((r["carrier"], r["set"]) for r in rows))
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    fig = Figure(figsize=(8.0, 4.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    width = 0.8 / max(1, len(controllers))
    x = np.arange(len(groups), dtype=float)
    for i, c in enumerate(controllers):
        values = []
        for g in groups:
            row = next(
                (r for r in rows if r["controller"] == c and (r["carrier"], r["set"]) == g), None
            )
            v = row[key] if row is not None else None
            values.append(math.nan if v is None else v)
        bars = ax.bar(x - 0.4 + (i + 0.5) * width, values, width, label=DISPLAY.get(c, c))
        ax.bar_label(bars, fmt="%.1f", fontsize=7, padding=1)
    paper_index = {"image_error_px": 0, "center_error_mm": 1, "orientation_error_deg": 2}
    if key in paper_index:
        for j, (_, set_) in enumerate(groups):
            y = PAPER_MEANS[set_][paper_index[key]]
            ax.hlines(
                y,
                j - 0.45,
                j + 0.45,
                colors="k",
                linestyles="--",
                lw=1.0,
                label="the paper's figure (Sec. V)" if j == 0 else "_nolegend_",
            )
    ax.set_xticks(x, [f"{a}\n{s}" for a, s in groups])
    ax.set_ylabel(label)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=PLOT_DPI, format="png")
