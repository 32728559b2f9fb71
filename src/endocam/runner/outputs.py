"""What an episode leaves behind: scene, log, metrics, video, plot and report files.

The files are ``scene.json``, ``episode.csv``, ``check.json`` (the safety check of the two
before, :mod:`endocam.runner.check`), ``metrics.json`` (with the check's summary),
``video.mp4``, ``tracking.png`` and ``report.html``.
Raw files are SI unless a column or key says its unit (``image_error_px``, ``center_error_mm``).
Everything is written into a temporary folder next to the destination and moved into place when
complete, so an interrupted run never leaves output that looks finished. Every folder written so
holds the marker file :data:`OUTPUT_MARKER`; endocam replaces an existing folder only if it holds
that marker or is empty (:func:`check_output_folder`), so ``--out`` never deletes what a person
put there.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import imageio_ffmpeg
import jinja2
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from endocam import __version__
from endocam.control.types import TrackingState
from endocam.geometry import FloatArray, quat_wxyz_from_R
from endocam.metrics import summarize
from endocam.perception.loop import estimation_summary
from endocam.robot.actuator import ArmKind
from endocam.runner.check import (
    CHECK_JSON,
    EPISODE_CSV,
    SCENE_JSON,
    CheckResult,
    check_run,
    write_check,
)
from endocam.runner.episode import BLOCKED, UNREACHABLE, EpisodeResult, state_fractions
from endocam.runner.log_schema import (
    episode_column_names,
    joint_column,
    log_section,
    quat_names,
    xyz_names,
)

METRICS_JSON = "metrics.json"
VIDEO_MP4 = "video.mp4"
TRACKING_PNG = "tracking.png"
REPORT_HTML = "report.html"
WIRE_POLYLINE_POINTS = 1000  # count, samples of the wire centre line in scene.json
NEAR_WIRE_M = 0.010  # m: "near the wire" in metrics.json (a pickup camera is about this wide)
PLOT_DPI = 120  # dots per inch of the PNG plots
VIDEO_CRF = 20  # x264 constant rate factor (lower = better quality; 20 keeps the wire crisp)
_TEMPLATES = Path(__file__).parent / "templates"
_SHADE = {
    TrackingState.PLANNING.value: ("#f5c542", "planning (way-points)"),
    TrackingState.FROZEN_OUTSIDE_CONE.value: ("#9aa5b1", "frozen outside cone"),
    TrackingState.LOST_TRACKING.value: ("#e06666", "lost tracking"),
    UNREACHABLE: ("#c27ba0", "unreachable"),
    BLOCKED: ("#8e44ad", "blocked (braked at the workspace)"),
}

Progress = Callable[[int], object]


# --------------------------------------------------------------------------- atomic folders
OUTPUT_MARKER = ".endocam-output"
"""The file endocam writes into every output folder it creates: endocam replaces (or resumes) an
existing folder only if it holds this file, or is empty."""
_MARKER_TEXT = (
    "endocam {version} wrote this folder; endocam may replace it. Delete this file to keep "
    "endocam from ever replacing the folder (docs/conventions.md, 'Output folders').\n"
)


def write_marker(folder: Path) -> None:
    """Write :data:`OUTPUT_MARKER` into ``folder`` (which endocam created)."""
    (Path(folder) / OUTPUT_MARKER).write_text(
        _MARKER_TEXT.format(version=__version__), encoding="utf-8"
    )


def check_replaceable(out_dir: str | Path) -> None:
    """Raise ``ValueError`` (one line) unless endocam may replace or fill ``out_dir``.

    Refused: an empty path; the current folder, the home folder or any folder holding either;
    a file in the way; an existing folder that is not empty and holds no :data:`OUTPUT_MARKER`.
    Nothing is created (see :func:`check_output_folder` for the writability probe too).
    """
    if not str(out_dir).strip():
        raise ValueError("output folder: the path is empty; name a folder, e.g. out/run")
    out = Path(out_dir)
    resolved = out.resolve()
    for what, base in (("the current folder", Path.cwd()), ("your home folder", _home())):
        if base is not None and (resolved == base or resolved in base.parents):
            which = "is" if resolved == base else "contains"
            raise ValueError(
                f"output folder {str(out)!r} {which} {what}, which endocam would replace; "
                "name a new folder, e.g. out/run"
            )
    if resolved.exists() and not resolved.is_dir():
        raise ValueError(f"output {out} exists and is not a folder")
    if resolved.is_dir() and not (resolved / OUTPUT_MARKER).is_file():
        try:
            empty = next(resolved.iterdir(), None) is None
        except OSError as exc:
            raise ValueError(f"cannot read output folder {out}: {exc.strerror}") from None
        if not empty:
            raise ValueError(
                f"output folder {out} is not empty and endocam did not write it (no "
                f"{OUTPUT_MARKER} file); choose a new or empty folder"
            )


def _home() -> Path | None:
    try:
        return Path.home().resolve()
    except (RuntimeError, KeyError):  # no HOME and no password entry
        return None


def check_output_folder(out_dir: str | Path) -> Path:
    """The output folder ``out_dir`` checked before any work starts; returns it as a ``Path``.

    Raises
    ------
    ValueError
        One line: what :func:`check_replaceable` refuses, or a place that cannot be written.
    """
    check_replaceable(out_dir)
    check_writable(Path(out_dir))
    return Path(out_dir)


@contextlib.contextmanager
def atomic_dir(out_dir: Path) -> Iterator[Path]:
    """Yield a temporary folder that replaces ``out_dir`` only if the block completes.

    The folder gets :data:`OUTPUT_MARKER`. ``out_dir`` must be one endocam may replace
    (:func:`check_replaceable`, checked before the block runs and again before the swap).

    Raises
    ------
    ValueError
        ``out_dir`` is not replaceable (then nothing is written), or stopped being so while the
        block ran (then the finished folder is kept under its temporary name, named in the error).
    """
    check_replaceable(out_dir)
    out_dir = Path(out_dir).resolve()
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp-", dir=out_dir.parent))
    try:
        yield tmp
        write_marker(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    try:
        check_replaceable(out_dir)
    except ValueError as exc:  # someone filled the folder meanwhile: keep both
        raise ValueError(f"{exc}; the finished output is in {tmp}") from None
    old = None
    if out_dir.exists():
        old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
        os.replace(out_dir, old)
    os.replace(tmp, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_atomic(path: Path, write: Callable[[Path], object]) -> None:
    """Call ``write`` on a hidden temporary file beside ``path``, then rename it to ``path``.

    A reader never sees a half-written file; an exception leaves no temporary file behind.
    """
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def check_writable(out_dir: Path) -> None:
    """Raise ``ValueError`` (one line) unless ``out_dir`` can be created and written."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"output {out_dir} exists and is not a folder")
    parent = out_dir.resolve().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"cannot create output folder {parent}: {exc.strerror}") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"output folder {parent} is not writable")
    try:  # os.access says yes to root everywhere (even /proc): create a folder there to know
        tempfile.TemporaryDirectory(prefix=f".{out_dir.name}.probe-", dir=parent).cleanup()
    except OSError as exc:
        raise ValueError(f"cannot create output folder {out_dir}: {exc.strerror}") from None


