"""A run folder as an MCAP file of ROS 2 messages: what Foxglove, ``ros2 bag`` and PlotJuggler open.

:func:`export_mcap` reads a run folder (``scene.json``, ``episode.csv`` and, when present,
``video.mp4``) and writes one MCAP file with the ``ros2`` profile: every message CDR-encoded
by ``mcap-ros2-support`` from a standard ROS 2 message definition (:data:`SCHEMAS`), no
endocam-specific type. Every value of ``episode.csv`` is in a message, bit for bit (float64
in CDR is the float64 the CSV holds); a reader needs no endocam code (docs/robot.md,
"Recordings: MCAP").

Topics follow the CRTK names the dVRK publishes per arm, and a name means what it means on
the live link (:mod:`endocam.link.messages`): ``/PSM3/measured_cp`` and ``/PSM3/servo_cp``
(``/ECM/...`` for the ECM; :func:`crtk_topics`) are the dVRK's tool tip in the arm's base
frame (``frame_id`` ``PSM3_base``), converted from the logged camera pose by the link's own
:class:`endocam.robot.dvrk_frames.CrtkFrames`; ``/PSM3/measured_js`` the dVRK's joints. The
logged values themselves (:func:`topic_map`) are in the world frame (``frame_id`` ``world``):
the camera's optical frame on ``/camera/measured_cp``, the command on ``/camera/servo_cp``
— for the free camera (no dVRK counterpart, no joints) these are its CRTK topics on the link
too. Time stamps are the simulation's: header stamps and log times are ``t`` rounded to the
nanosecond; ``t`` itself, as a float64, is on :data:`SIM_TIME_TOPIC`. Poses are in m,
quaternions as ROS orders them (x, y, z, w).

The video's frames go in as ``foxglove_msgs/msg/CompressedVideo`` (``h264``: the left eye
re-encoded without B-frames, a key frame with its SPS/PPS every second, one access unit per
message, as Foxglove reads it) or ``sensor_msgs/msg/CompressedImage`` (``jpeg``: every ROS
image tool reads it, 4–6× the size on the demo's runs). Each frame is stamped with the
control step it shows (the step :func:`endocam.runner.outputs.video_frame_steps` gives).

``mcap`` and ``mcap-ros2-support`` are the optional extra ``robot``
(``pip install 'endocam[robot]'``); :func:`require_mcap` says so in one line.
"""

from __future__ import annotations

import enum
import json
import math
import subprocess
import tempfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from endocam.config import config_from_mapping
from endocam.robot.actuator import ArmKind
from endocam.robot.carriers import crtk_frames
from endocam.robot.dvrk_frames import (
    ARM_NAMESPACES,
    WORLD_FRAME_ID,
    CrtkFrames,
    crtk_pose_fields,
)
from endocam.runner.check import EPISODE_CSV, SCENE_JSON
from endocam.runner.log_schema import (
    LogHeader,
    joint_column,
    joint_names,
    quat_names,
    read_columns,
    xyz_names,
)
from endocam.runner.outputs import VIDEO_MP4, video_frame_steps, write_atomic

EPISODE_MCAP = "episode.mcap"
"""The file ``--mcap`` writes into each run folder (``endocam export mcap``'s default)."""
WORLD_FRAME = WORLD_FRAME_ID
"""``frame_id`` of every logged pose and point: the simulation's world frame."""
CAMERA_NS = ARM_NAMESPACES[ArmKind.FREE]
"""Namespace of the camera's optical frame in the world (``/camera/measured_cp``, ``servo_cp``)."""
IMAGE_FRAME = "endoscope_left_optical"
"""``frame_id`` of the video frames: the left eye, OpenCV optical frame (x right, y down)."""
SIM_TIME_TOPIC = "/endocam/sim_time"
"""``std_msgs/Float64``: the step's simulation time, s, exactly ``episode.csv``'s ``t``."""
NS_PER_S = 1_000_000_000  # ns in a second: header stamps and MCAP log times are integer ns
JPEG_QUALITY = 85  # 0..100, OpenCV's JPEG quality for --video jpeg (the wire stays crisp)
VIDEO_CRF = 20  # x264 constant rate factor of the re-encoded H.264 (as video.mp4's)

