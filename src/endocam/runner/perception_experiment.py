"""``endocam experiment perception``: the stereo estimator alone on rendered pairs (issue 26).

The ``endocam`` tracker's episodes on the paper's six paths (the ideal set and the study's
three paths) on the free camera and on the PSM give the camera and ring poses (on truth);
``frames`` pairs spread evenly over the twelve episodes from ``SKIP_S`` on are rendered at the
config's size (both eyes, the arm and the instruments drawn) and estimated as rendered and
through the image model (``ImageModelConfig()``; blur from the ring's image velocity in each
eye, highlights on the ring's rim; seeded per pair). Per pair: the distance, the viewing angle
(the line of sight from the rig to the ring centre against the ring's normal, up to sign), the
occluded fraction (of the ring's core circle, the larger over the eyes: out of the image or
hidden by anything but the ring, by ray casts), and each condition's centre and normal errors.

Written into ``--out``: ``pairs.csv`` (one row per pair and condition), ``report.json`` (per
condition: errors where the ring is at least half visible in both eyes, estimate share, wild
estimates, reasons, time per pair) and ``errors.png`` (the errors against distance, angle and
occluded fraction). ``bench/perception_estimator.py`` runs the same with the stress variants.
"""

from __future__ import annotations

import collections
import csv
import json
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from endocam.camera import Eye
from endocam.config import ExperimentConfig
from endocam.perception.estimator import RingEstimate, RingModel, estimate_ring_detail
from endocam.perception.image_model import ImageModelConfig, degrade
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeResult, run_episode
from endocam.runner.experiments import paper_paths
from endocam.runner.outputs import atomic_dir, json_safe

POLICY = "endocam"
CARRIERS = (ArmKind.FREE, ArmKind.PSM)
RIM_POINTS = 24  # points on the core circle for the visible fraction
HALF = 0.5  # visible fraction in both eyes that makes a pair count for the targets
WILD_M = 20e-3  # m, an estimate off by more than this is wild (issue 26)
WILD_RAD = math.radians(45.0)  # rad, likewise for the normal
SKIP_S = 1.0  # s, pairs before this (the camera settling from its start) are not sampled
IMAGE_SEED = 0  # seeds the image model: pair i uses default_rng((IMAGE_SEED, i))
DEFAULT_FRAMES = 300  # pairs: ~1 min on the shared 2-core machine
CONDITIONS = ("rendered", "image_model")
Stress = Mapping[str, tuple[ImageModelConfig, float | None]]
"""Extra conditions: name → (image model, blur speed along the image's x, px/s, or None for
the ring's own image velocity)."""


def eye_images(left: np.ndarray, right: np.ndarray) -> tuple[tuple[Eye, np.ndarray], ...]:
    """The two eyes' names with their images."""
    return (("left", left), ("right", right))


def rim_points(T_world_ring: np.ndarray, radius: float) -> np.ndarray:
    """(RIM_POINTS, 3) world points on the ring's core circle of ``radius`` m, m."""
    phi = np.linspace(0.0, 2.0 * math.pi, RIM_POINTS, endpoint=False)
    local = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.zeros_like(phi)], 1)
    return local @ T_world_ring[:3, :3].T + T_world_ring[:3, 3]


def visible_fraction(scene: Any, T_world_cam: np.ndarray, pts: np.ndarray) -> float:
    """Smaller over the two eyes of the share of ``pts`` (N, 3), m, in the image and not hidden.

    ``scene``: a ``WireChaserScene`` at the pose to test (ray casts skip the ring itself).
    """
    from endocam.sim.scene import GROUP_RING

    shares = []
    for eye in ("left", "right"):
        inside = scene.camera.in_image(T_world_cam, pts, eye)
        seen = [
            bool(ok) and scene.ray_visible(p, T_world_cam, eye, exclude_groups=(GROUP_RING,))
            for p, ok in zip(pts, inside, strict=True)
        ]
        shares.append(float(np.mean(seen)))
    return min(shares)