# ------------------------------------------------------------------------------- raw files
def scene_dict(result: EpisodeResult) -> dict[str, Any]:
    """The ``scene.json`` content, SI: wire, ring, camera, RCM, cone and the config."""
    cfg = result.config
    cam = result.camera
    wire = result.wire
    return {
        "units": "SI (m, s, rad); pixel quantities in px",
        "wire": {
            "points": wire.polyline(WIRE_POLYLINE_POINTS).tolist(),
            "wire_radius": cfg.task.wire.radius,
            "length": wire.length,
        },
        "ring": {
            "major_radius": cfg.task.ring.major_radius,
            "minor_radius": cfg.task.ring.minor_radius,
        },
        "camera": {
            "K_left": cam.intrinsics.K.tolist(),
            "T_cam_left": cam.T_cam_left.tolist(),
            "T_cam_right": cam.T_cam_right.tolist(),
            "width": cam.intrinsics.width,
            "height": cam.intrinsics.height,
            "baseline": cam.baseline,
            "fovy": cam.intrinsics.fovy,
            "T_world_overview": result.T_world_overview.tolist(),
        },
        "rcm": list(cfg.task.scene.rcm_position),
        "cone": {
            "apex": list(cfg.task.scene.rcm_position),
            "axis_towards": result.log.T_world_ring_sensed[0][:3, 3].tolist(),
            "height": cfg.controller.cone_height,
            "base_radius": cfg.controller.cone_base_radius,
        },
        "episode": {
            "policy": result.spec.policy,
            "trajectory": result.spec.trajectory.value,
            "control_points": result.spec.control_points,
            "seed": result.spec.seed,
        },
        "log": log_section(
            ArmKind(result.log.arm),
            result.trajectory.duration,
            1.0 / cfg.episode.control_rate,
            result.log.estimates is not None,
        ),
        "config": cfg.model_dump(mode="json"),
        "endocam_version": __version__,
    }


