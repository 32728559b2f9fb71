"""``endocam study make``: render the study videos, their manifest and raw material.

Design (paper Sec. IV-D: "three randomised trajectories of increasing difficulty"):

====  ===============  ==============  =======================================================
diff  name             control points  noise per control point (magnitude range, random sign)
====  ===============  ==============  =======================================================
1     ``t1-36-low``    36              position: config's (3-3.5 mm); angles: 5-10°
2     ``t2-36-high``   36              the config's (paper: 3-3.5 mm, 10-30°)
3     ``t3-71-high``   71              the config's; twice the control points = more turns
====  ===============  ==============  =======================================================

Each trajectory is rendered with each of the study's k ≥ 2 camera **conditions**, each a policy
of ``endocam.registry.POLICIES`` named by its policy (default ``DEFAULT_CONDITIONS``: ``fixed``,
``centering`` and ``endocam``, the paper's conditions I-III; ``--conditions``): 3k videos, left
eye, the config's resolution and frame rate. The manifest's presentation orders are the
conditions' Williams design (:mod:`endocam.study.counterbalance`). The noise seed
of trajectory ``k`` is the ``k``-th draw of ``numpy.random.default_rng(seed).integers(0, 2**31)``;
video ids are eight hex digits drawn from ``default_rng([seed, ID_STREAM])``, so nothing in a URL
reveals the condition and the same ``--seed`` gives the same study.

Unless ``practice=False`` (``--no-practice``), one more video is the practice shown with feedback
before the first set: the easiest trajectory's kind and control points with its own noise seed
(:func:`practice_seed`, stream ``PRACTICE_STREAM``; never one of the nine trajectories' seeds),
filmed by the **fixed** camera only, so the practice trains participants on none of the moving
conditions more than on another. Its ``true_touches`` comes from the same ground truth as the
study's videos'; it is not counted in the observability, observer or hypothesis files.

A drawn path that cannot be made legible is drawn again from a derived seed
(:func:`endocam.task.trajectory.redraw_seed`; ``design.json`` names it as ``drawn_seed``); an
extra seed none of whose draws is legible is skipped and listed (``skipped_extra_seeds``).

Written (atomically: a temporary folder renamed at the end)::

    manifest.json          the contract with `study serve` / `study analyze`
    videos/<id>.mp4        the 3k videos (H.264)
    videos/practice.mp4    the practice video (fixed camera), unless ``practice=False``
    design.json            the conditions and their policies, trajectories (seeds, noise,
                           touches), the key id → condition, the practice video's trajectory,
                           seed and touches, skipped extra seeds
    observability.json     objective touch observability (endocam.study.observability) + CSV
    observability.csv
    observer.json          the automatic observer's counts (endocam.study.observer) + HTML
    observer.html
    hypothesis.json        per condition: the closing gap (resolved, in sight), observer
                           counting error and image-space observability on the most difficult
                           trajectory and over ``extra_seeds`` more seeds
    logs/<id>/             scene.json, episode.csv, metrics.json, tracking.png, report.html
    logs/practice/         the same for the practice video
    seeds/<seed>/          with ``keep_seed_videos``: the extra seeds' k videos, truth.json, and for
                           the ideal observer each condition's right eye (<c>.right.mp4) and
                           per-step log (<c>.episode.csv, episode.csv's columns)
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import json
import math
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from endocam import __version__
from endocam.config import ExperimentConfig
from endocam.progress import progress_bar
from endocam.runner.pool import DEFAULT_WORKERS, executor
from endocam.study.counterbalance import presentation_orders
from endocam.study.hypothesis import (
    HYPOTHESIS_JSON,
    SEEDS_DIR,
    hypothesis_dict,
    seed_rows,
    with_gaps,
    write_truth,
)
from endocam.study.manifest import (
    DEFAULT_CONDITIONS,
    MANIFEST_NAME,
    MIN_CONDITIONS,
    AttentionQuestion,
    Manifest,
    PracticeVideo,
    Video,
    manifest_json,
)
from endocam.study.observability import (
    OBSERVABILITY_CSV,
    OBSERVABILITY_JSON,
    TouchObservation,
    observability_csv,
    observability_json,
    observe_episode,
    summarize,
)
from endocam.study.observer import (
    OBSERVER_HTML,
    OBSERVER_JSON,
    ColourKeys,
    VideoObservation,
    observe_video,
    observer_document,
    observer_html,
)
from endocam.study.visibility import closing_gap, gap_row
from endocam.task.study_paths import (
    DEFAULT_STUDY_SEED,
    STUDY_TRAJECTORIES,
    StudyTrajectory,
)
from endocam.task.study_paths import study_trajectory_seeds as trajectory_seeds
from endocam.task.trajectory import TrajectoryKind

if TYPE_CHECKING:  # the simulator (MuJoCo) is imported only when a study is made
    from endocam.camera import Eye
    from endocam.runner.episode import EpisodeResult

DEFAULT_SEED = DEFAULT_STUDY_SEED
ID_STREAM = 1  # second entry of the id generator's seed, keeps ids apart from trajectory seeds
ID_HEX_DIGITS = 8  # hex digits of a video id (32 random bits)
DESIGN_JSON = "design.json"
EXTRA_STREAM = 2  # second entry of the extra seeds' generator seed (ids use ID_STREAM)
PRACTICE_STREAM = 3  # second entry of the practice seed's generator seed
PRACTICE_NAME = "practice"  # stem of the practice video and name of its log folder
PRACTICE_CONDITION = "fixed"  # the practice's policy: no moving condition is trained more
VIDEOS_DIR = "videos"
LOGS_DIR = "logs"
PRACTICE_FILE = f"{VIDEOS_DIR}/{PRACTICE_NAME}.mp4"  # the manifest's practice.file
DEFAULT_ATTENTION = AttentionQuestion(
    question="To show you are paying attention, enter the number four as a digit.", answer=4
)


def trajectory_config(config: ExperimentConfig, trajectory: StudyTrajectory) -> ExperimentConfig:
    """``config`` with the trajectory's noise override (see ``study_path_config``)."""
    from endocam.runner.experiments import study_path_config

    return study_path_config(config, trajectory)


