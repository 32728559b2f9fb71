"""CLI of the wire-chaser world: run, demo, experiment paper and config."""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import yaml

from endocam.cli.common import (
    ARM_CHOICES,
    EXIT_UNSAFE,
    UsageError,
    check_workers,
    integer,
    load_config_arg,
    out_dir,
    perception_arg,
    with_faults,
    with_perception,
)
from endocam.cli.export import export_runs, require_mcap
from endocam.config import ExperimentConfig
from endocam.registry import POLICIES
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import DEFAULT_SEED
from endocam.task.config import MAX_CONTROL_POINTS
from endocam.task.trajectory import TrajectoryKind

SEED_HELP = f"noise seed (default {DEFAULT_SEED})"
MAX_EXTRA_SEEDS = 1000  # count: --seeds of experiment tracking
MAX_PERCEPTION_FRAMES = 100_000  # count: --frames of experiment perception (~1 s each)


def _config(args: argparse.Namespace) -> ExperimentConfig:
    cfg = load_config_arg(getattr(args, "config", None))
    cfg = with_faults(cfg, getattr(args, "faults", None))
    return with_perception(cfg, getattr(args, "perception", None))


def _control_points(n: int) -> None:
    if not 2 <= n <= MAX_CONTROL_POINTS:
        raise UsageError(f"--control-points must be in 2..{MAX_CONTROL_POINTS}, got {n}")


def safety_exit(out: Path) -> int:
    """The exit code after writing ``out``: 0, or :data:`EXIT_UNSAFE` after a last line.

    :data:`EXIT_UNSAFE` when a run written under ``out`` broke a safety invariant (its
    ``metrics.json``'s ``check``, as ``endocam check`` finds it).
    """
    total, counts, runs = 0, Counter[str](), 0
    for path in sorted(Path(out).rglob("metrics.json")):
        check = json.loads(path.read_text(encoding="utf-8")).get("check")
        if check is None:
            continue
        runs += 1
        total += int(check["violations"])
        counts.update({k: int(v) for k, v in check["counts"].items()})
    if total == 0:
        return 0
    broken = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()) if v)
    where = f"{out}" if runs == 1 else f"{out} ({runs} runs)"
    print(f"safety check: {total} violations ({broken}) in {where} — see check.json")
    return EXIT_UNSAFE


def _with_arm(cfg: ExperimentConfig, arm: str | None) -> ExperimentConfig:
    """The config with ``episode.arm`` replaced when ``--arm`` was given."""
    if arm is None:
        return cfg
    episode = cfg.episode.model_copy(update={"arm": ArmKind(arm)})
    return cfg.model_copy(update={"episode": episode})


def _run(args: argparse.Namespace) -> int:
    from endocam.runner.episode import EpisodeSpec
    from endocam.runner.experiments import run_and_write

    _control_points(args.control_points)
    if args.seed < 0:
        raise UsageError(f"--seed must be ≥ 0, got {args.seed}")
    cfg = _with_arm(_config(args), args.arm)
    out = out_dir(args.out)
    _check_mcap(args)
    spec = EpisodeSpec(args.policy, TrajectoryKind(args.trajectory), args.control_points, args.seed)
    metrics = run_and_write(cfg, spec, out, video=not args.no_video)
    check = metrics["check"]
    safety = "safety check OK" if check["ok"] else f"{check['violations']} safety violations"
    print(
        f"{spec.policy}: image {metrics['image_error_px']['mean']:.1f} px, "
        f"3D {metrics['center_error_mm']['mean']:.2f} mm, "
        f"orientation {metrics['orientation_error_deg']['mean']:.2f} deg, "
        f"{metrics['touches']} touches, {safety} -> {out / 'report.html'}"
    )
    return _finish(args, out)


def _demo(args: argparse.Namespace) -> int:
    from endocam.runner.experiments import run_demo

    _control_points(args.control_points)
    if args.seed < 0:
        raise UsageError(f"--seed must be ≥ 0, got {args.seed}")
    cfg = _config(args)
    out = out_dir(args.out)
    _check_mcap(args)
    report = run_demo(
        cfg, out, control_points=args.control_points, seed=args.seed, video=not args.no_video
    )
    print(f"demo report: {report}")
    return _finish(args, out)


def _experiment(args: argparse.Namespace) -> int:
    from endocam.runner.experiments import run_paper_experiment

    cfg = _config(args)
    out = out_dir(args.out)
    _check_mcap(args)
    table = run_paper_experiment(_with_arm(cfg, args.arm), out, policy=args.policy)
    print(table)
    return _finish(args, out)


