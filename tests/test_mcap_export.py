"""``endocam export mcap`` / ``--mcap``: a run as MCAP with ROS 2 messages, every value exact.

The file is read back with mcap's reader and mcap-ros2-support's decoder only (no endocam
code), and compared cell by cell with ``episode.csv`` parsed by the csv module.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import sys
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from endocam.cli import main
from endocam.config import config_from_mapping
from endocam.robot import PSM
from endocam.robot.actuator import ArmKind
from endocam.runner.log_schema import episode_column_names
from endocam.runner.mcap_export import topic_map

SHORT_TOML = """
[task.trajectory]
duration = 1.0

[camera]
width = 160
height = 120

[episode]
video_fps = 10.0
"""
WIDTH_PX, HEIGHT_PX, FPS_HZ, DURATION_S, RATE_HZ = 160, 120, 10.0, 1.0, 100.0
N_FRAMES = 11  # count: frames over [0, 1] s at 10 Hz
NS_PER_S = 1_000_000_000
TEXT = ("state", "fault", "reason")

# The reader's side, written out here rather than taken from the exporter: topic -> columns.
ARM = "PSM3"
POSES = {"/ring/measured_cp": "ring", "/camera/measured_cp": "cam", "/camera/servo_cp": "cmd"}
TIPS = {f"/{ARM}/measured_cp": "cam", f"/{ARM}/servo_cp": "cmd"}  # the dVRK's tip, base frame
TIP_ATOL_M = 1e-12  # m: a pose through a quaternion and three 4x4 products, round-off
POINTS = {"/PSM1/tip": "psm1_tip", "/PSM2/tip": "psm2_tip"}
SCALARS = {
    "/endocam/sim_time": "t",
    "/endocam/state": "state",
    "/endocam/reason": "reason",
    "/endocam/fault": "fault",
    "/endocam/d_f": "d_f",
    "/endocam/contact": "contact",
    "/endocam/clearance": "clearance",
    "/endocam/image_error_px": "image_error_px",
    "/endocam/center_error_mm": "center_error_mm",
    "/endocam/orientation_error_deg": "orientation_error_deg",
    "/endocam/goal_conceded_mm": "goal_conceded_mm",
    "/endocam/goal_conceded_deg": "goal_conceded_deg",
}
VIDEO_TOPIC = "/endoscope/left/compressed_video"
JPEG_TOPIC = "/endoscope/left/image_raw/compressed"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 1 s PSM run at 160×120 px with video, written with ``--mcap``."""
    root = tmp_path_factory.mktemp("mcap")
    config = root / "short.toml"
    config.write_text(SHORT_TOML)
    out = root / "run"
    args = ["run", "--policy", "endocam", "--trajectory", "noisy", "--control-points", "36"]
    code = main([*args, "--seed", "3", "--out", str(out), "--config", str(config), "--mcap"])
    assert code == 0
    return out


def _csv(path: Path) -> dict[str, list[object]]:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return {
        name: [r[name] if name in TEXT else (float(r[name]) if r[name] else math.nan) for r in rows]
        for name in rows[0]
    }