_SEP = "\n" + "=" * 80 + "\n"


def _msgdef(main: str, *deps: str) -> str:
    """A ROS 2 message definition as rosbag2 stores it: the type, then ``MSG:`` dependencies."""
    return _SEP.join((main, *(_DEPS[d] for d in deps)))


_DEPS = {
    "Header": "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id",
    "Time": "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec",
    "Pose": "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation",
    "Point": "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z",
    "Vector3": "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z",
    "Quaternion": "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\n"
    "float64 w 1",
}
SCHEMAS: dict[str, str] = {
    "geometry_msgs/msg/PoseStamped": _msgdef(
        "std_msgs/Header header\ngeometry_msgs/Pose pose",
        "Header",
        "Time",
        "Pose",
        "Point",
        "Quaternion",
    ),
    "geometry_msgs/msg/PointStamped": _msgdef(
        "std_msgs/Header header\ngeometry_msgs/Point point", "Header", "Time", "Point"
    ),
    "geometry_msgs/msg/Vector3Stamped": _msgdef(
        "std_msgs/Header header\ngeometry_msgs/Vector3 vector", "Header", "Time", "Vector3"
    ),
    "sensor_msgs/msg/JointState": _msgdef(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort",
        "Header",
        "Time",
    ),
    "sensor_msgs/msg/CompressedImage": _msgdef(
        "std_msgs/Header header\nstring format\nuint8[] data", "Header", "Time"
    ),
    "foxglove_msgs/msg/CompressedVideo": _msgdef(
        "builtin_interfaces/Time timestamp\nstring frame_id\nuint8[] data\nstring format", "Time"
    ),
    "std_msgs/msg/Float64": "float64 data",
    "std_msgs/msg/String": "string data",
    "std_msgs/msg/Bool": "bool data",
}
"""The ROS 2 definitions (common_interfaces, foxglove_msgs) of every type the file holds."""

POSE = "geometry_msgs/msg/PoseStamped"
POINT = "geometry_msgs/msg/PointStamped"
VECTOR = "geometry_msgs/msg/Vector3Stamped"
FLOAT = "std_msgs/msg/Float64"
TEXT = "std_msgs/msg/String"


class VideoFormat(enum.StrEnum):
    """How the video's frames are stored: H.264 access units, JPEG images, or not at all."""

    H264 = "h264"
    JPEG = "jpeg"
    NONE = "none"


@dataclass(frozen=True)
class Topic:
    """One topic of the file: its name, ROS 2 type and the ``episode.csv`` columns it carries.

    ``columns`` are in the message's field order: for a pose ``x, y, z`` then ``qx, qy, qz,
    qw`` (ROS order); for a joint state the ``q_<joint>`` columns; else the one column.
    """

    name: str
    type: str
    columns: tuple[str, ...]