def episode_columns(result: EpisodeResult) -> dict[str, np.ndarray]:
    """Per-step columns of ``episode.csv`` (ordered), SI unless the name gives a unit.

    The names and their order are :func:`endocam.runner.log_schema.episode_column_names` of the
    carrier, the checker's own (``RuntimeError`` if the columns built here drift from them).
    """
    log = result.log
    cols: dict[str, np.ndarray] = {"t": log.t}
    _pose_columns(cols, "ring", log.T_world_ring, quat_wxyz_from_R(log.T_world_ring[:, :3, :3]))
    _pose_columns(cols, "cam", log.T_world_cam, _quaternions(log.T_world_cam))
    cols["contact"] = log.contact.astype(int)
    cols["clearance"] = log.clearance
    cols["state"] = log.state
    cols["fault"] = log.fault if log.fault is not None else np.full(len(log.t), "", dtype=object)
    cols["d_f"] = log.d_f
    _pose_columns(cols, "cmd", log.T_world_cmd, _quaternions(log.T_world_cmd))
    for j, name in enumerate(("psm1", "psm2")):
        cols.update(zip(xyz_names(f"{name}_tip"), log.p_world_tips[:, j].T, strict=True))
    if log.joints is not None:
        for j, name in enumerate(log.joint_names):
            cols[joint_column(name)] = log.joints[:, j]
    if log.goal_position_error is not None and log.goal_orientation_error is not None:
        # how far the pose the arm heads for lies from the commanded goal (0: reached exactly)
        cols["goal_conceded_mm"] = log.goal_position_error * 1e3
        cols["goal_conceded_deg"] = np.degrees(log.goal_orientation_error)
    cols["image_error_px"] = result.image_error  # raw: NaN behind the camera
    cols["center_error_mm"] = result.center_error * 1e3
    cols["orientation_error_deg"] = np.degrees(result.orientation_error)
    est = log.estimates
    if est is not None:  # a stereo run: the estimates delivered, empty where none
        cols.update(zip(xyz_names("est"), est.p_world.T, strict=True))
        cols.update(zip(("est_nx", "est_ny", "est_nz"), est.n_world.T, strict=True))
        cols["est_ok"] = est.ok.astype(int)
        cols["est_age_s"] = log.t - est.t_capture
    cols["reason"] = np.array(log.reason, dtype=object)
    carrier = ArmKind(log.arm)
    names = episode_column_names(carrier) if est is None else episode_column_names(carrier, True)
    if set(cols) != set(names):
        drift = sorted(set(cols).symmetric_difference(names))
        raise RuntimeError(f"episode.csv columns drifted from the log schema: {drift}")
    return {name: cols[name] for name in names}