def tracker_episodes(
    config: ExperimentConfig, progress: Callable[[int], object] | None = None
) -> list[tuple[str, ArmKind, EpisodeResult]]:
    """The tracker's episodes on the paper's six paths, per carrier: (path, carrier, result)."""
    out = []
    for path in paper_paths():
        base = path.config(config)
        for kind in CARRIERS:
            cfg = base.model_copy(update={"episode": base.episode.model_copy(update={"arm": kind})})
            out.append((path.name, kind, run_episode(cfg, path.spec(POLICY))))
            if progress is not None:
                progress(1)
    return out


def pose_errors(est: RingEstimate, p_cam: np.ndarray, n_cam: np.ndarray) -> tuple[float, float]:
    """Centre error (m) and normal error up to sign (rad) of an estimate (camera frame)."""
    ce = float(np.linalg.norm(est.p_cam_ring - p_cam))
    ne = math.acos(min(1.0, abs(float(est.n_cam @ n_cam))))
    return ce, ne


def sample_pairs(
    config: ExperimentConfig,
    runs: list[tuple[str, ArmKind, EpisodeResult]],
    per_run: int,
    stress: Stress | None = None,
    progress: Callable[[int], object] | None = None,
) -> list[dict[str, Any]]:
    """Render ``per_run`` pairs of each run and estimate them; one dict per pair.

    Keys: ``path``, ``carrier``, ``t_s``, ``distance_mm``, ``view_angle_deg``,
    ``occluded_fraction``, ``blur_px`` (the left eye's), and per condition (``CONDITIONS``
    and ``stress``'s names) ``<c>_centre_mm``, ``<c>_normal_deg`` (None without an estimate),
    ``<c>_status``, ``<c>_wall_ms``, ``<c>_cpu_ms``.
    """
    import cv2

    from endocam.sim.render import WireChaserScene

    cv2.setNumThreads(1)
    camera = config.camera.stereo()
    model = RingModel.from_task(config.task, camera)
    image_cfg = ImageModelConfig()
    scenes = {kind: WireChaserScene(config.task, camera, arm=kind) for kind in CARRIERS}
    rows: list[dict[str, Any]] = []
    try:
        for name, kind, res in runs:
            scene, log = scenes[kind], res.log
            dt = float(log.t[1] - log.t[0])
            first = int(np.searchsorted(log.t, SKIP_S))
            for k in np.linspace(first, len(log.t) - 2, per_run).astype(int):
                T_cam, T_ring = log.T_world_cam[k], log.T_world_ring[k]
                scene.set_ring_pose(T_ring)
                scene.set_psm2_tip(log.p_world_tips[k, 1])
                scene.set_camera_pose(T_cam)
                scene.set_arm_from_log(log, k)
                left, right = scene.render("left"), scene.render("right")
                p_cam = T_cam[:3, :3].T @ (T_ring[:3, 3] - T_cam[:3, 3])
                n_cam = T_cam[:3, :3].T @ T_ring[:3, 2]
                rim = rim_points(T_ring, config.task.ring.major_radius)
                sight = p_cam / np.linalg.norm(p_cam)
                row: dict[str, Any] = {
                    "path": name,
                    "carrier": kind.value,
                    "t_s": float(log.t[k]),
                    "distance_mm": float(np.linalg.norm(p_cam)) * 1e3,
                    "view_angle_deg": math.degrees(math.acos(min(1.0, abs(float(sight @ n_cam))))),
                    "occluded_fraction": 1.0 - visible_fraction(scene, T_cam, rim),
                }
                rng = np.random.default_rng((IMAGE_SEED, len(rows)))
                pairs = {"rendered": (left, right)}
                velocities: dict[Eye, np.ndarray] = {}
                sites: dict[Eye, np.ndarray] = {}
                degraded = []
                for eye, img in eye_images(left, right):
                    uv0 = camera.project(T_cam, T_ring[:3, 3], eye)
                    uv1 = camera.project(
                        log.T_world_cam[k + 1], log.T_world_ring[k + 1, :3, 3], eye
                    )
                    ok = np.all(np.isfinite(uv0 + uv1))
                    velocities[eye] = (uv1 - uv0) / dt if ok else np.zeros(2)
                    uv = camera.project(T_cam, rim, eye)
                    sites[eye] = uv[np.all(np.isfinite(uv), axis=1)]
                    degraded.append(degrade(img, image_cfg, rng, velocities[eye], sites[eye]))
                row["blur_px"] = float(np.hypot(*velocities["left"])) * image_cfg.exposure
                pairs["image_model"] = (degraded[0], degraded[1])
                for label, (cfg_s, speed) in (stress or {}).items():
                    srng = np.random.default_rng((IMAGE_SEED, len(rows), 1))
                    stressed = []
                    for eye, img in eye_images(left, right):
                        vel = velocities[eye] if speed is None else np.array([speed, 0.0])
                        stressed.append(degrade(img, cfg_s, srng, vel, sites[eye]))
                    pairs[label] = (stressed[0], stressed[1])
                for label, (a, b) in pairs.items():
                    t0, c0 = time.perf_counter(), time.thread_time()
                    out = estimate_ring_detail(a, b, model)
                    row[label + "_wall_ms"] = (time.perf_counter() - t0) * 1e3
                    row[label + "_cpu_ms"] = (time.thread_time() - c0) * 1e3
                    row[label + "_status"] = out.status.value
                    err = None if out.estimate is None else pose_errors(out.estimate, p_cam, n_cam)
                    row[label + "_centre_mm"] = None if err is None else err[0] * 1e3
                    row[label + "_normal_deg"] = None if err is None else math.degrees(err[1])
                rows.append(row)
                if progress is not None:
                    progress(1)
    finally:
        for scene in scenes.values():
            scene.close()
    return rows


