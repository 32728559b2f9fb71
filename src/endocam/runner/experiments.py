"""Whole jobs built from episodes: one run, the three-condition demo and the paper's experiment.

Each job shows progress bars (on stderr), writes its files atomically and returns what it wrote.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from endocam.camera import Eye
from endocam.config import ExperimentConfig
from endocam.progress import progress_bar
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode
from endocam.runner.outputs import (
    CARRIERS,
    METRICS_JSON,
    REPORT_HTML,
    atomic_dir,
    frame_indices,
    json_safe,
    metrics_dict,
    plot_tracking,
    render_template,
    video_writer,
    write_json,
    write_run,
    written_check,
)
from endocam.task.study_paths import (
    DEFAULT_STUDY_SEED,
    STUDY_TRAJECTORIES,
    StudyTrajectory,
    study_task_config,
    study_trajectory_seeds,
)
from endocam.task.touches import TouchReport, touch_events
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

CONDITIONS = ("fixed", "centering", "orientation")
# The paper's conditions I-III and the policy that plays each: condition III is the method,
# played by endocam's controller; the paper-faithful reactive one stays available as the
# policy "orientation" (experiment tracking compares them).
CONDITION_POLICY = {"fixed": "fixed", "centering": "centering", "orientation": "endocam"}
GRID_MP4 = "comparison.mp4"
COMPARISON_PNG = "comparison.png"
# The paper's Sec. V means for the orientation camera: (image px, 3D mm, orientation deg).
PAPER_MEANS = {"ideal": (35.0, 3.41, 5.45), "noisy": (36.0, 3.33, 4.30)}
# Our reading of "three ideal and three noisy trajectories": the deterministic ideal path
# sampled with three control-point counts (a deterministic simulator repeats identical trials
# exactly), and the study's three noisy paths (paper Sec. V: "the same trajectories used in the
# user study"), with the study's default seed.
PAPER_IDEAL_POINTS = (36, 54, 71)


def _bar(total: int, desc: str) -> tqdm:
    return progress_bar(total=total, desc=desc, unit="step", dynamic_ncols=True)


def ground_truth(config: ExperimentConfig, kind: TrajectoryKind, n: int, seed: int) -> TouchReport:
    """Touch events of one trajectory (independent of the camera policy)."""
    wire = Wire(config.task.wire)
    traj = make_trajectory(config.task, kind, n, seed, wire=wire)
    return touch_events(traj, wire, config.task.ring, config.task.trajectory.touch_sample_dt)


def clock_from_first_update(bar: tqdm) -> Callable[[int], object]:
    """``bar.update``, but the bar's clock restarts at the first update.

    An episode's first steps load (or, on first use, compile) its kernels: seconds to tens of
    seconds before the loop runs at its speed. Counted in, they make the bar's rate and time
    left read as a stall (2 steps/s and "35:13" left, for a loop that then runs in 5 s). Those
    first steps still count; the rate and time left are of the steps after them.
    """
    started = False

    def update(n: int) -> object:
        nonlocal started
        if not started:
            started = True
            done = bar.n
            bar.reset()  # tqdm's public way to restart its clock (and its count: restored next)
            return bar.update(done + n)
        return bar.update(n)

    return update


def run_with_progress(
    config: ExperimentConfig, spec: EpisodeSpec, touches: TouchReport | None = None
) -> EpisodeResult:
    """:func:`run_episode` with a progress bar over control steps."""
    steps = math.floor(config.task.trajectory.duration * config.episode.control_rate + 1e-9) + 1
    with _bar(steps, f"{spec.policy} control") as bar:
        return run_episode(config, spec, progress=clock_from_first_update(bar), touches=touches)


def run_and_write(
    config: ExperimentConfig, spec: EpisodeSpec, out_dir: Path, *, video: bool = True
) -> dict[str, Any]:
    """Run one episode and write all its outputs; returns the metrics written."""
    result = run_with_progress(config, spec)
    if video:
        n_frames = len(frame_indices(result))
        with progress_bar(total=n_frames, desc="render", unit="frame") as bar:
            write_run(result, out_dir, video=True, progress=bar.update)
    else:
        write_run(result, out_dir, video=False)
    metrics = dict(json_safe(metrics_dict(result)))
    metrics["check"] = written_check(out_dir)
    return metrics


LABEL_HEIGHT_PX = 32  # px, height of the caption strip above the side-by-side video (even)


def label_strip(labels: Sequence[str], panel_width: int, height: int = LABEL_HEIGHT_PX) -> Any:
    """(height, len(labels)·panel_width, 3) uint8 strip with each label centred on its panel.

    Drawn once with matplotlib (Agg) and stacked above every frame of the side-by-side video.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    width = panel_width * len(labels)
    dpi = 100.0
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="#1d232a")
    canvas = FigureCanvasAgg(fig)
    for j, text in enumerate(labels):
        fig.text(
            (j + 0.5) / len(labels),
            0.5,
            text,
            color="white",
            ha="center",
            va="center",
            fontsize=0.45 * height,
            fontweight="bold",
        )
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[:height, :width, :3])