def _pose_columns(
    cols: dict[str, np.ndarray], prefix: str, T: FloatArray, quat: FloatArray
) -> None:
    """Add ``<prefix>_x/y/z`` (translations of ``T`` (N, 4, 4)) and ``_qw..qz`` (``quat``)."""
    cols.update(zip(xyz_names(prefix), T[:, :3, 3].T, strict=True))
    cols.update(zip(quat_names(prefix), quat.T, strict=True))


def _quaternions(T: FloatArray) -> FloatArray:
    """(N, 4) quaternions (w, x, y, z) of poses (N, 4, 4); NaN rows where a pose is not finite."""
    q = np.full((len(T), 4), np.nan)
    ok = np.isfinite(T[:, :3, :3]).all(axis=(1, 2))
    if ok.any():
        q[ok] = quat_wxyz_from_R(T[ok, :3, :3])
    return q


def write_episode_csv(result: EpisodeResult, path: Path) -> None:
    """Write ``episode.csv``: one row per control step, full float precision."""
    cols = episode_columns(result)
    names = list(cols)
    arrays = [cols[n] for n in names]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(names)
        for k in range(len(result.log.t)):
            writer.writerow([_cell(a[k]) for a in arrays])


def _cell(value: Any) -> Any:
    if isinstance(value, float | np.floating):
        return repr(float(value)) if math.isfinite(value) else ""
    if isinstance(value, np.integer):
        return int(value)
    return value