def right_video(condition: str) -> str:
    """File name of a kept seed's right-eye video of ``condition`` (``seeds/<seed>/``)."""
    return f"{condition}.right.mp4"


def seed_log(condition: str) -> str:
    """File name of a kept seed's per-step log (``episode.csv`` columns) of ``condition``."""
    return f"{condition}.episode.csv"


def video_ids(seed: int, n: int) -> tuple[str, ...]:
    """``n`` distinct random-looking ids (``ID_HEX_DIGITS`` hex digits), seeded by ``seed``."""
    if seed < 0:
        raise ValueError(f"seed must be ≥ 0, got {seed}")
    rng = np.random.default_rng([seed, ID_STREAM])
    ids: list[str] = []
    while len(ids) < n:
        candidate = f"{int(rng.integers(0, 16**ID_HEX_DIGITS)):0{ID_HEX_DIGITS}x}"
        if candidate not in ids:
            ids.append(candidate)
    return tuple(ids)


def practice_seed(seed: int, n: int = len(STUDY_TRAJECTORIES)) -> int:
    """Noise seed of the practice video: a draw of ``default_rng([seed, PRACTICE_STREAM])``.

    Draws again while the value is one of the ``n`` trajectory seeds (:func:`trajectory_seeds`),
    so the practice video is never one of the study's videos.
    """
    taken = set(trajectory_seeds(seed, n))
    rng = np.random.default_rng([seed, PRACTICE_STREAM])
    while (value := int(rng.integers(0, 2**31))) in taken:
        pass
    return value


def check_conditions(conditions: Sequence[str]) -> tuple[str, ...]:
    """The study's conditions, checked: registered policy names, distinct, at least two.

    Raises
    ------
    ValueError
        One line naming the problem (an unknown name lists the choices).
    """
    from endocam.registry import POLICIES

    names = tuple(conditions)
    unknown = [c for c in names if c not in POLICIES]
    if unknown:
        raise ValueError(
            f"unknown condition {unknown[0]!r}; choose policies from: {', '.join(POLICIES)}"
        )
    repeated = sorted({c for c in names if names.count(c) > 1})
    if repeated:
        raise ValueError(f"each condition once, repeated: {', '.join(repeated)}")
    if len(names) < MIN_CONDITIONS:
        raise ValueError(f"a study needs at least {MIN_CONDITIONS} conditions, got {len(names)}")
    return names