def topic_map(carrier: ArmKind, estimates: bool = False) -> tuple[Topic, ...]:
    """Every per-step topic for a camera carried by ``carrier``, with the columns it carries.

    Together they carry each column of ``episode_column_names(carrier, estimates)`` exactly
    once; with ``estimates`` (a stereo run) also the estimator's ring centre
    (``/ring/estimate/position``, world, m), unit face normal (``/ring/estimate/normal``,
    world), ``est_ok`` and ``est_age_s`` (s), NaN where no estimate was delivered.
    """
    arm = ARM_NAMESPACES[carrier]

    def pose(prefix: str) -> tuple[str, ...]:
        w, x, y, z = quat_names(prefix)
        return (*xyz_names(prefix), x, y, z, w)

    topics = [
        Topic(SIM_TIME_TOPIC, FLOAT, ("t",)),
        Topic("/ring/measured_cp", POSE, pose("ring")),
        Topic(f"/{CAMERA_NS}/measured_cp", POSE, pose("cam")),
        Topic(f"/{CAMERA_NS}/servo_cp", POSE, pose("cmd")),
        Topic("/PSM1/tip", POINT, xyz_names("psm1_tip")),
        Topic("/PSM2/tip", POINT, xyz_names("psm2_tip")),
        Topic("/endocam/state", TEXT, ("state",)),
        Topic("/endocam/reason", TEXT, ("reason",)),
        Topic("/endocam/fault", TEXT, ("fault",)),
        Topic("/endocam/d_f", FLOAT, ("d_f",)),
        Topic("/endocam/contact", "std_msgs/msg/Bool", ("contact",)),
        Topic("/endocam/clearance", FLOAT, ("clearance",)),
        Topic("/endocam/image_error_px", FLOAT, ("image_error_px",)),
        Topic("/endocam/center_error_mm", FLOAT, ("center_error_mm",)),
        Topic("/endocam/orientation_error_deg", FLOAT, ("orientation_error_deg",)),
    ]
    if carrier is not ArmKind.FREE:
        q = tuple(joint_column(j) for j in joint_names(carrier))
        topics += [
            Topic(f"/{arm}/measured_js", "sensor_msgs/msg/JointState", q),
            Topic("/endocam/goal_conceded_mm", FLOAT, ("goal_conceded_mm",)),
            Topic("/endocam/goal_conceded_deg", FLOAT, ("goal_conceded_deg",)),
        ]
    if estimates:
        topics += [
            Topic("/ring/estimate/position", POINT, xyz_names("est")),
            Topic("/ring/estimate/normal", VECTOR, ("est_nx", "est_ny", "est_nz")),
            Topic("/ring/estimate/ok", FLOAT, ("est_ok",)),
            Topic("/ring/estimate/age_s", FLOAT, ("est_age_s",)),
        ]
    return tuple(topics)


def crtk_topics(carrier: ArmKind) -> tuple[Topic, ...]:
    """An arm's CRTK pose topics, converted from the logged camera poses (the free camera: none).

    ``/ARM/measured_cp`` from the ``cam_*`` columns, ``/ARM/servo_cp`` from the ``cmd_*``
    columns (``columns``: the world camera pose each is converted from), each the dVRK's tip in
    the arm's base frame as the link carries it. The link's ``setpoint_cp`` is not logged in
    ``episode.csv``, so a file has none.
    """
    if carrier is ArmKind.FREE:
        return ()
    arm = ARM_NAMESPACES[carrier]
    by_name = {t.name: t for t in topic_map(carrier)}
    return tuple(
        Topic(f"/{arm}/{name}", POSE, by_name[f"/{CAMERA_NS}/{name}"].columns)
        for name in ("measured_cp", "servo_cp")
    )


def crtk_poses(
    columns: Mapping[str, np.ndarray], names: tuple[str, ...], frames: CrtkFrames
) -> list[Any]:
    """The tip poses of the world camera poses in ``columns[names]`` (ROS order), as message fields.

    ``names`` : the 7 columns ``x, y, z, qx, qy, qz, qw`` of a camera pose in the world, m.
    Returns per step ``(x, y, z, qx, qy, qz, qw)`` of ``frames.tip_from_camera`` (the link's
    conversion, :func:`endocam.robot.dvrk_frames.crtk_pose_fields`), all NaN where the logged
    pose is not finite.
    """
    v = np.column_stack([np.asarray(columns[c], dtype=float) for c in names])
    ok = np.all(np.isfinite(v), axis=1)
    T = np.tile(np.eye(4), (len(v), 1, 1))
    T[:, :3, 3] = v[:, :3]
    T[ok, :3, :3] = Rotation.from_quat(v[ok, 3:]).as_matrix()
    nan = (math.nan,) * 7
    return [crtk_pose_fields(frames.tip_from_camera(T[k])) if ok[k] else nan for k in range(len(v))]