def metrics_dict(result: EpisodeResult) -> dict[str, Any]:
    """The ``metrics.json`` content: tracking errors in px / mm / deg, touches, states, config."""
    return {
        "image_error_px": summarize(result.image_error_saturated),
        "ring_out_of_view_fraction": float(np.mean(result.ring_out_of_view)),
        "center_error_mm": summarize(result.center_error, 1e3),
        "orientation_error_deg": summarize(result.orientation_error, math.degrees(1.0)),
        "touches": result.touches.count,
        "contact_fraction": result.touches.contact_fraction,
        "touch_events": [
            {
                "t_start": ev.t_start,
                "t_end": ev.t_end,
                "contact_point": np.asarray(ev.p_world_contact).tolist(),
                "min_clearance": ev.min_clearance,
            }
            for ev in result.touches.events
        ],
        "camera_wire_clearance_mm": {
            "min": 1e3 * float(np.min(result.camera_wire_clearance)),
            "p5": 1e3 * float(np.percentile(result.camera_wire_clearance, 5.0)),
            "share_below_10mm": float(np.mean(result.camera_wire_clearance < NEAR_WIRE_M)),
        },
        "arm": result.log.arm,
        "state_fractions": state_fractions(result.log),
        "by_state": {
            state: {
                "image_error_px": summarize(result.image_error_saturated[mask]),
                "center_error_mm": summarize(result.center_error[mask], 1e3),
                "orientation_error_deg": summarize(
                    result.orientation_error[mask], math.degrees(1.0)
                ),
            }
            for state in np.unique(result.log.state)
            for mask in [result.log.state == state]
        },
        "episode": {
            "policy": result.spec.policy,
            "trajectory": result.spec.trajectory.value,
            "control_points": result.spec.control_points,
            "seed": result.spec.seed,
            "duration_s": float(result.trajectory.duration),
            "control_steps": len(result.log.t),
        },
        **(
            {"perception": estimation_summary(result.log.estimates, result.trajectory.poses)}
            if result.log.estimates is not None
            else {}
        ),
        "config": result.config.model_dump(mode="json"),
        "endocam_version": __version__,
    }


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON (strict: NaN and inf refused; pass it through json_safe)."""
    text = json.dumps(data, indent=2, allow_nan=False, default=_nan_to_none)
    path.write_text(text + "\n", encoding="utf-8")


def _nan_to_none(obj: Any) -> Any:  # pragma: no cover - json only calls it for unknown types
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def json_safe(data: Any) -> Any:
    """Replace NaN/inf by None recursively (JSON has no NaN)."""
    if isinstance(data, dict):
        return {k: json_safe(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [json_safe(v) for v in data]
    if isinstance(data, float) and not math.isfinite(data):
        return None
    return data


# ---------------------------------------------------------------------------------- plots
def _shade_states(ax: Any, t: np.ndarray, state: np.ndarray) -> None:
    for value, (colour, _label) in _SHADE.items():
        mask = state == value
        if mask.any():
            ax.fill_between(
                t,
                0,
                1,
                where=mask,
                color=colour,
                alpha=0.25,
                lw=0,
                step="mid",
                transform=ax.get_xaxis_transform(),
            )


MAX_LINE_WIDTH = 2.6  # pt: the first of several lines (the paper experiment draws six)


def plot_tracking(results: Sequence[EpisodeResult], labels: Sequence[str], path: Path) -> None:
    """The three tracking errors against time, one line per episode (like paper Figs. 5–6).

    With one episode, the control states (planning, frozen, lost) are shaded behind the lines.
    """
    fig = Figure(figsize=(9.0, 7.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    series = [
        ("image_error_saturated", 1.0, "Image centring\nerror (px)"),
        ("center_error", 1e3, "3D centring\nerror (mm)"),
        ("orientation_error", math.degrees(1.0), "Orientation\nerror (deg)"),
    ]
    # each line thinner than the one before, drawn over it: lines that coincide (the fixed and
    # the centring camera keep one orientation) stay visible as a band and the line inside it
    widths = np.linspace(min(1.0 + 0.8 * (len(results) - 1), MAX_LINE_WIDTH), 1.0, len(results))
    for ax, (attr, scale, ylabel) in zip(axes, series, strict=True):
        for result, label, lw in zip(results, labels, widths, strict=True):
            ax.plot(result.log.t, getattr(result, attr) * scale, lw=lw, label=label)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0)
    if len(results) == 1:
        for ax in axes:
            _shade_states(ax, results[0].log.t, results[0].log.state)
        present = {s for s in np.unique(results[0].log.state) if s in _SHADE}
        handles = [_patch(_SHADE[s][0], _SHADE[s][1]) for s in _SHADE if s in present]
        if handles:
            axes[0].legend(handles=handles, loc="upper right", fontsize=8)
    else:
        axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("Time (s)   (a ring out of view counts as the farthest image corner)")
    r0 = results[0]
    fig.suptitle(
        f"Tracking errors, {r0.spec.trajectory.value} trajectory, "
        f"{r0.spec.control_points} control points, seed {r0.spec.seed}"
    )
    fig.savefig(path, dpi=PLOT_DPI, format="png")


def _patch(colour: str, label: str) -> Any:
    from matplotlib.patches import Patch

    return Patch(facecolor=colour, alpha=0.4, label=label)


# ---------------------------------------------------------------------------------- video
def frame_indices(result: EpisodeResult) -> np.ndarray:
    """Control-step index shown in each video frame (nearest step to ``j / fps``)."""
    episode = result.config.episode
    return video_frame_steps(
        result.trajectory.duration, episode.control_rate, episode.video_fps, len(result.log.t)
    )


def video_frame_steps(duration: float, control_rate: float, fps: float, steps: int) -> np.ndarray:
    """(F,) the control step each frame of a run's video shows: the nearest to ``j / fps``.

    ``duration`` s, ``control_rate`` and ``fps`` Hz, ``steps`` the log's rows; F frames cover
    ``[0, duration]``. The one mapping the renderer and the MCAP export share.
    """
    n_frames = math.floor(duration * fps + 1e-9) + 1
    k = np.rint(np.arange(n_frames) * control_rate / fps).astype(int)
    return np.minimum(k, steps - 1)


def video_writer(path: Path, width: int, height: int, fps: float) -> Any:
    """A primed imageio-ffmpeg H.264 writer (yuv420p, playable in every browser)."""
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (width, height),
        fps=fps,
        codec="libx264",
        pix_fmt_in="rgb24",
        pix_fmt_out="yuv420p",
        macro_block_size=1,
        ffmpeg_log_level="error",
        output_params=["-crf", str(VIDEO_CRF), "-preset", "veryfast", "-movflags", "+faststart"],
    )
    writer.send(None)
    return writer


def render_video(result: EpisodeResult, path: Path, progress: Progress | None = None) -> int:
    """Render the left eye over the episode into an H.264 MP4; returns the number of frames."""
    from endocam.sim.render import WireChaserScene, log_arm

    log = result.log
    idx = frame_indices(result)
    k = result.camera.intrinsics
    if k.width % 2 or k.height % 2:
        raise ValueError("video needs an even image width and height (H.264 yuv420p)")
    with WireChaserScene(result.config.task, result.camera, arm=log_arm(log)) as scene:
        writer = video_writer(path, k.width, k.height, result.config.episode.video_fps)
        try:
            for i in idx:
                scene.set_ring_pose(log.T_world_ring[i])
                scene.set_psm2_tip(log.p_world_tips[i, 1])
                scene.set_camera_pose(log.T_world_cam[i])
                scene.set_arm_from_log(log, i)
                writer.send(np.ascontiguousarray(scene.render("left")))
                if progress is not None:
                    progress(1)
        finally:
            writer.close()
    return len(idx)


# --------------------------------------------------------------------------------- report
def _env() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(_TEMPLATES)),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def fmt(x: Any, digits: int = 2) -> str:
    """Format a number for a table; missing values as an en dash."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}f}"