def _tracking(args: argparse.Namespace) -> int:
    from endocam.runner.tracking import check_choices, run_tracking_experiment

    controllers = [c for c in args.controllers.split(",") if c]
    carriers = [c for c in args.carriers.split(",") if c]
    try:
        check_choices(controllers, carriers)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if not 0 <= args.seeds <= MAX_EXTRA_SEEDS:
        raise UsageError(f"--seeds must be in 0..{MAX_EXTRA_SEEDS}, got {args.seeds}")
    check_workers(args.workers)
    cfg = _config(args)
    out = out_dir(args.out)
    _check_mcap(args)
    table = run_tracking_experiment(
        cfg,
        out,
        controllers=controllers,
        carriers=carriers,
        extra_seeds=args.seeds,
        workers=args.workers,
    )
    print(table)
    return _finish(args, out)


def _perception(args: argparse.Namespace) -> int:
    from endocam.runner.experiments import paper_paths
    from endocam.runner.perception_experiment import CARRIERS, run_perception_experiment

    least = len(paper_paths()) * len(CARRIERS)
    if not least <= args.frames <= MAX_PERCEPTION_FRAMES:
        raise UsageError(f"--frames must be in {least}..{MAX_PERCEPTION_FRAMES}, got {args.frames}")
    cfg = load_config_arg(args.config)
    out = out_dir(args.out)
    print(run_perception_experiment(cfg, out, args.frames))
    print(f"perception report: {out}")
    return 0


def _faults(args: argparse.Namespace) -> int:
    from endocam.runner.fault_matrix import run_fault_matrix

    check_workers(args.workers)
    cfg = _config(args)
    out = out_dir(args.out)
    _check_mcap(args)
    table = run_fault_matrix(cfg, out, workers=args.workers)
    print(table)
    return _finish(args, out)


def _check_mcap(args: argparse.Namespace) -> None:
    """With ``--mcap``, refuse before any work when the ``robot`` extra is missing."""
    if args.mcap:
        require_mcap()


def _finish(args: argparse.Namespace, out: Path) -> int:
    """After the results are written: ``--mcap``'s files, then the safety check's exit code."""
    if args.mcap:
        n = export_runs(out)
        print(f"mcap: episode.mcap in {n} run folder{'s' if n != 1 else ''} under {out}")
    return safety_exit(out)


def _mcap_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--mcap",
        action="store_true",
        help="also write each run as episode.mcap (ROS 2 messages, H.264 video; as `endocam "
        "export mcap` writes it; needs the robot extra)",
    )


def _faults_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--faults",
        metavar="FILE",
        help="TOML or YAML file with a faults section (see `endocam config`): inject seeded "
        "tracker and arm faults, logged per step in episode.csv's fault column",
    )