def video_topic(video: VideoFormat) -> Topic:
    """The video's topic and type for ``video`` (H.264 or JPEG; no columns)."""
    if video is VideoFormat.H264:
        return Topic("/endoscope/left/compressed_video", "foxglove_msgs/msg/CompressedVideo", ())
    if video is VideoFormat.JPEG:
        return Topic("/endoscope/left/image_raw/compressed", "sensor_msgs/msg/CompressedImage", ())
    raise ValueError(f"video format {video.value!r} has no topic")


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_mcap` wrote: the file, its size (bytes), messages and video frames."""

    path: Path
    size_bytes: int
    messages: int
    frames: int


Progress = Callable[[int], object]


def require_mcap() -> None:
    """Raise ``ValueError`` (one line) unless the ``robot`` extra (mcap-ros2-support) is there."""
    try:
        import mcap_ros2.writer  # noqa: F401
    except ImportError:
        raise ValueError(
            "MCAP export needs the packages mcap and mcap-ros2-support: "
            "pip install 'endocam[robot]'"
        ) from None


@dataclass(frozen=True)
class RunFiles:
    """A run folder read back: ``scene.json``'s log header, the episode's columns, the video.

    ``columns`` : every ``episode.csv`` column, (N,) float64 (NaN for an empty cell) or, for
    the text columns, strings. ``video`` : the ``video.mp4`` path, or ``None``.
    ``frame_steps`` : (F,) the control step each video frame shows.
    ``frames`` : where the carrier's CRTK poses are (the run's config, as the link mounts it).
    """

    header: LogHeader
    scene: Mapping[str, Any]
    columns: Mapping[str, np.ndarray]
    video: Path | None
    frame_steps: np.ndarray
    frames: CrtkFrames


def read_run(run_dir: Path) -> RunFiles:
    """Read and validate the run folder ``run_dir`` (``ValueError``: one line, the problem)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ValueError(f"{run_dir} is not a folder (a run folder holds scene.json, episode.csv)")
    for name in (SCENE_JSON, EPISODE_CSV):
        if not (run_dir / name).is_file():
            raise ValueError(f"{run_dir} has no {name}: not an endocam run folder")
    try:
        scene = json.loads((run_dir / SCENE_JSON).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{run_dir / SCENE_JSON} is not JSON: {exc}") from None
    if not isinstance(scene, dict):
        raise ValueError(f"{run_dir / SCENE_JSON} is not a JSON object")
    header = LogHeader.from_scene(scene, str(run_dir / SCENE_JSON))
    columns = read_columns(run_dir / EPISODE_CSV, header)
    video = run_dir / VIDEO_MP4
    steps = np.zeros(0, dtype=int)
    if video.is_file():
        episode = scene.get("config", {}).get("episode", {})
        steps = video_frame_steps(
            header.duration, episode["control_rate"], episode["video_fps"], len(columns["t"])
        )
    config = config_from_mapping(scene.get("config", {}), f"{run_dir / SCENE_JSON} (config)")
    frames = crtk_frames(header.carrier, config.episode.T_tip_cam, config.task.scene.T_world_rcm)
    return RunFiles(header, scene, columns, video if video.is_file() else None, steps, frames)


def export_mcap(
    run_dir: Path,
    out: Path,
    video: VideoFormat = VideoFormat.H264,
    progress: Progress | None = None,
) -> ExportResult:
    """Write the run folder ``run_dir`` as the MCAP file ``out``; returns what was written.

    Atomic: a hidden temporary file beside ``out``, renamed when complete (removed on error).

    ``video`` : the frames' format (ignored when the run has no ``video.mp4``).
    ``progress`` : called with the number of steps (then frames) done since its last call.

    Raises
    ------
    ValueError
        One line: the ``robot`` extra missing, not a run folder, a malformed log
        (``runner.log_schema.MalformedLogError``), a video that is not the run's.
    """
    require_mcap()
    run = read_run(run_dir)
    counts = {"messages": 0, "frames": 0}

    def write(tmp: Path) -> None:
        with tempfile.TemporaryDirectory(prefix=".endocam-mcap-") as work:
            frames = _frames(run, video, Path(work), progress)
            with open(tmp, "wb") as fh:
                counts.update(_write(fh, run, video, frames, progress))

    write_atomic(Path(out), write)
    return ExportResult(Path(out), Path(out).stat().st_size, counts["messages"], counts["frames"])


def _write(
    fh: Any,
    run: RunFiles,
    video: VideoFormat,
    frames: list[bytes],
    progress: Progress | None,
) -> dict[str, int]:
    from mcap_ros2.writer import Writer

    topics = topic_map(run.header.carrier, run.header.estimates)
    tips = crtk_topics(run.header.carrier)
    vtopic = video_topic(video) if frames else None
    used = {t.type for t in topics} | ({vtopic.type} if vtopic is not None else set())
    cols = run.columns
    tip_poses = {t.name: crtk_poses(cols, t.columns, run.frames) for t in tips}
    writer = Writer(fh)
    schemas = {n: writer.register_msgdef(n, SCHEMAS[n]) for n in SCHEMAS if n in used}
    writer.add_metadata("endocam", _metadata(run))
    t = cols["t"]
    stamps = [_stamp_ns(float(x)) for x in t]
    frames_at: dict[int, list[int]] = {}
    for j, k in enumerate(run.frame_steps[: len(frames)]):
        frames_at.setdefault(int(k), []).append(j)
    names = list(joint_names(run.header.carrier))
    values = {name: (a.tolist() if a.dtype != object else list(a)) for name, a in cols.items()}
    messages = 0
    for k, ns in enumerate(stamps):
        header = {"stamp": _time(ns), "frame_id": WORLD_FRAME}
        for topic in topics:
            msg = _message(topic, k, header, values, names)
            writer.write_message(topic.name, schemas[topic.type], msg, ns, ns, k)
            messages += 1
        tip_header = {"stamp": header["stamp"], "frame_id": run.frames.frame_id}
        for topic in tips:
            msg = _pose_message(tip_header, tip_poses[topic.name][k])
            writer.write_message(topic.name, schemas[POSE], msg, ns, ns, k)
            messages += 1
        if vtopic is not None:
            for j in frames_at.get(k, ()):
                msg = _frame_message(video, frames[j], _time(ns))
                writer.write_message(vtopic.name, schemas[vtopic.type], msg, ns, ns, j)
                messages += 1
        if progress is not None and (k + 1) % 100 == 0:
            progress(100)
    if progress is not None:
        progress(len(stamps) % 100)
    writer.finish()
    return {"messages": messages, "frames": len(frames) if vtopic is not None else 0}


def _message(
    topic: Topic, k: int, header: dict[str, Any], values: Mapping[str, list[Any]], joints: list[str]
) -> dict[str, Any]:
    """The message of ``topic`` at step ``k`` (a dict in the ROS 2 type's field layout)."""
    v = [values[c][k] for c in topic.columns]
    if topic.type == POSE:
        return _pose_message(header, v)
    if topic.type == POINT:
        return {"header": header, "point": {"x": v[0], "y": v[1], "z": v[2]}}
    if topic.type == VECTOR:
        return {"header": header, "vector": {"x": v[0], "y": v[1], "z": v[2]}}
    if topic.type == "sensor_msgs/msg/JointState":
        return {"header": header, "name": joints, "position": v, "velocity": [], "effort": []}
    if topic.type == "std_msgs/msg/Bool":
        return {"data": bool(v[0])}
    return {"data": v[0]}


def _pose_message(header: dict[str, Any], v: Any) -> dict[str, Any]:
    """``geometry_msgs/PoseStamped`` of the fields ``v`` = ``(x, y, z, qx, qy, qz, qw)``."""
    return {
        "header": header,
        "pose": {
            "position": {"x": v[0], "y": v[1], "z": v[2]},
            "orientation": {"x": v[3], "y": v[4], "z": v[5], "w": v[6]},
        },
    }


def _frame_message(video: VideoFormat, data: bytes, stamp: dict[str, int]) -> dict[str, Any]:
    if video is VideoFormat.H264:
        return {"timestamp": stamp, "frame_id": IMAGE_FRAME, "data": data, "format": "h264"}
    return {"header": {"stamp": stamp, "frame_id": IMAGE_FRAME}, "format": "jpeg", "data": data}


def _stamp_ns(t: float) -> int:
    """A simulation time ``t`` (s, ≥ 0) as integer nanoseconds (rounded to the nearest)."""
    return round(t * NS_PER_S)


def _time(ns: int) -> dict[str, int]:
    """``builtin_interfaces/Time`` of ``ns`` nanoseconds."""
    return {"sec": ns // NS_PER_S, "nanosec": ns % NS_PER_S}


def _metadata(run: RunFiles) -> dict[str, str]:
    """The file's ``endocam`` metadata record: what the run was and what the topics mean."""
    episode = run.scene.get("episode", {})
    return {
        "endocam_version": str(run.scene.get("endocam_version", "")),
        "carrier": run.header.carrier.value,
        "control_period_s": repr(run.header.control_period),
        "duration_s": repr(run.header.duration),
        "policy": str(episode.get("policy", "")),
        "trajectory": str(episode.get("trajectory", "")),
        "control_points": str(episode.get("control_points", "")),
        "seed": str(episode.get("seed", "")),
        "units": "SI (m, s, rad) unless a topic name gives its unit (_mm, _deg, _px)",
        "time": f"simulation time; exact float64 seconds on {SIM_TIME_TOPIC}",
        "docs": "docs/robot.md, 'Recordings: MCAP'",
    }


# ------------------------------------------------------------------------------------ video
def _frames(
    run: RunFiles, video: VideoFormat, work: Path, progress: Progress | None
) -> list[bytes]:
    """The run's video frames in ``video``'s format, one ``bytes`` per frame (none: [])."""
    if run.video is None or video is VideoFormat.NONE:
        return []
    frames = _h264_frames(run, work) if video is VideoFormat.H264 else _jpeg_frames(run.video)
    if len(frames) != len(run.frame_steps):
        raise ValueError(
            f"{run.video} has {len(frames)} frames, but the run's {run.header.duration:g} s at "
            f"its video rate give {len(run.frame_steps)}: not this run's video"
        )
    if progress is not None:
        progress(len(frames))
    return frames


def _jpeg_frames(path: Path) -> list[bytes]:
    import cv2
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    out = []
    for raw in reader:
        rgb = np.frombuffer(raw, np.uint8).reshape(height, width, 3)
        ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
            raise RuntimeError("JPEG encoding failed")
        out.append(buf.tobytes())
    return out


def _h264_frames(run: RunFiles, work: Path) -> list[bytes]:
    """``video.mp4`` re-encoded as H.264 Annex B, split into one access unit per frame.

    No B-frames (Foxglove decodes in order), a key frame every second with its SPS/PPS
    (ffmpeg's raw H.264 output repeats them), an access unit delimiter before each frame.
    """
    import imageio_ffmpeg

    assert run.video is not None
    fps = float(run.scene["config"]["episode"]["video_fps"])
    raw = work / "left.h264"
    cmd = [
        imageio_ffmpeg.get_ffmpeg_exe(),
        "-nostdin",
        "-v",
        "error",
        "-i",
        str(run.video),
        "-an",
        "-c:v",
        "libx264",
        "-preset",
        "veryfast",
        "-crf",
        str(VIDEO_CRF),
        "-pix_fmt",
        "yuv420p",
        "-bf",
        "0",
        "-g",
        str(max(1, math.ceil(fps))),
        "-x264-params",
        "aud=1",
        "-f",
        "h264",
        str(raw),
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["ffmpeg failed"])[-1]
        raise ValueError(f"{run.video}: cannot read the video ({last})")
    return list(access_units(raw.read_bytes()))


def access_units(stream: bytes) -> Iterator[bytes]:
    """Split an H.264 Annex B byte stream into access units at each delimiter (NAL type 9).

    Each unit keeps its delimiter and start codes; bytes before the first delimiter open the
    first unit.
    """
    starts = []
    i = stream.find(b"\x00\x00\x01")
    while i >= 0:
        if i + 3 < len(stream) and stream[i + 3] & 0x1F == 9:
            starts.append(i - 1 if i > 0 and stream[i - 1] == 0 else i)
        i = stream.find(b"\x00\x00\x01", i + 3)
    if not starts:
        return
    starts[0] = 0
    for a, b in zip(starts, [*starts[1:], len(stream)], strict=True):
        yield stream[a:b]


def run_folders(root: Path) -> list[Path]:
    """Every run folder at or under ``root``, sorted.

    A run folder holds ``scene.json`` and ``episode.csv``; hidden folders (endocam's
    temporary ones) are skipped.
    """
    root = Path(root)
    found = [p.parent for p in root.rglob(EPISODE_CSV) if (p.parent / SCENE_JSON).is_file()]
    visible = [p for p in found if not any(s.startswith(".") for s in p.relative_to(root).parts)]
    return sorted(set(visible))