def check_study_config(config: ExperimentConfig) -> None:
    """Raise ``ValueError`` (one line) if the config cannot make study videos."""
    if config.camera.width % 2 or config.camera.height % 2:
        raise ValueError(
            f"camera.width and camera.height must be even for H.264 video, got "
            f"{config.camera.width}x{config.camera.height}"
        )


def render_conditions(
    results: Sequence[EpisodeResult],
    paths: Sequence[Path],
    progress: Callable[[int], object] | None = None,
    eye: Eye = "left",
) -> None:
    """Render one eye (default the left) of episodes that share one ring trajectory, in one pass.

    One scene serves all of them: per frame the ring is placed once, then each episode's camera.

    Parameters
    ----------
    results : sequence of EpisodeResult
        Episodes of the same config and trajectory (different policies).
    paths : sequence of Path
        One MP4 per episode.
    progress : callable, optional
        Called with 1 per rendered frame (all episodes).
    eye : {"left", "right"}
        The eye filmed.
    """
    from endocam.runner.experiments import render_episodes

    render_episodes(results, paths, None, progress, eye)


def make_study(
    config: ExperimentConfig,
    out_dir: str | Path,
    *,
    seed: int = DEFAULT_SEED,
    trajectories: Sequence[StudyTrajectory] = STUDY_TRAJECTORIES,
    extra_seeds: int = 0,
    practice: bool = True,
    workers: int = DEFAULT_WORKERS,
    keep_seed_videos: bool = False,
    conditions: Sequence[str] = DEFAULT_CONDITIONS,
) -> Manifest:
    """Simulate, render and write a complete study folder (see the module docstring).

    Parameters
    ----------
    config : ExperimentConfig
        Camera, controller, episode and task; the trajectories override only the angle noise.
    out_dir : str or Path
        Study folder; replaced atomically when everything is written.
    seed : int
        Study seed (≥ 0): trajectory noise seeds and video ids derive from it.
    trajectories : sequence of StudyTrajectory
        The design; distinct names and difficulties in 1..3.
    extra_seeds : int
        More noise seeds of the most difficult trajectory (≥ 0): each is simulated, rendered
        with every condition and counted by the observer for ``hypothesis.json``.
    practice : bool
        Also render the practice video (easiest trajectory, fixed camera, :func:`practice_seed`)
        and name it in the manifest.
    workers : int
        Processes for the extra seeds (≥ 1; 1: in this process); the results do not depend on it.
    keep_seed_videos : bool
        Keep the extra seeds' videos and true touches in ``seeds/<noise seed>/``, so that
        ``study observe`` can count them again (:mod:`endocam.study.hypothesis`).
    conditions : sequence of str
        The conditions (registered policy names, distinct, at least two), in the order of the
        manifest, the tables and the Williams design's first order.

    Returns
    -------
    Manifest
        The manifest written (validated).
    """
    from endocam.runner.episode import EpisodeSpec
    from endocam.runner.experiments import ground_truth, run_with_progress
    from endocam.runner.outputs import atomic_dir, check_output_folder, frame_indices, write_run
    from endocam.sim.render import WireChaserScene

    check_study_config(config)
    conds = check_conditions(conditions)
    if extra_seeds < 0:
        raise ValueError(f"extra_seeds must be ≥ 0, got {extra_seeds}")
    if workers < 1:
        raise ValueError(f"workers must be ≥ 1, got {workers}")
    out = Path(out_dir)
    check_output_folder(out)
    seeds = trajectory_seeds(seed, len(trajectories))
    ids = iter(video_ids(seed, len(trajectories) * len(conds)))
    kind = TrajectoryKind.NOISY

    runs: list[tuple[StudyTrajectory, int, list[EpisodeResult]]] = []
    with progress_bar(total=len(trajectories) * len(conds), desc="episodes") as bar:
        for traj, traj_seed in zip(trajectories, seeds, strict=True):
            cfg = trajectory_config(config, traj)
            touches = ground_truth(cfg, kind, traj.control_points, traj_seed)
            results = []
            for condition in conds:
                spec = EpisodeSpec(condition, kind, traj.control_points, traj_seed)
                results.append(run_with_progress(cfg, spec, touches))
                bar.update(1)
            runs.append((traj, traj_seed, results))

    practice_run: tuple[StudyTrajectory, int, EpisodeResult] | None = None
    if practice:
        easiest = min(trajectories, key=lambda t: t.difficulty)
        p_seed = practice_seed(seed, len(trajectories))
        cfg = trajectory_config(config, easiest)
        touches = ground_truth(cfg, kind, easiest.control_points, p_seed)
        spec = EpisodeSpec(PRACTICE_CONDITION, kind, easiest.control_points, p_seed)
        practice_run = (easiest, p_seed, run_with_progress(cfg, spec, touches))

    key: dict[tuple[str, str], str] = {
        (traj.name, c): next(ids) for traj, _, _ in runs for c in conds
    }
    videos = []
    for c_index, c in enumerate(conds):  # condition-major, easy to hard in each set
        for traj, _, results in sorted(runs, key=lambda r: r[0].difficulty):
            vid = key[(traj.name, c)]
            videos.append(
                Video(
                    id=vid,
                    condition=c,
                    trajectory=traj.name,
                    difficulty=traj.difficulty,
                    true_touches=results[c_index].touches.count,
                    contact_fraction=results[c_index].touches.contact_fraction,
                    file=f"{VIDEOS_DIR}/{vid}.mp4",
                )
            )
    manifest = Manifest(
        endocam_version=__version__,
        created=datetime.now(UTC).replace(microsecond=0),
        conditions=conds,
        videos=tuple(videos),
        orders=presentation_orders(conds),
        attention=DEFAULT_ATTENTION,
        practice=None
        if practice_run is None
        else PracticeVideo(file=PRACTICE_FILE, true_touches=practice_run[2].touches.count),
    )

    n_frames = sum(len(frame_indices(rs[0])) * len(rs) for _, _, rs in runs)
    n_practice = 0 if practice_run is None else len(frame_indices(practice_run[2]))
    records: list[TouchObservation] = []
    with atomic_dir(out) as tmp:
        # cheap outputs first: a failure there must not waste the long render
        for traj, _, results in progress_bar(runs, desc="logs"):
            for c, result in zip(conds, results, strict=True):
                write_run(result, tmp / LOGS_DIR / key[(traj.name, c)], video=False)
        if practice_run is not None:
            write_run(practice_run[2], tmp / LOGS_DIR / PRACTICE_NAME, video=False)
        first = runs[0][2][0]
        with WireChaserScene(first.config.task, first.camera) as scene:
            for traj, _, results in progress_bar(runs, desc="observability"):
                for c, result in zip(conds, results, strict=True):
                    vid = key[(traj.name, c)]
                    records += observe_episode(
                        result, scene, video_id=vid, condition=c, trajectory=traj.name
                    )
        (tmp / VIDEOS_DIR).mkdir()
        with progress_bar(total=n_frames + n_practice, desc="render", unit="frame") as bar:
            for traj, _, results in runs:
                paths = [tmp / VIDEOS_DIR / f"{key[(traj.name, c)]}.mp4" for c in conds]
                render_conditions(results, paths, bar.update)
            if practice_run is not None:
                render_conditions([practice_run[2]], [tmp / PRACTICE_FILE], bar.update)
        keys = ColourKeys.from_scene(config.task.scene)
        observations: dict[str, VideoObservation] = {}
        with progress_bar(total=n_frames, desc="observer", unit="frame") as bar:
            for v in manifest.videos:
                observations[v.id] = observe_video(tmp / v.file, keys, bar.update)
        records = [with_gaps(r, observations[r.video_id]) for r in records]
        summary = summarize(records, conditions=conds)
        (tmp / OBSERVABILITY_JSON).write_text(observability_json(summary, records), "utf-8")
        (tmp / OBSERVABILITY_CSV).write_text(observability_csv(records), "utf-8")
        observer = observer_document(manifest, observations)
        (tmp / OBSERVER_JSON).write_text(json.dumps(observer, indent=2) + "\n", "utf-8")
        (tmp / OBSERVER_HTML).write_text(observer_html(manifest, observations), "utf-8")
        hardest = max(trajectories, key=lambda t: t.difficulty)
        extra, skipped = run_extra_seeds(
            config,
            ExtraSeeds(hardest, seed, extra_seeds, conds),
            keys,
            tmp,
            workers,
            keep_seed_videos,
        )
        frame_s = 1.0 / config.episode.video_fps
        hypothesis = hypothesis_dict(
            manifest, observer, records, hardest.name, extra, frame_s, skipped=skipped
        )
        (tmp / HYPOTHESIS_JSON).write_text(json.dumps(hypothesis, indent=2) + "\n", "utf-8")
        design = design_dict(config, runs, key, seed, practice_run) | {
            "skipped_extra_seeds": skipped
        }
        (tmp / DESIGN_JSON).write_text(json.dumps(design, indent=2) + "\n", "utf-8")
        (tmp / MANIFEST_NAME).write_text(manifest_json(manifest), "utf-8")
    return manifest