def render_episodes(
    results: Sequence[EpisodeResult],
    paths: Sequence[Path],
    grid_path: Path | None = None,
    progress: Callable[[int], object] | None = None,
    eye: Eye = "left",
) -> None:
    """Render one eye (default the left) of episodes that share one ring trajectory, in one pass.

    One scene serves all of them: per frame the ring is placed once, then each episode's camera
    (and camera arm, if its log has joints).

    Parameters
    ----------
    results : sequence of EpisodeResult
        Episodes of the same config and trajectory (different policies).
    paths : sequence of Path
        One MP4 per episode.
    grid_path : Path, optional
        Also write the episodes side by side, under a caption strip naming each policy.
    progress : callable, optional
        Called with 1 per rendered frame and episode.
    eye : {"left", "right"}
        The eye filmed (the study's videos: left; its ideal observer's stereo input: right too).
    """
    from endocam.sim.render import WireChaserScene, log_arm

    first = results[0]
    idx = frame_indices(first)
    k = first.camera.intrinsics
    fps = first.config.episode.video_fps
    writers = [video_writer(p, k.width, k.height, fps) for p in paths]
    header = grid = None
    if grid_path is not None:
        header = label_strip([r.spec.policy for r in results], k.width)
        grid = video_writer(grid_path, k.width * len(results), k.height + header.shape[0], fps)
    try:
        arm = next((log_arm(r.log) for r in results if r.log.joints is not None), None)
        with WireChaserScene(first.config.task, first.camera, arm=arm) as scene:
            for i in idx:
                scene.set_ring_pose(first.log.T_world_ring[i])
                scene.set_psm2_tip(first.log.p_world_tips[i, 1])
                frames = []
                for result, writer in zip(results, writers, strict=True):
                    scene.set_camera_pose(result.log.T_world_cam[i])
                    scene.set_arm_from_log(result.log, i)
                    frame = np.ascontiguousarray(scene.render(eye))
                    writer.send(frame)
                    frames.append(frame)
                    if progress is not None:
                        progress(1)
                if grid is not None and header is not None:
                    grid.send(np.ascontiguousarray(np.vstack([header, np.hstack(frames)])))
    finally:
        for w in writers if grid is None else [*writers, grid]:
            w.close()


def render_side_by_side(
    results: Sequence[EpisodeResult], paths: Sequence[Path], grid_path: Path
) -> None:
    """Render every episode's left eye in one pass: one MP4 each plus a side-by-side MP4.

    The side-by-side video carries a caption strip naming each panel's policy.
    """
    total = len(frame_indices(results[0])) * len(results)
    with progress_bar(total=total, desc="render", unit="frame") as bar:
        render_episodes(results, paths, grid_path, bar.update)