def _show_config(args: argparse.Namespace) -> int:
    cfg = _config(args)
    print(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False), end="")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``run``, ``demo``, ``experiment`` and ``config`` to the CLI."""
    policies = list(POLICIES)
    p = sub.add_parser(
        "run",
        help="run one wire-chaser episode and write its video, logs, metrics and report",
        description="Run one wire-chaser episode. Writes scene.json, episode.csv, metrics.json, "
        "video.mp4, tracking.png and report.html into --out.",
    )
    p.add_argument("--policy", required=True, choices=policies, help="camera policy")
    p.add_argument(
        "--trajectory",
        required=True,
        choices=[k.value for k in TrajectoryKind],
        help="ideal (centred, face perpendicular) or noisy (paper's randomised) ring trajectory",
    )
    p.add_argument(
        "--control-points",
        type=integer,
        default=71,
        help="control points along the wire, ≥ 2 (paper: 36 or 71; default 71)",
    )
    p.add_argument("--seed", type=integer, default=DEFAULT_SEED, help=SEED_HELP)
    p.add_argument("--out", required=True, help="output folder (replaced atomically)")
    p.add_argument("--no-video", action="store_true", help="skip rendering video.mp4")
    p.add_argument(
        "--arm",
        choices=ARM_CHOICES,
        default=None,
        help="what carries the camera: free (Cartesian limits only), psm or ecm (dVRK "
        "kinematics, IK and joint limits); default: the config's episode.arm (psm). "
        "orientation-ecm always uses the ECM",
    )
    p.add_argument("--config", help="TOML or YAML config file (see `endocam config`)")
    _faults_arg(p)
    perception_arg(p)
    _mcap_arg(p)
    p.set_defaults(handler=_run, runs_episodes=True)

    d = sub.add_parser(
        "demo",
        help="the three camera conditions on one noisy trajectory, side by side (make demo)",
    )
    d.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    d.add_argument("--control-points", type=integer, default=71, help="control points (default 71)")
    d.add_argument("--seed", type=integer, default=DEFAULT_SEED, help=SEED_HELP)
    d.add_argument("--no-video", action="store_true", help="skip the videos")
    d.add_argument("--config", help="TOML or YAML config file")
    perception_arg(d)
    _mcap_arg(d)
    d.set_defaults(handler=_demo, runs_episodes=True)

    e = sub.add_parser("experiment", help="reproduce the paper's experiments")
    esub = e.add_subparsers(dest="experiment", metavar="NAME")
    esub.required = True
    ep = esub.add_parser(
        "paper",
        help="3 ideal + 3 noisy trajectories with the orientation camera, beside the paper's "
        "Table (Sec. V)",
    )
    ep.add_argument("--out", default="out/paper", help="output folder (default out/paper)")
    ep.add_argument(
        "--policy",
        choices=policies,
        default="orientation",
        help="camera policy (default orientation)",
    )
    ep.add_argument(
        "--arm",
        choices=ARM_CHOICES,
        default="free",
        help="what carries the camera (default free: the paper's simulated 6-DoF endoscope, "
        "Cartesian limits only; psm or ecm: through that dVRK arm); overrides a --config "
        "file's episode.arm",
    )
    ep.add_argument("--config", help="TOML or YAML config file")
    _faults_arg(ep)
    _mcap_arg(ep)
    ep.set_defaults(handler=_experiment, runs_episodes=True)
    et = esub.add_parser(
        "tracking",
        help="the tracking protocol: controllers (paper, endocam, centering, oracle, "
        "endocam-visible) × carriers × 3 ideal + 3 study trajectories; table, plots and errors "
        "by phase",
    )
    et.add_argument("--out", required=True, help="output folder (replaced atomically)")
    et.add_argument(
        "--seeds",
        type=integer,
        default=0,
        help="extra noisy 71-point trajectories, seeds 1..N (default 0)",
    )
    et.add_argument(
        "--controllers",
        default="paper,endocam,centering,oracle,endocam-visible",
        help="comma-separated controllers (default paper,endocam,centering,oracle,endocam-visible)",
    )
    et.add_argument(
        "--carriers", default="free,psm", help="comma-separated carriers (default free,psm)"
    )
    et.add_argument("--workers", type=integer, default=2, help="worker processes (default 2)")
    et.add_argument("--config", help="TOML or YAML config file")
    _faults_arg(et)
    perception_arg(et)
    _mcap_arg(et)
    et.set_defaults(handler=_tracking, runs_episodes=True)
    epc = esub.add_parser(
        "perception",
        help="the stereo estimator alone on rendered pairs over the paper's six paths (the "
        "tracker's episodes, free camera and PSM), as rendered and through the image model: "
        "errors against distance, viewing angle and occluded fraction (pairs.csv, report.json, "
        "errors.png)",
    )
    epc.add_argument("--out", required=True, help="output folder (replaced atomically)")
    epc.add_argument(
        "--frames",
        type=integer,
        default=300,
        help="stereo pairs over the twelve episodes (default 300: about a minute)",
    )
    epc.add_argument("--config", help="TOML or YAML config file")
    epc.set_defaults(handler=_perception, runs_episodes=True)
    ef = esub.add_parser(
        "faults",
        help="the fault matrix: each fault alone at two severities, then all at once, on the "
        "orientation camera (endocam) with the free camera and the PSM; safety check, "
        "recovery times and tracking errors against the same run without faults",
    )
    ef.add_argument("--out", required=True, help="output folder (replaced atomically)")
    ef.add_argument("--workers", type=integer, default=2, help="worker processes (default 2)")
    ef.add_argument("--config", help="TOML or YAML config file (its faults section is ignored)")
    perception_arg(ef)  # the matrix on the stereo estimate (faults on what it delivers)
    _mcap_arg(ef)
    ef.set_defaults(handler=_faults, runs_episodes=True)

    c = sub.add_parser("config", help="print the full config (defaults, or --config merged)")
    c.add_argument("--config", help="TOML or YAML config file to validate and show")
    c.set_defaults(handler=_show_config)