def summarise(rows: list[dict[str, Any]], key: str) -> dict[str, Any]:
    """The report of one condition ``key`` over ``rows`` (see :func:`sample_pairs`).

    Errors (median, p95, max) and the estimate share over the pairs at least ``HALF`` visible
    in both eyes; wild estimates (> 20 mm or > 45°) over all pairs; the reasons for missing
    estimates; the time per pair (median wall and thread CPU, ms).
    """
    half = [r for r in rows if 1.0 - r["occluded_fraction"] >= HALF]
    got = [r for r in half if r[key + "_centre_mm"] is not None]
    ce = np.array([r[key + "_centre_mm"] for r in got], dtype=float)
    ne = np.array([r[key + "_normal_deg"] for r in got], dtype=float)
    wild = sum(
        1
        for r in rows
        if r[key + "_centre_mm"] is not None
        and (
            r[key + "_centre_mm"] > WILD_M * 1e3 or r[key + "_normal_deg"] > math.degrees(WILD_RAD)
        )
    )
    reasons = collections.Counter(r[key + "_status"] for r in half if r[key + "_centre_mm"] is None)

    def q(a: np.ndarray, p: float) -> float | None:
        return float(np.percentile(a, p)) if len(a) else None

    wall = np.array([r[key + "_wall_ms"] for r in rows], dtype=float)
    cpu = np.array([r[key + "_cpu_ms"] for r in rows], dtype=float)
    return {
        "pairs": len(rows),
        "half_visible_pairs": len(half),
        "estimate_share": len(got) / max(len(half), 1),
        "center_error_mm": {"median": q(ce, 50), "p95": q(ce, 95), "max": q(ce, 100)},
        "normal_error_deg": {"median": q(ne, 50), "p95": q(ne, 95), "max": q(ne, 100)},
        "wild_estimates_all_pairs": wild,
        "estimates_all_pairs": sum(1 for r in rows if r[key + "_centre_mm"] is not None),
        "missing_reasons": dict(reasons),
        "time_per_pair_ms": {
            "median_wall": q(wall, 50),
            "median_cpu": q(cpu, 50),
        },
    }