def run_demo(
    config: ExperimentConfig,
    out_dir: Path,
    *,
    control_points: int = 71,
    seed: int = 1,
    video: bool = True,
) -> Path:
    """The three camera conditions on one noisy trajectory, with a comparison report."""
    kind = TrajectoryKind.NOISY
    touches = ground_truth(config, kind, control_points, seed)
    results = [
        run_with_progress(
            config, EpisodeSpec(CONDITION_POLICY[name], kind, control_points, seed), touches
        )
        for name in CONDITIONS
    ]
    with atomic_dir(Path(out_dir)) as tmp, tempfile.TemporaryDirectory(dir=tmp) as work:
        rendered = [Path(work) / f"{name}.mp4" for name in CONDITIONS]
        if video:
            render_side_by_side(results, rendered, tmp / GRID_MP4)
        rows = []
        for name, result, mp4 in zip(CONDITIONS, results, rendered, strict=True):
            write_run(result, tmp / name, video=video, prerendered=mp4 if video else None)
            metrics = json_safe(metrics_dict(result))
            metrics["check"] = written_check(tmp / name)
            rows.append((name, metrics))
        plot_tracking(results, list(CONDITIONS), tmp / COMPARISON_PNG)
        summary = {name: _summary(m) for name, m in rows}
        write_json(
            tmp / METRICS_JSON,
            {
                "conditions": summary,
                "touches": touches.count,
                "trajectory": {"kind": kind.value, "control_points": control_points, "seed": seed},
            },
        )
        html = render_template(
            "compare.html",
            rows=rows,
            carrier=CARRIERS[results[-1].log.arm],
            video=GRID_MP4 if video else None,
            plot=COMPARISON_PNG,
            touches=touches.count,
            control_points=control_points,
            seed=seed,
        )
        (tmp / REPORT_HTML).write_text(html, encoding="utf-8")
    return Path(out_dir) / REPORT_HTML


def _summary(metrics: dict[str, Any]) -> dict[str, Any]:
    return {
        key: metrics[key]
        for key in (
            "image_error_px",
            "center_error_mm",
            "orientation_error_deg",
            "ring_out_of_view_fraction",
            "state_fractions",
            "arm",
            "check",
        )
    }


@dataclass(frozen=True)
class NamedEpisode:
    """An episode of an experiment: its folder name, its config and what to run."""

    name: str
    config: ExperimentConfig
    spec: EpisodeSpec


def study_path_config(config: ExperimentConfig, path: StudyTrajectory) -> ExperimentConfig:
    """``config`` with a study path's noise (angular range, legibility) applied, validated."""
    return PathSpec(path.name, "noisy", TrajectoryKind.NOISY, path.control_points, 0, path).config(
        config
    )


EXTRA_NOISY_POINTS = 71  # count: control points of the extra noisy paths (--seeds)


@dataclass(frozen=True)
class PathSpec:
    """One trajectory of the protocol.

    Attributes
    ----------
    name : str
        Folder suffix, e.g. ``ideal-71`` or ``t3-71-high``.
    set : str
        ``ideal`` or ``noisy``.
    kind : TrajectoryKind
    control_points : int
    seed : int
        Noise seed (0 for the ideal path).
    study : StudyTrajectory or None
        The study path this is (its noise overrides apply, :func:`study_task_config`); None:
        the config's noise.
    """

    name: str
    set: str
    kind: TrajectoryKind
    control_points: int
    seed: int
    study: StudyTrajectory | None = None

    def config(self, config: ExperimentConfig) -> ExperimentConfig:
        """``config`` with this path's noise override applied (validated again)."""
        if self.study is None:
            return config
        return config.model_copy(update={"task": study_task_config(config.task, self.study)})

    def spec(self, policy: str) -> EpisodeSpec:
        """The episode of ``policy`` on this path."""
        return EpisodeSpec(policy, self.kind, self.control_points, self.seed)


def paper_paths(extra_seeds: int = 0) -> list[PathSpec]:
    """The paper's trajectories: 3 ideal, the 3 study paths, ``extra_seeds`` noisy 71-point."""
    if extra_seeds < 0:
        raise ValueError(f"extra seeds must be ≥ 0, got {extra_seeds}")
    paths = [
        PathSpec(f"ideal-{n}", "ideal", TrajectoryKind.IDEAL, n, 0) for n in PAPER_IDEAL_POINTS
    ]
    seeds = study_trajectory_seeds(DEFAULT_STUDY_SEED, len(STUDY_TRAJECTORIES))
    for traj, seed in zip(STUDY_TRAJECTORIES, seeds, strict=True):
        paths.append(
            PathSpec(
                traj.name,
                "noisy",
                TrajectoryKind.NOISY,
                traj.control_points,
                seed,
                traj,
            )
        )
    for seed in range(1, extra_seeds + 1):
        paths.append(
            PathSpec(
                f"noisy-{EXTRA_NOISY_POINTS}-s{seed}",
                "noisy",
                TrajectoryKind.NOISY,
                EXTRA_NOISY_POINTS,
                seed,
            )
        )
    return paths