def extra_seed_values(seed: int, n: int) -> tuple[int, ...]:
    """Noise seeds of ``n`` extra trajectories: draws of ``default_rng([seed, EXTRA_STREAM])``."""
    rng = np.random.default_rng([seed, EXTRA_STREAM])
    return tuple(int(s) for s in rng.integers(0, 2**31, size=n))


@dataclass(frozen=True)
class ExtraSeeds:
    """The extra seeds of a study: ``n`` more noise seeds of ``trajectory``, each condition.

    Attributes
    ----------
    trajectory : StudyTrajectory
        The path (the study's most difficult).
    seed : int
        The study seed; the noise seeds are :func:`extra_seed_values` ``(seed, n)``.
    n : int
        How many (≥ 0).
    conditions : tuple of str
        The study's conditions (policy names).
    """

    trajectory: StudyTrajectory
    seed: int
    n: int
    conditions: tuple[str, ...]


def run_extra_seeds(
    config: ExperimentConfig,
    extra: ExtraSeeds,
    keys: ColourKeys,
    work_dir: Path,
    workers: int = DEFAULT_WORKERS,
    keep_videos: bool = False,
) -> tuple[list[dict[str, Any]], list[int]]:
    """Simulate, render and observe the extra seeds (every condition each).

    The seeds run in the runner's process pool (:func:`endocam.runner.pool.executor`,
    ``workers`` processes started by ``spawn``, as they render; 1: in this process), one job per
    seed; the rows are in seed order whatever order the jobs finish in, so the result equals a
    serial run's.

    Returns one dict per seed and condition (:func:`endocam.study.hypothesis.seed_rows`) and
    the seeds skipped because no draw of their path was legible
    (:class:`~endocam.task.trajectory.IllegiblePathError`). The videos are rendered into
    ``work_dir/seeds/<noise seed>/`` with the seed's ``truth.json``; unless ``keep_videos``,
    each seed's folder is deleted once it is counted.
    """
    if extra.n == 0:
        return [], []
    seeds = extra_seed_values(extra.seed, extra.n)
    rows: dict[int, list[dict[str, Any]] | None] = {}
    with (
        progress_bar(total=extra.n, desc="extra seeds", unit="seed", leave=True) as bar,
        executor(workers, "spawn") as pool,
    ):
        futures = {
            pool.submit(_extra_seed_rows, config, extra, s, keys, work_dir, keep_videos): k
            for k, s in enumerate(seeds)
        }
        for fut in concurrent.futures.as_completed(futures):
            rows[futures[fut]] = fut.result()
            bar.update(1)
    if not keep_videos:
        with contextlib.suppress(OSError):
            (work_dir / SEEDS_DIR).rmdir()  # empty unless someone else put files there
    skipped = [seeds[k] for k in range(extra.n) if rows[k] is None]
    return [row for k in range(extra.n) for row in rows[k] or []], skipped