def plot_errors(rows: list[dict[str, Any]], path: Path) -> None:
    """``errors.png``: the errors against distance, viewing angle and occluded fraction.

    Centre (mm) and normal (deg) errors, both conditions (no estimate: not drawn).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_x = (
        ("distance_mm", "distance (mm)"),
        ("view_angle_deg", "viewing angle (deg)"),
        ("occluded_fraction", "occluded fraction"),
    )
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharey="row")
    for col, (xkey, xlabel) in enumerate(axes_x):
        for row_i, (suffix, ylabel) in enumerate(
            (("_centre_mm", "centre error (mm)"), ("_normal_deg", "normal error (deg)"))
        ):
            ax = axes[row_i, col]
            for cond, colour in zip(CONDITIONS, ("tab:blue", "tab:orange"), strict=True):
                pts = [(r[xkey], r[cond + suffix]) for r in rows if r[cond + suffix] is not None]
                if pts:
                    x, y = np.array(pts, dtype=float).T
                    ax.scatter(x, y, s=8, alpha=0.6, color=colour, label=cond.replace("_", " "))
            ax.set_yscale("log")
            ax.grid(True, alpha=0.3)
            if row_i == 1:
                ax.set_xlabel(xlabel)
            if col == 0:
                ax.set_ylabel(ylabel)
    axes[0, 0].legend(loc="upper left")
    fig.suptitle("Stereo estimator on rendered pairs (the tracker's episodes, paper's six paths)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_pairs_csv(rows: list[dict[str, Any]], path: Path) -> None:
    """``pairs.csv``: one row per pair and condition (errors empty without an estimate)."""
    fields = ["path", "carrier", "t_s", "distance_mm", "view_angle_deg", "occluded_fraction"]
    keys = [k.removesuffix("_status") for k in rows[0] if k.endswith("_status")] if rows else []
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                *fields,
                *("blur_px", "condition", "status", "center_error_mm", "normal_error_deg"),
                *("wall_ms", "cpu_ms"),
            ]
        )
        for r in rows:
            for c in keys:
                centre, normal = r[c + "_centre_mm"], r[c + "_normal_deg"]
                w.writerow(
                    [r[f] for f in fields]
                    + [r["blur_px"], c, r[c + "_status"]]
                    + ["" if centre is None else centre, "" if normal is None else normal]
                    + [r[c + "_wall_ms"], r[c + "_cpu_ms"]]
                )


def report_table(report: Mapping[str, Any]) -> str:
    """A Markdown table of :func:`summarise`'s reports, one row per condition."""

    def f(x: float | None, digits: int = 2) -> str:
        return "–" if x is None else f"{x:.{digits}f}"

    lines = [
        "| condition | pairs ≥ half visible | with an estimate | centre median / p95 / max (mm) "
        "| normal median / p95 / max (deg) | wild | time per pair, median (wall / CPU, ms) |",
        "|---|---|---|---|---|---|---|",
    ]
    for cond, s in report.items():
        c, n, t = s["center_error_mm"], s["normal_error_deg"], s["time_per_pair_ms"]
        lines.append(
            f"| {cond} | {s['half_visible_pairs']} | {100 * s['estimate_share']:.1f} % "
            f"| {f(c['median'])} / {f(c['p95'])} / {f(c['max'])} "
            f"| {f(n['median'], 1)} / {f(n['p95'], 1)} / {f(n['max'], 1)} "
            f"| {s['wild_estimates_all_pairs']} "
            f"| {f(t['median_wall'], 1)} / {f(t['median_cpu'], 1)} |"
        )
    return "\n".join(lines)


def run_perception_experiment(config: ExperimentConfig, out_dir: Path, frames: int) -> str:
    """Run the experiment (module docstring) with ``frames`` pairs; returns the Markdown table.

    Writes ``pairs.csv``, ``report.json``, ``report.md`` and ``errors.png`` into ``out_dir``
    (replaced atomically). Raises ``ValueError`` for fewer pairs than episodes.
    """
    from endocam.progress import progress_bar

    runs_n = len(paper_paths()) * len(CARRIERS)
    if frames < runs_n:
        raise ValueError(f"--frames must be at least {runs_n} (one per episode), got {frames}")
    per_run = math.ceil(frames / runs_n)
    with atomic_dir(Path(out_dir)) as tmp:
        with progress_bar(total=runs_n, desc="episodes", unit="episode") as bar:
            runs = tracker_episodes(config, bar.update)
        with progress_bar(total=per_run * runs_n, desc="pairs", unit="pair") as bar:
            rows = sample_pairs(config, runs, per_run, progress=bar.update)
        report = {c: summarise(rows, c) for c in CONDITIONS}
        table = report_table(report)
        write_pairs_csv(rows, tmp / "pairs.csv")
        (tmp / "report.json").write_text(
            json.dumps(json_safe({"report": report, "pairs": len(rows)}), indent=2),
            encoding="utf-8",
        )
        (tmp / "report.md").write_text(table + "\n", encoding="utf-8")
        plot_errors(rows, tmp / "errors.png")
    return table