def paper_episodes(config: ExperimentConfig, policy: str = "orientation") -> list[NamedEpisode]:
    """The six episodes of ``endocam experiment paper``: three ideal, the three study paths."""
    return [NamedEpisode(p.name, p.config(config), p.spec(policy)) for p in paper_paths()]


def run_paper_experiment(
    config: ExperimentConfig, out_dir: Path, *, policy: str = "orientation"
) -> str:
    """Three ideal and three noisy trajectories; returns a Markdown table beside the paper's."""
    episodes = paper_episodes(config, policy)
    results = []
    for ep in progress_bar(episodes, desc="episodes", unit="episode"):
        results.append(run_with_progress(ep.config, ep.spec))
    names = {id(r): ep.name for r, ep in zip(results, episodes, strict=True)}
    table_rows: list[dict[str, Any]] = []
    for kind in ("ideal", "noisy"):
        group = [r for r in results if r.spec.trajectory.value == kind]
        img = float(np.mean([np.mean(r.image_error_saturated) for r in group]))
        mm = float(np.mean([np.mean(r.center_error) for r in group])) * 1e3
        deg = float(np.degrees(np.mean([np.mean(r.orientation_error) for r in group])))
        frozen = float(np.mean([np.mean(r.log.state == "frozen_outside_cone") for r in group]))
        planning = float(np.mean([np.mean(r.log.state == "planning") for r in group]))
        tracking = [r.log.state == "tracking" for r in group]
        trk_mm = 1e3 * float(
            np.mean([r.center_error[m].mean() for r, m in zip(group, tracking, strict=True)])
        )
        trk_deg = float(
            np.degrees(
                np.mean(
                    [r.orientation_error[m].mean() for r, m in zip(group, tracking, strict=True)]
                )
            )
        )
        paper = PAPER_MEANS[kind]
        table_rows.append(
            {
                "trajectories": kind,
                "image_error_px": img,
                "center_error_mm": mm,
                "orientation_error_deg": deg,
                "paper_image_error_px": paper[0],
                "paper_center_error_mm": paper[1],
                "paper_orientation_error_deg": paper[2],
                "frozen_fraction": frozen,
                "planning_fraction": planning,
                "tracking_center_error_mm": trk_mm,
                "tracking_orientation_error_deg": trk_deg,
                "runs": [names[id(r)] for r in group],
            }
        )
    table = paper_table(table_rows, policy)
    with atomic_dir(Path(out_dir)) as tmp:
        for r in results:
            write_run(r, tmp / names[id(r)], video=False)
        for row in table_rows:
            row["violations"] = sum(written_check(tmp / n)["violations"] for n in row["runs"])
        violations = sum(row["violations"] for row in table_rows)
        table += f"\n\nSafety check (`endocam check`, every run): {violations} violations."
        write_json(tmp / "paper.json", json_safe({"policy": policy, "rows": table_rows}))
        (tmp / "paper.md").write_text(table + "\n", encoding="utf-8")
        plot_tracking(
            results,
            [names[id(r)] for r in results],
            tmp / "tracking.png",
        )
    return table


def paper_table(rows: Sequence[dict[str, Any]], policy: str) -> str:
    """Markdown table of our means beside the paper's, with the time spent in each phase."""
    lines = [
        f"| {policy} camera | image error (px) | 3D error (mm) | orientation error (deg) "
        "| frozen / planning | while tracking: 3D (mm), orientation (deg) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['trajectories']}, endocam | {r['image_error_px']:.1f} | "
            f"{r['center_error_mm']:.2f} | {r['orientation_error_deg']:.2f} | "
            f"{100 * r['frozen_fraction']:.0f} % / {100 * r['planning_fraction']:.0f} % | "
            f"{r['tracking_center_error_mm']:.2f}, {r['tracking_orientation_error_deg']:.2f} |"
        )
        lines.append(
            f"| {r['trajectories']}, paper | {r['paper_image_error_px']:.0f} | "
            f"{r['paper_center_error_mm']:.2f} | {r['paper_orientation_error_deg']:.2f} | – | – |"
        )
    return "\n".join(lines)