def _extra_seed_rows(
    config: ExperimentConfig,
    extra: ExtraSeeds,
    s: int,
    keys: ColourKeys,
    work_dir: Path,
    keep_videos: bool,
) -> list[dict[str, Any]] | None:
    """One extra seed's rows (see :func:`run_extra_seeds`); None: its path is illegible."""
    from endocam.runner.episode import EpisodeSpec, run_episode
    from endocam.runner.experiments import ground_truth
    from endocam.runner.outputs import write_episode_csv
    from endocam.sim.render import WireChaserScene
    from endocam.task.trajectory import IllegiblePathError

    cfg = trajectory_config(config, extra.trajectory)
    kind = TrajectoryKind.NOISY
    points = extra.trajectory.control_points
    try:
        touches = ground_truth(cfg, kind, points, s)
    except IllegiblePathError:
        return None
    results = [
        run_episode(cfg, EpisodeSpec(c, kind, points, s), touches=touches) for c in extra.conditions
    ]
    events = [(e.t_start, e.t_end) for e in touches.events]
    with WireChaserScene(cfg.task, results[0].camera) as scene:
        gaps = {
            c: [gap_row(closing_gap(r, scene, e.t_start)) for e in touches.events]
            for c, r in zip(extra.conditions, results, strict=True)
        }
    hidden = {c: [g["hidden_by_left"] for g in rows] for c, rows in gaps.items()}
    folder = work_dir / SEEDS_DIR / str(s)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        render_conditions(results, [folder / f"{c}.mp4" for c in extra.conditions])
        rows = seed_rows(folder, s, events, keys, extra.conditions, gaps=gaps)
        if keep_videos:  # the ideal observer's material: the right eye and the per-step logs
            render_conditions(
                results, [folder / right_video(c) for c in extra.conditions], None, "right"
            )
            for c, r in zip(extra.conditions, results, strict=True):
                write_episode_csv(r, folder / seed_log(c))
            write_truth(folder, s, cfg.episode.video_fps, events, hidden, gaps=gaps)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    if not keep_videos:
        shutil.rmtree(folder, ignore_errors=True)
    return rows


