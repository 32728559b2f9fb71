"""``endocam export mcap``: a run folder as an MCAP file of ROS 2 messages; ``--mcap`` on runs.

The library is :mod:`endocam.runner.mcap_export`; this module parses, checks the paths and
reports in one line.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from endocam.cli.common import UsageError

VIDEO_HELP = (
    "video frames as h264 (foxglove_msgs/CompressedVideo: Foxglove, about the size of "
    "video.mp4), jpeg (sensor_msgs/CompressedImage: every ROS image tool, 4-6x larger) "
    "or none (default h264; ignored for a run without video.mp4)"
)


def require_mcap() -> None:
    """A :class:`UsageError` (one line, the extra to install) when mcap is not installed."""
    from endocam.runner.mcap_export import require_mcap as require

    try:
        require()
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def export_runs(out: Path) -> int:
    """Write ``episode.mcap`` into every run folder under ``out`` (``--mcap``); returns how many."""
    from endocam.progress import progress_bar
    from endocam.runner.mcap_export import EPISODE_MCAP, export_mcap, run_folders

    folders = run_folders(out)
    for folder in progress_bar(folders, desc="mcap", unit="run", disable=len(folders) < 2):
        try:
            export_mcap(folder, folder / EPISODE_MCAP)
        except ValueError as exc:
            raise UsageError(f"--mcap: {exc}") from None
    return len(folders)


def _export_mcap(args: argparse.Namespace) -> int:
    from endocam.progress import progress_bar
    from endocam.runner.mcap_export import EPISODE_MCAP, VideoFormat, export_mcap, read_run

    require_mcap()
    run_dir = Path(args.run_dir)
    try:
        run = read_run(run_dir)  # the input first: a missing run is named as such
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(args.out) if args.out is not None else run_dir / EPISODE_MCAP
    if out.is_dir():
        raise UsageError(f"--out {out} is a folder; name a file, e.g. {out / EPISODE_MCAP}")
    if out.exists() and not args.force:
        raise UsageError(f"--out {out} exists; pass --force to replace it")
    if not out.parent.is_dir():
        raise UsageError(f"--out {out}: folder {out.parent} does not exist")
    try:
        video = VideoFormat(args.video)
        frames = run.video is not None and video is not VideoFormat.NONE
        total = len(run.columns["t"]) + (len(run.frame_steps) if frames else 0)
        with progress_bar(total=total, desc="mcap", unit="step") as bar:
            result = export_mcap(run_dir, out, video, progress=bar.update)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    video_note = f", {result.frames} video frames" if result.frames else ""
    print(
        f"{result.path}: {result.messages} messages{video_note}, {result.size_bytes / 1e6:.1f} MB"
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``export mcap`` to the CLI."""
    e = sub.add_parser("export", help="write a run in another format (mcap: ROS 2 tools)")
    esub = e.add_subparsers(dest="format", metavar="FORMAT")
    esub.required = True
    m = esub.add_parser(
        "mcap",
        help="a run folder as an MCAP file of ROS 2 (CDR) messages: Foxglove, ros2 bag, "
        "PlotJuggler open it (needs the robot extra)",
        description="Write RUN_DIR (scene.json, episode.csv, video.mp4) as MCAP with ROS 2 "
        "messages: CRTK topics (/PSM3/measured_cp, /PSM3/servo_cp, /PSM3/measured_js, "
        "/ring/measured_cp), the controller's state, reason and d_f, the tool tips, the "
        "touches and the left-eye video; time stamps are the simulation's. Every value of "
        "episode.csv is in it exactly (docs/robot.md, 'Recordings: MCAP').",
    )
    m.add_argument("run_dir", metavar="RUN_DIR", help="a run folder (endocam run --out)")
    m.add_argument("--out", metavar="FILE", help="the MCAP file (default RUN_DIR/episode.mcap)")
    m.add_argument("--force", action="store_true", help="replace an existing --out file")
    m.add_argument("--video", choices=["h264", "jpeg", "none"], default="h264", help=VIDEO_HELP)
    m.set_defaults(handler=_export_mcap)