CARRIERS = {
    "free": "a free 6-DoF camera (Cartesian speed, acceleration and jerk limits)",
    "psm": "a dVRK PSM (closed-form IK, joint limits, ruckig joint motion)",
    "ecm": "the dVRK ECM (4 DoF: the view from its port)",
}


def render_template(name: str, **context: Any) -> str:
    """Render one of the report templates."""
    return _env().get_template(name).render(fmt=fmt, version=__version__, **context)


def write_run(
    result: EpisodeResult,
    out_dir: Path,
    *,
    video: bool = True,
    progress: Progress | None = None,
    prerendered: Path | None = None,
) -> Path:
    """Write every output of one episode into ``out_dir`` atomically; returns ``out_dir``.

    ``prerendered`` is an MP4 of this episode already rendered elsewhere (moved in, not redone).
    """
    metrics = json_safe(metrics_dict(result))
    with atomic_dir(Path(out_dir)) as tmp:
        write_json(tmp / SCENE_JSON, json_safe(scene_dict(result)))
        write_episode_csv(result, tmp / EPISODE_CSV)
        check = check_run(tmp)
        write_check(check, tmp / CHECK_JSON)
        metrics["check"] = check_summary(check)
        write_json(tmp / METRICS_JSON, metrics)
        plot_tracking([result], [result.spec.policy], tmp / TRACKING_PNG)
        if video and prerendered is not None:
            shutil.move(prerendered, tmp / VIDEO_MP4)
        elif video:
            render_video(result, tmp / VIDEO_MP4, progress)
        html = render_template(
            "run.html",
            metrics=metrics,
            spec=result.spec,
            carrier=CARRIERS[result.log.arm],
            video=VIDEO_MP4 if video else None,
            plot=TRACKING_PNG,
            files=[SCENE_JSON, EPISODE_CSV, CHECK_JSON, METRICS_JSON],
            check=check,
        )
        (tmp / REPORT_HTML).write_text(html, encoding="utf-8")
    return Path(out_dir)


def written_check(out_dir: Path) -> dict[str, Any]:
    """The safety check's summary of a run :func:`write_run` wrote (from its ``metrics.json``)."""
    metrics = json.loads((Path(out_dir) / METRICS_JSON).read_text(encoding="utf-8"))
    return dict(metrics["check"])


def check_summary(check: CheckResult) -> dict[str, Any]:
    """The safety check's summary as ``metrics.json`` holds it (``check.json`` has the steps)."""
    return {
        "ok": check.ok,
        "violations": check.total,
        "counts": {k: v for k, v in check.counts.items() if v},
    }