def _decode(path: Path) -> dict[str, list[tuple[int, object]]]:
    """Every message of the file by topic: (log time in ns, decoded ROS 2 message)."""
    by_topic: dict[str, list[tuple[int, object]]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, ros in reader.iter_decoded_messages(log_time_order=True):
            by_topic.setdefault(channel.topic, []).append((message.log_time, ros))
    return by_topic


def _err_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def test_every_value_of_episode_csv_comes_back_exactly(run_dir: Path) -> None:
    expected = _csv(run_dir / "episode.csv")
    topics = _decode(run_dir / "episode.mcap")
    got: dict[str, list[object]] = {}
    for topic, prefix in POSES.items():
        msgs = [m for _, m in topics[topic]]
        for axis in "xyz":
            got[f"{prefix}_{axis}"] = [getattr(m.pose.position, axis) for m in msgs]
        for axis in "wxyz":
            got[f"{prefix}_q{axis}"] = [getattr(m.pose.orientation, axis) for m in msgs]
    for topic, prefix in POINTS.items():
        for axis in "xyz":
            got[f"{prefix}_{axis}"] = [getattr(m.point, axis) for _, m in topics[topic]]
    for topic, column in SCALARS.items():
        got[column] = [m.data for _, m in topics[topic]]
    got["contact"] = [float(c) for c in got["contact"]]
    js = [m for _, m in topics[f"/{ARM}/measured_js"]]
    names = list(js[0].name)
    for j, name in enumerate(names):
        got[f"q_{name}"] = [m.position[j] for m in js]
    assert set(got) == set(expected)  # every column, no more
    n = len(expected["t"])
    assert n == int(DURATION_S * RATE_HZ) + 1
    for name, values in expected.items():
        assert len(got[name]) == n, name
        if name in TEXT:
            assert got[name] == values, name
        else:  # float64 in CDR is the CSV's float64: equal bit for bit (NaN where NaN)
            np.testing.assert_array_equal(np.array(got[name]), np.array(values), err_msg=name)
    # time stamps: the simulation's, in the log time and every header, to the nanosecond
    stamps = [round(t * NS_PER_S) for t in expected["t"]]
    for topic in [*POSES, *POINTS, f"/{ARM}/measured_js"]:
        assert [log for log, _ in topics[topic]] == stamps, topic
        heads = [m.header for _, m in topics[topic]]
        assert [h.stamp.sec * NS_PER_S + h.stamp.nanosec for h in heads] == stamps, topic
        assert {h.frame_id for h in heads} == {"world"}
    for topic in SCALARS:
        assert [log for log, _ in topics[topic]] == stamps, topic
    # the arm's CRTK topics as on the link: the PSM's tip (its forward kinematics at the
    # logged joints) in its base frame, named as the dVRK names it
    for topic in TIPS:
        assert [log for log, _ in topics[topic]] == stamps, topic
        assert {m.header.frame_id for _, m in topics[topic]} == {f"{ARM}_base"}
    q = np.array([[got[f"q_{name}"][k] for name in names] for k in range(n)])
    psm = PSM()
    tip = {t: np.array([_matrix(m.pose) for _, m in topics[t]]) for t in TIPS}
    for k in range(0, n, 10):
        np.testing.assert_allclose(
            tip[f"/{ARM}/measured_cp"][k], psm.forward(q[k]), atol=TIP_ATOL_M
        )
    config = config_from_mapping(json.loads((run_dir / "scene.json").read_text())["config"])
    T_world_rcm, T_tip_cam = config.task.scene.T_world_rcm, config.episode.T_tip_cam
    for topic, prefix in TIPS.items():  # the camera in the world on that tip: the logged pose
        T_world_cam = T_world_rcm @ tip[topic] @ T_tip_cam
        p = np.column_stack([expected[f"{prefix}_{axis}"] for axis in "xyz"])
        np.testing.assert_allclose(T_world_cam[:, :3, 3], p, atol=TIP_ATOL_M, rtol=0, err_msg=topic)


def _matrix(pose: object) -> np.ndarray:
    """(4, 4) of a decoded ``geometry_msgs/Pose``."""
    p, o = pose.position, pose.orientation  # type: ignore[attr-defined]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
    T[:3, 3] = p.x, p.y, p.z
    return T


def test_video_frames_decode_at_their_steps(run_dir: Path, tmp_path: Path) -> None:
    topics = _decode(run_dir / "episode.mcap")
    frames = topics[VIDEO_TOPIC]
    assert len(frames) == N_FRAMES
    steps = np.rint(np.arange(N_FRAMES) * RATE_HZ / FPS_HZ).astype(int)
    t = np.arange(int(DURATION_S * RATE_HZ) + 1) / RATE_HZ
    assert [log for log, _ in frames] == [round(float(x) * NS_PER_S) for x in t[steps]]
    assert {m.format for _, m in frames} == {"h264"}
    first = bytes(frames[0][1].data)
    assert b"\x00\x00\x01\x67" in first  # the key frame carries its SPS (NAL type 7)
    stream = tmp_path / "left.h264"
    stream.write_bytes(b"".join(bytes(m.data) for _, m in frames))
    reader = imageio_ffmpeg.read_frames(str(stream))
    meta = next(reader)
    assert tuple(meta["size"]) == (WIDTH_PX, HEIGHT_PX)
    assert sum(1 for _ in reader) == N_FRAMES  # each message held exactly one frame


def test_jpeg_frames_and_size(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "jpeg.mcap"
    assert main(["export", "mcap", str(run_dir), "--out", str(out), "--video", "jpeg"]) == 0
    frames = _decode(out)[JPEG_TOPIC]
    assert len(frames) == N_FRAMES
    image = cv2.imdecode(np.frombuffer(bytes(frames[0][1].data), np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (HEIGHT_PX, WIDTH_PX, 3)
    assert frames[0][1].format == "jpeg"
    # the H.264 file stays within 1.5x the CSV and the video it holds
    source = (run_dir / "episode.csv").stat().st_size + (run_dir / "video.mp4").stat().st_size
    assert (run_dir / "episode.mcap").stat().st_size <= 1.5 * source


@pytest.mark.parametrize("estimates", [False, True])
@pytest.mark.parametrize("carrier", list(ArmKind))
def test_topics_carry_each_column_once(carrier: ArmKind, estimates: bool) -> None:
    columns = [c for topic in topic_map(carrier, estimates) for c in topic.columns]
    assert sorted(columns) == sorted(episode_column_names(carrier, estimates))
    joints = [t for t in topic_map(carrier) if t.type == "sensor_msgs/msg/JointState"]
    assert len(joints) == (0 if carrier is ArmKind.FREE else 1)


EST_TOPICS = {  # the reader's side: topic -> the estimate columns, in field order
    "/ring/estimate/position": ("point", ("est_x", "est_y", "est_z")),
    "/ring/estimate/normal": ("vector", ("est_nx", "est_ny", "est_nz")),
}


def test_a_stereo_runs_estimates_come_back_exactly(run_dir: Path, tmp_path: Path) -> None:
    """A run's log with the estimate columns (as a stereo run writes them) read back exactly."""
    stereo = tmp_path / "stereo"
    stereo.mkdir()
    scene = json.loads((run_dir / "scene.json").read_text())
    scene["log"]["estimates"] = True
    (stereo / "scene.json").write_text(json.dumps(scene))
    with open(run_dir / "episode.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    rng = np.random.default_rng(26)
    for k, row in enumerate(rows):  # an estimate on two steps of three, none on the third
        ok = k % 3 != 2
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        est = [*rng.normal(scale=0.05, size=3), *n, 1.0, rng.uniform(0.05, 0.2)]
        names = ("est_x", "est_y", "est_z", "est_nx", "est_ny", "est_nz", "est_ok", "est_age_s")
        row.update({c: repr(float(v)) if ok else "" for c, v in zip(names, est, strict=True)})
        row["est_ok"] = "1" if ok else "0"
    columns = episode_column_names(ArmKind.PSM, estimates=True)
    with open(stereo / "episode.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    out = tmp_path / "stereo.mcap"
    assert main(["export", "mcap", str(stereo), "--out", str(out), "--video", "none"]) == 0
    expected, topics = _csv(stereo / "episode.csv"), _decode(out)
    got: dict[str, list[object]] = {}
    for topic, (field, names) in EST_TOPICS.items():
        for axis, name in zip("xyz", names, strict=True):
            got[name] = [getattr(getattr(m, field), axis) for _, m in topics[topic]]
    got["est_ok"] = [m.data for _, m in topics["/ring/estimate/ok"]]
    got["est_age_s"] = [m.data for _, m in topics["/ring/estimate/age_s"]]
    for name, values in got.items():  # float64 both ways: equal bit for bit, NaN where empty
        np.testing.assert_array_equal(values, expected[name], err_msg=name)
    assert sum(expected["est_ok"]) == sum(1 for k in range(len(rows)) if k % 3 != 2)


def test_bad_input_exits_2_and_writes_nothing(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.mcap"
    cases: list[tuple[list[str], str]] = []
    cases.append(([str(tmp_path / "missing"), "--out", str(out)], "is not a folder"))
    no_csv = tmp_path / "no_csv"
    no_csv.mkdir()
    shutil.copy(run_dir / "scene.json", no_csv)
    cases.append(([str(no_csv), "--out", str(out)], "has no episode.csv"))
    short = tmp_path / "short"
    short.mkdir()
    shutil.copy(run_dir / "scene.json", short)
    lines = (run_dir / "episode.csv").read_text().splitlines(keepends=True)
    (short / "episode.csv").write_text("".join(lines[:-1]))  # one row missing
    cases.append(([str(short), "--out", str(out)], "rows"))
    cases.append(([str(run_dir), "--out", str(tmp_path)], "is a folder"))
    for args, needle in cases:
        assert main(["export", "mcap", *args]) == 2, args
        assert needle in _err_line(capsys)
        assert not out.exists()
    assert main(["export", "mcap", str(tmp_path / "missing")]) == 2  # the input named first
    assert "missing is not a folder" in _err_line(capsys)
    assert main(["export", "mcap", str(run_dir)]) == 2  # --mcap wrote it: not replaced
    assert "--force" in _err_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["no_csv", "short"]  # no temp files
    assert {p.name for p in run_dir.iterdir() if p.name.startswith(".")} == {".endocam-output"}


def test_missing_extra_refused_before_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "mcap_ros2.writer", None)  # import fails: not installed
    out = tmp_path / "run"
    args = ["run", "--policy", "fixed", "--trajectory", "ideal", "--out", str(out), "--mcap"]
    assert main(args) == 2
    assert "pip install 'endocam[robot]'" in _err_line(capsys)
    assert not out.exists()