def design_dict(
    config: ExperimentConfig,
    runs: Sequence[tuple[StudyTrajectory, int, list[EpisodeResult]]],
    key: dict[tuple[str, str], str],
    seed: int,
    practice: tuple[StudyTrajectory, int, EpisodeResult] | None = None,
) -> dict[str, Any]:
    """``design.json``: the study seed, the conditions, each trajectory's parameters, the key.

    ``conditions`` maps each condition to the registry policy that filmed it (the same name).
    Per trajectory, ``noise_seed`` is the seed drawn for it and ``drawn_seed`` the one its path
    was drawn with (another only when the first draw was illegible and re-drawn,
    :func:`endocam.task.trajectory.redraw_seed`). ``practice`` (trajectory, noise seed, episode)
    adds a ``practice`` entry (else ``null``).
    """
    conds = list(dict.fromkeys(c for _, c in key))
    trajectories = []
    for traj, traj_seed, results in runs:
        cfg = results[0].config.task.trajectory
        trajectories.append(
            {
                "name": traj.name,
                "difficulty": traj.difficulty,
                "control_points": traj.control_points,
                "noise_seed": traj_seed,
                "drawn_seed": results[0].trajectory.control_points.noise_seed,
                "position_noise_mm": [v * 1e3 for v in cfg.position_noise],
                "angle_noise_deg": [math.degrees(v) for v in cfg.angle_noise],
                "duration_s": cfg.duration,
                "true_touches": results[0].touches.count,
                "contact_fraction": results[0].touches.contact_fraction,
                "videos": {c: key[(traj.name, c)] for c in conds},
            }
        )
    return {
        "seed": seed,
        "conditions": {c: c for c in conds},  # each condition is named by its policy
        "eye": "left",
        "width_px": config.camera.width,
        "height_px": config.camera.height,
        "video_fps": config.episode.video_fps,
        "ring_rgba": list(config.task.scene.ring_rgba),
        "wire_rgba": list(config.task.scene.wire_rgba),
        "trajectories": trajectories,
        "practice": None
        if practice is None
        else {
            "trajectory": practice[0].name,
            "noise_seed": practice[1],
            "condition": PRACTICE_CONDITION,
            "true_touches": practice[2].touches.count,
            "file": PRACTICE_FILE,
        },
        "endocam_version": __version__,
    }
